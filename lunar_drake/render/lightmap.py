"""Baked terrain shadows: the fraction of the solar disk visible from each DEM cell.

Paper section 5 ("Baked Shadows"): the Sun moves slowly at the poles (~0.5 deg/hour), so
terrain self-shadowing is pre-computed into a lightmap at the DEM resolution, with the
Sun modelled as an extended source (the paper cast rays from 280 points of the disk).
The paper planned, but did not implement, one lightmap per hour with linear
interpolation in between: :func:`lightmap_series` and :func:`interpolate_lightmap`.

Method (:func:`lightmap`)
-------------------------
The horizon is treated as a straight, level line across the small solar disk (angular
radius ``r`` = 0.2665 deg) at the Sun's azimuth, so the visible fraction depends only on
the horizon elevation ``h`` there: 1 below ``e - r``, 0 above ``e + r`` and the
circular-segment area in between (:func:`solar_disk_visible_fraction`). Only ``h``
inside that 0.53-deg band matters, which the banded sweep engine of
:mod:`lunar_drake.render.horizon` resolves (sliding-window maxima along sweep lines for
a few slopes across the band, an exact near field for each cell's own ray, lunar
curvature, tiles with a halo of the shadow reach, bit-identical whatever the tiling).
Terrain outside the DEM enters through a :class:`HorizonMask`:
``h_eff = max(h_local, mask(azimuth))``; by default the surroundings are a level plain
(horizon 0 deg), so a Sun below the horizon gives zeros. The Sun's azimuth and
elevation are those at the site origin (the grid centre, grid-north azimuth); since the
local vertical follows the Moon's curvature, a cell ``u`` m towards the Sun sees it
``u / R`` higher (0.005 deg at 164 m), and so do distant outside horizons.

Accuracy: against the brute-force reference (:func:`lightmap_bruteforce`, 280 rays per
cell marched exactly over the bilinear surface) on rough fractal terrain under a
3-8 deg Sun, the lit fraction agrees to better than 0.01 at the 99th percentile of cells
(tests/test_lightmap.py asserts 0.02); the largest single-cell differences (~0.2) come from
the straight-horizon assumption (the horizon is not level across the disk's 0.53 deg of
azimuth when a caster is a few pixels away) and from lateral interpolation between sweep
lines for casters just beyond the exact near field.

Limb darkening
--------------
``limb="uniform"`` (the default: the paper's 280 uniform rays; the fraction of the disk
*area*) or ``"darkened"``: the fraction of the *flux*, linear law
``I(mu) = 1 - u (1 - mu)`` with ``u = 0.6`` (visible, ~550 nm; e.g. Cox 2000, *Allen's
Astrophysical Quantities*, 4th ed., solar limb darkening -- from memory). Both are closed
form: with ``v = (e - h) / r`` the area above the line is
``pi - acos v + v sqrt(1 - v**2)`` and, integrating the chords analytically, the flux
above it is ``(1 - u) (pi - acos v + v sqrt(1 - v**2)) + u (pi / 2) (2/3 + v - v**3 / 3)``
out of ``pi (1 - u / 3)``. Darkening sharpens penumbrae slightly (by at most 0.02 in the
fraction). Per cell the fraction is read from a 4097-entry table of these formulas
(linear interpolation, error < 1e-5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render.horizon import (
    MOON_RADIUS_M,
    HorizonField,
    HorizonMask,
    as_grid,
    band_plan,
    bilinear_rows,
    height_range,
    tiled_dask,
)

__all__ = [
    "LIMBS",
    "LIMB_DARKENING_U",
    "SUN_ANGULAR_RADIUS_DEG",
    "LightmapSeries",
    "add_arguments",
    "interpolate_lightmap",
    "lightmap",
    "lightmap_bruteforce",
    "lightmap_dask",
    "lightmap_from_horizon",
    "lightmap_series",
    "run_cli",
    "solar_disk_visible_fraction",
    "sun_in_grid_frame",
    "sunflower_disk",
]

SUN_ANGULAR_RADIUS_DEG = 0.2665
"""Angular radius of the Sun seen from the Moon at 1 au (deg): asin(695 700 km / 1 au)
(IAU 2015 Resolution B3 nominal solar radius); it varies by +-1.7 % over a year."""

LIMB_DARKENING_U = 0.6
"""Linear limb-darkening coefficient of the Sun in the visible (Cox 2000, from memory)."""

LIMBS = ("uniform", "darkened")


# ----------------------------------------------------------------------------------------
# Visible fraction of the solar disk
# ----------------------------------------------------------------------------------------
def _check_limb(limb: str) -> None:
    if limb not in LIMBS:
        raise ConfigError(f"limb = {limb!r} is unknown; allowed: {LIMBS}")


def _fraction_of_offset(v: np.ndarray, limb: str, u_ld: float = LIMB_DARKENING_U) -> np.ndarray:
    """Visible fraction for the disk centre ``v`` radii above a straight horizon (float64)."""
    v = np.clip(np.asarray(v, dtype=np.float64), -1.0, 1.0)
    seg = np.pi - np.arccos(v) + v * np.sqrt(1.0 - v * v)  # area above the line
    if limb == "uniform":
        return seg / np.pi
    quad = (np.pi / 2.0) * (2.0 / 3.0 + v - v**3 / 3.0)
    return ((1.0 - u_ld) * seg + u_ld * quad) / (np.pi * (1.0 - u_ld / 3.0))


def solar_disk_visible_fraction(
    horizon_elev_rad,
    sun_elev_rad,
    *,
    sun_radius_rad: float = math.radians(SUN_ANGULAR_RADIUS_DEG),
    limb: str = "uniform",
    limb_darkening_u: float = LIMB_DARKENING_U,
) -> np.ndarray:
    """Fraction of the solar disk (or of its flux) above a straight horizon.

    The horizon is a horizontal line at elevation ``horizon_elev_rad`` across the disk
    of angular radius ``sun_radius_rad`` centred at ``sun_elev_rad`` (all rad;
    broadcast). ``limb="uniform"``: area fraction, ``1 - (acos v - v sqrt(1 - v**2)) /
    pi`` with ``v = (sun - horizon) / radius`` clipped to [-1, 1]; ``"darkened"``: flux
    fraction under the linear law ``I(mu) = 1 - u (1 - mu)`` (closed form, see the
    module docstring). Returns float64 in [0, 1].
    """
    _check_limb(limb)
    r = float(sun_radius_rad)
    if not (math.isfinite(r) and 0 < r < 0.1):
        raise OutOfRangeError(
            f"sun_radius_rad = {sun_radius_rad!r} is invalid; allowed (0, 0.1) rad"
        )
    u = float(limb_darkening_u)
    if not 0.0 <= u <= 1.0:
        raise OutOfRangeError(f"limb_darkening_u = {limb_darkening_u!r} is invalid; allowed [0, 1]")
    v = (np.asarray(sun_elev_rad, dtype=np.float64) - np.asarray(horizon_elev_rad)) / r
    return _fraction_of_offset(v, limb, u)


_LUT_N = 4097
_LUT_V = np.linspace(-1.0, 1.0, _LUT_N)


def _fraction_lut(limb: str, u_ld: float) -> np.ndarray:
    lut = _fraction_of_offset(_LUT_V, limb, u_ld)
    lut[0], lut[-1] = 0.0, 1.0  # exactly dark / lit beyond the disk
    return lut


# ----------------------------------------------------------------------------------------
# Lightmap
# ----------------------------------------------------------------------------------------
def _check_sun(az, el) -> tuple[float, float]:
    a = float(az)
    e = float(el)
    if not math.isfinite(a):
        raise OutOfRangeError(f"sun_azimuth_deg = {az!r} is invalid; must be finite (deg)")
    if not (math.isfinite(e) and -89.0 <= e <= 89.0):
        raise OutOfRangeError(f"sun_elevation_deg = {el!r} is invalid; allowed [-89, 89] deg")
    return a % 360.0, e


def _check_disk(sun_radius_deg, limb, limb_darkening_u) -> float:
    _check_limb(limb)
    r = math.radians(float(sun_radius_deg))
    if not (math.isfinite(r) and 0 < r < 0.1):
        raise OutOfRangeError(
            f"sun_radius_deg = {sun_radius_deg!r} is invalid; allowed (0, 5.7) deg"
        )
    if not 0.0 <= float(limb_darkening_u) <= 1.0:
        raise OutOfRangeError(f"limb_darkening_u = {limb_darkening_u!r} is invalid; allowed [0, 1]")
    return r


def _check_mask(horizon_mask) -> HorizonMask:
    mask = HorizonMask.level(0.0) if horizon_mask is None else horizon_mask
    if not isinstance(mask, HorizonMask):
        raise ConfigError(f"horizon_mask must be a HorizonMask or None, got {horizon_mask!r}")
    return mask


def _sun_tilt(shape, res: float, az_deg: float, window, moon_radius_m: float):
    """``(rows_term, cols_term)`` (rad, float64) with ``delta[r, c] = rows[r] + cols[c]``:
    how much higher the Sun stands at cell ``(r, c)`` of ``window`` than at the site origin
    (the grid centre), ``u / R`` for a displacement ``u`` towards the Sun (the local
    vertical tilts with the Moon's curvature)."""
    nrows, ncols = shape
    r0, c0, nr, nc = window
    a = math.radians(az_deg)
    x = (np.arange(c0, c0 + nc) + 0.5 - 0.5 * ncols) * res
    y = (0.5 * nrows - np.arange(r0, r0 + nr) - 0.5) * res
    return y * (math.cos(a) / moon_radius_m), x * (math.sin(a) / moon_radius_m)


def _tilt_bound(shape, res: float, moon_radius_m: float) -> float:
    """Largest |Sun tilt| over the grid (rad): half its diagonal over R."""
    return 0.5 * math.hypot(shape[0], shape[1]) * res / moon_radius_m


def _fraction_from_tan(
    t: np.ndarray,
    tm,
    *,
    el_deg: float,
    radius: float,
    lut: np.ndarray,
    tilt=None,
    tilt_bound: float = 0.0,
) -> np.ndarray:
    """Lit fraction (float32) from the tangent ``t`` of each cell's horizon (its local
    frame; NaN on nodata), the tangent ``tm`` of the outside horizon (scalar or array)
    and the Sun's elevation at the site origin.

    At a cell the Sun stands higher by ``delta`` = ``tilt`` (see :func:`_sun_tilt`; at
    most ``tilt_bound``); so do distant outside horizons, so the mask is compared with
    the Sun in the origin's frame: ``h - e`` at the cell is
    ``max(atan t - e - delta, m - e)``. Only exact arithmetic touches a pixel (no
    ``atan``/``acos``: ``tan(h - e) = (t - T) / (1 + t T)`` equals ``h - e`` to 4e-8 rad
    in the band; the segment area comes from a uniform lookup table), so the value of a
    cell never depends on the array it is computed in.
    """
    e = math.radians(el_deg)
    T = math.tan(e)
    cap = math.pi / 2 - 1e-6

    def tan_at(a: float) -> float:
        return math.tan(min(cap, max(-cap, a)))

    d = float(tilt_bound)
    lit_t, dark_t = tan_at(e - radius - d), tan_at(e + radius + d)
    lit_m, dark_m = tan_at(e - radius), tan_at(e + radius)
    tm_arr = np.asarray(tm, dtype=np.float64)
    surely_lit = (t <= lit_t) & (tm_arr <= lit_m)
    surely_dark = (t >= dark_t) | (tm_arr >= dark_m)
    frac = np.zeros(t.shape, dtype=np.float32)
    frac[surely_lit] = 1.0
    part = ~(surely_lit | surely_dark | np.isnan(t))
    idx = np.nonzero(part)
    tp = np.clip(t[idx].astype(np.float64), tan_at(e - 2 * radius - d), tan_at(e + 2 * radius + d))
    y = (tp - T) / (1.0 + tp * T)  # h - e in the origin's frame
    if tilt is not None:
        y -= tilt[0][idx[0]] + tilt[1][idx[1]]  # h - e at the cell
    tmp = tm_arr[idx] if tm_arr.ndim else tm_arr
    tmp = np.clip(tmp, tan_at(e - 2 * radius), tan_at(e + 2 * radius))
    y = np.fmax(y, (tmp - T) / (1.0 + tmp * T))
    v = -y / radius  # Sun centre above the effective horizon, in radii
    u = np.clip((v + 1.0) * (0.5 * (_LUT_N - 1)), 0.0, _LUT_N - 1.0)
    i = np.minimum(u.astype(np.int64), _LUT_N - 2)
    f = u - i
    frac[idx] = (lut[i] + f * (lut[i + 1] - lut[i])).astype(np.float32)
    frac[np.isnan(t)] = np.nan
    return frac


_LIGHTMAP_ARGS_DOC = """
    Args:
        dem: a :class:`~lunar_drake.terrain.heightfield.Heightfield` (file-backed ones are
            read tile by tile) or a 2-D array of heights (m; row 0 north, NaN nodata).
        sun_azimuth_deg: Sun azimuth, deg clockwise from grid north (site frame).
        sun_elevation_deg: elevation of the Sun's centre above the local horizontal at
            the site origin (the grid centre), deg, in [-89, 89]; a cell ``u`` m towards
            the Sun sees it ``u / R`` rad higher (lunar curvature).
        resolution_m: pixel size (m); required for arrays.
        horizon_mask: terrain outside the DEM; default a level horizon (0 deg), i.e. a
            plain. ``HorizonMask.none()`` lets only the DEM cast shadows.
        sun_radius_deg: solar angular radius (deg), default 0.2665.
        limb: ``"uniform"`` (default) or ``"darkened"`` (linear law, ``limb_darkening_u``).
        slopes_per_diameter: horizon slopes sampled per solar diameter (default 4).
        near_steps: steps of each cell's own ray computed exactly (default 16); the rest
            comes from the sweep lines.
        near_interior_steps: steps over which the interior maxima of the bilinear surface
            between grid lines are found (default 3).
        max_shadow_length_m: reach of shadow casters (m); default ``relief / tan(e - r)``
            capped at ``halo_cap_px`` pixels (default 4096). Farther casters are ignored,
            whatever the tiling -- put them in the ``horizon_mask``.
        tile_px: DEMs larger than this (either side) are computed in tiles of this size,
            each read with a halo of the shadow reach towards the Sun, on dask's threaded
            scheduler (default 4096).
        workers: threads (default 2).
        moon_radius_m: sphere radius for the curvature drop (default 1737.4 km).
        progress: tqdm progress bar over tiles.

    Returns:
        ``(rows, cols)`` float32 lit fraction in [0, 1], NaN on nodata; bit-identical for
        any ``tile_px`` and ``workers``.
"""


def lightmap(
    dem,
    *,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    resolution_m: float | None = None,
    horizon_mask: HorizonMask | None = None,
    sun_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
    limb: str = "uniform",
    limb_darkening_u: float = LIMB_DARKENING_U,
    slopes_per_diameter: int = 4,
    near_steps: int = 16,
    near_interior_steps: int = 3,
    max_shadow_length_m: float | None = None,
    halo_cap_px: int = 4096,
    tile_px: int = 4096,
    workers: int = 2,
    moon_radius_m: float = MOON_RADIUS_M,
    progress: bool = False,
) -> np.ndarray:
    """Fraction of the solar disk visible from each DEM cell (see the module docstring)."""
    arr = lightmap_dask(
        dem,
        sun_azimuth_deg=sun_azimuth_deg,
        sun_elevation_deg=sun_elevation_deg,
        resolution_m=resolution_m,
        horizon_mask=horizon_mask,
        sun_radius_deg=sun_radius_deg,
        limb=limb,
        limb_darkening_u=limb_darkening_u,
        slopes_per_diameter=slopes_per_diameter,
        near_steps=near_steps,
        near_interior_steps=near_interior_steps,
        max_shadow_length_m=max_shadow_length_m,
        halo_cap_px=halo_cap_px,
        tile_px=tile_px,
        workers=workers,
        moon_radius_m=moon_radius_m,
        progress=progress,
    )
    if isinstance(arr, np.ndarray):
        return arr
    return arr.compute(scheduler="threads", num_workers=int(workers))


lightmap.__doc__ += "\n" + _LIGHTMAP_ARGS_DOC


def lightmap_dask(
    dem,
    *,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    resolution_m: float | None = None,
    horizon_mask: HorizonMask | None = None,
    sun_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
    limb: str = "uniform",
    limb_darkening_u: float = LIMB_DARKENING_U,
    slopes_per_diameter: int = 4,
    near_steps: int = 16,
    near_interior_steps: int = 3,
    max_shadow_length_m: float | None = None,
    halo_cap_px: int = 4096,
    tile_px: int = 4096,
    workers: int = 2,
    moon_radius_m: float = MOON_RADIUS_M,
    progress: bool = False,
):
    """As :func:`lightmap`, but a lazy ``dask.array`` (``tile_px`` chunks) when the DEM
    is larger than one tile -- e.g. to stream it into a
    :class:`~lunar_drake.terrain.geotiff.GeoTiffWriter` with ``dask.array.store`` -- and
    the computed numpy array otherwise."""
    src, shape, res, read = as_grid(dem, resolution_m)
    az, el = _check_sun(sun_azimuth_deg, sun_elevation_deg)
    r = _check_disk(sun_radius_deg, limb, limb_darkening_u)
    mask = _check_mask(horizon_mask)
    if not (
        isinstance(slopes_per_diameter, int | np.integer)
        and not isinstance(slopes_per_diameter, bool)
        and slopes_per_diameter >= 1
    ):
        raise OutOfRangeError(
            f"slopes_per_diameter = {slopes_per_diameter!r} is invalid; an integer >= 1"
        )
    e = math.radians(el)
    R = float(moon_radius_m)
    dmax = _tilt_bound(shape, res, R) if math.isfinite(R) and R > 0 else 0.0
    cap = math.pi / 2 - 1e-6
    plan = band_plan(
        shape,
        res,
        height_range(src),
        azimuth_deg=az,
        tan_lo=math.tan(max(-cap, e - r - dmax)),  # the Sun's disk at every cell
        tan_hi=math.tan(min(cap, e + r + dmax)),
        max_dtau=(math.tan(e + r) - math.tan(e - r)) / int(slopes_per_diameter),
        near_steps=near_steps,
        near_interior_steps=near_interior_steps,
        max_shadow_length_m=max_shadow_length_m,
        halo_cap_px=halo_cap_px,
        moon_radius_m=moon_radius_m,
    )
    lut = _fraction_lut(limb, float(limb_darkening_u))
    dark = el + math.degrees(r) <= mask.min_elevation_deg()

    def tile(r0, r1, c0, c1, wk):
        if dark:  # the Sun is below the outside horizon everywhere
            z = np.asarray(read(r0, c0, r1 - r0, c1 - c0))
            return np.where(np.isnan(z), np.float32(np.nan), np.float32(0.0))
        t = plan.tile(read, r0, r1, c0, c1, workers=wk)
        win = (r0, c0, r1 - r0, c1 - c0)
        tm = mask.tan_on_grid(az, shape=shape, resolution_m=res, window=win)
        tilt = _sun_tilt(shape, res, az, win, R)
        return _fraction_from_tan(t, tm, el_deg=el, radius=r, lut=lut, tilt=tilt, tilt_bound=dmax)

    return tiled_dask(
        tile, shape, tile_px=tile_px, workers=workers, progress=progress, desc="lightmap"
    )


def lightmap_from_horizon(
    horizon,
    *,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    resolution_m: float | None = None,
    horizon_mask: HorizonMask | None = None,
    sun_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
    limb: str = "uniform",
    limb_darkening_u: float = LIMB_DARKENING_U,
) -> np.ndarray:
    """Lit fraction from precomputed horizons: a :class:`HorizonField` (interpolated at
    the Sun azimuth) or an array of horizon elevations (rad) along the Sun azimuth.

    The Sun's disk must lie inside the field's elevation range (its horizons are clipped
    to it). With ``resolution_m`` (m) the Sun's elevation change across the grid
    (distance towards the Sun / lunar radius) is applied as in :func:`lightmap`; without
    it, it is ignored (a gridded ``horizon_mask`` needs it).
    """
    az, el = _check_sun(sun_azimuth_deg, sun_elevation_deg)
    r = _check_disk(sun_radius_deg, limb, limb_darkening_u)
    mask = _check_mask(horizon_mask)
    if isinstance(horizon, HorizonField):
        lo, hi = horizon.elevation_range_deg
        rd = math.degrees(r)
        if el - rd < lo or el + rd > hi:
            raise OutOfRangeError(
                f"sun_elevation_deg = {sun_elevation_deg!r} puts the disk (radius {rd:.4f} deg) "
                f"outside the field's elevation range [{lo:g}, {hi:g}] deg"
            )
        h = horizon.at(az)
    else:
        h = np.asarray(horizon, dtype=np.float32)
        if h.ndim != 2:
            raise ConfigError(f"horizon has shape {h.shape}; a 2-D array (rad) is required")
    tilt, bound = None, 0.0
    if resolution_m is not None:
        res = float(resolution_m)
        if not (math.isfinite(res) and res > 0):
            raise OutOfRangeError(f"resolution_m = {resolution_m!r} is invalid; must be > 0")
        win = (0, 0, *h.shape)
        tilt = _sun_tilt(h.shape, res, az, win, MOON_RADIUS_M)
        bound = _tilt_bound(h.shape, res, MOON_RADIUS_M)
    elif mask.gridded:
        raise ConfigError("resolution_m is required with a gridded horizon_mask")
    tm = mask.tan_on_grid(az, shape=h.shape, resolution_m=float(resolution_m or 1.0))
    return _fraction_from_tan(
        np.tan(h),
        tm,
        el_deg=el,
        radius=r,
        lut=_fraction_lut(limb, float(limb_darkening_u)),
        tilt=tilt,
        tilt_bound=bound,
    )


# ----------------------------------------------------------------------------------------
# Hourly series and interpolation
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LightmapSeries:
    """Lightmaps at increasing sim times, for :func:`interpolate_lightmap`.

    Attributes:
        times_s: strictly increasing sim times (s).
        maps: float32 ``(n, rows, cols)`` lit fractions.
        sun_azimuth_deg, sun_elevation_deg: the Sun at each time (deg).
    """

    times_s: tuple[float, ...]
    maps: np.ndarray
    sun_azimuth_deg: tuple[float, ...] = ()
    sun_elevation_deg: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        t = np.asarray(self.times_s, dtype=np.float64).ravel()
        m = np.asarray(self.maps)
        if t.size < 1 or not np.isfinite(t).all() or np.any(np.diff(t) <= 0):
            raise ConfigError(
                f"LightmapSeries.times_s = {self.times_s!r} is invalid; need strictly "
                "increasing finite times (s)"
            )
        if m.ndim != 3 or m.shape[0] != t.size:
            raise ConfigError(
                f"LightmapSeries.maps has shape {m.shape}; expected ({t.size}, rows, cols)"
            )
        object.__setattr__(self, "times_s", tuple(float(v) for v in t))

    def at(self, t: float) -> np.ndarray:
        """Same as ``interpolate_lightmap(self, t)``."""
        return interpolate_lightmap(self, t)


def lightmap_series(dem, *, times, sun_az_el_at, **kwargs) -> LightmapSeries:
    """Lightmaps at ``times`` (e.g. hourly: ``np.arange(t0, t1 + 1, 3600.0)``, sim s).

    ``sun_az_el_at(t) -> (azimuth_deg, elevation_deg)`` gives the Sun in the site frame
    (e.g. from :mod:`lunar_drake.ephemeris`); ``kwargs`` go to :func:`lightmap`. The paper
    planned one lightmap per hour (the Sun moves about its own width in an hour) with
    linear interpolation in between; a penumbra sweeping across a cell in less than the
    interval is blurred in time by the interpolation.
    """
    ts = [float(t) for t in np.asarray(times, dtype=np.float64).ravel()]
    az, el, maps = [], [], []
    for t in ts:
        a, e = sun_az_el_at(t)
        az.append(float(a))
        el.append(float(e))
        maps.append(lightmap(dem, sun_azimuth_deg=a, sun_elevation_deg=e, **kwargs))
    return LightmapSeries(tuple(ts), np.stack(maps), tuple(az), tuple(el))


def interpolate_lightmap(series: LightmapSeries, t: float) -> np.ndarray:
    """Lightmap at sim time ``t`` (s): linear between the two bracketing maps (float32).

    Raises:
        OutOfRangeError: ``t`` outside ``[times_s[0], times_s[-1]]``.
    """
    ts = series.times_s
    t = float(t)
    if not (ts[0] <= t <= ts[-1]):
        raise OutOfRangeError(f"t = {t!r} s is outside the series' times [{ts[0]:g}, {ts[-1]:g}] s")
    if len(ts) == 1:
        return series.maps[0]
    i = min(int(np.searchsorted(ts, t, side="right")) - 1, len(ts) - 2)
    f = np.float32((t - ts[i]) / (ts[i + 1] - ts[i]))
    a, b = series.maps[i], series.maps[i + 1]
    return a + f * (b - a)


# ----------------------------------------------------------------------------------------
# Brute-force reference
# ----------------------------------------------------------------------------------------
def sunflower_disk(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points evenly spread over the unit disk (Vogel's sunflower / Fibonacci
    pattern: radius ``sqrt((k + 1/2) / n)``, angle ``k`` x the golden angle); ``(x, y)``."""
    k = np.arange(int(n), dtype=np.float64)
    rad = np.sqrt((k + 0.5) / n)
    ang = k * (math.pi * (3.0 - math.sqrt(5.0)))
    return rad * np.cos(ang), rad * np.sin(ang)


def lightmap_bruteforce(
    z,
    *,
    resolution_m: float,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    n_rays: int = 280,
    sun_radius_deg: float = SUN_ANGULAR_RADIUS_DEG,
    limb: str = "uniform",
    limb_darkening_u: float = LIMB_DARKENING_U,
    horizon_mask: HorizonMask | None = None,
    pixels=None,
    chunk_rays: int = 1 << 17,
    moon_radius_m: float = MOON_RADIUS_M,
) -> np.ndarray:
    """Reference lit fraction by marching ``n_rays`` rays per cell over the solar disk.

    As the paper: rays towards ``n_rays`` sunflower points of the disk (each with its own
    azimuth and elevation) start at the cell centre, on the surface. Each ray is marched
    cell by cell over the bilinear surface: between consecutive grid-line crossings the
    terrain along the ray is a quadratic, and so is its height above the ray (the ray
    rises by ``d tan(e) + d**2 / (2 R)``, R the lunar radius), so sampling the crossing
    and the segment midpoint gives that segment's maximum exactly; the Sun's elevation is
    the origin's plus ``u / R`` for a cell ``u`` m towards the Sun. A ray is blocked if
    the terrain rises above it anywhere -- including right at the start (self-shadowing
    by the cell's own slope) -- and free once it clears the DEM's maximum or leaves the
    DEM, where it must also clear ``horizon_mask`` (default a level horizon, 0 deg).
    ``limb="darkened"`` weights the rays by the linear limb-darkening law. Slow: for
    tests and benchmarks.

    Args:
        pixels: optional ``(rows, cols)`` index arrays: compute only those cells and
            return a 1-D array.

    Returns:
        float32 fraction, shape of ``z`` (or of ``pixels``); NaN on nodata.
    """
    _check_limb(limb)
    zz = np.asarray(z, dtype=np.float64)
    if zz.ndim != 2:
        raise ConfigError(f"z has shape {zz.shape}; a 2-D grid is required")
    az, el = _check_sun(sun_azimuth_deg, sun_elevation_deg)
    res = float(resolution_m)
    if not (math.isfinite(res) and res > 0):
        raise OutOfRangeError(f"resolution_m = {resolution_m!r} is invalid; must be > 0 (m)")
    if not (isinstance(n_rays, int | np.integer) and n_rays >= 1):
        raise OutOfRangeError(f"n_rays = {n_rays!r} is invalid; an integer >= 1")
    mask = HorizonMask.level(0.0) if horizon_mask is None else horizon_mask
    nr, nc = zz.shape
    if pixels is None:
        rows, cols = np.divmod(np.arange(nr * nc), nc)
    else:
        rows = np.asarray(pixels[0], dtype=np.int64).ravel()
        cols = np.asarray(pixels[1], dtype=np.int64).ravel()
    r = math.radians(float(sun_radius_deg))
    dx, dy = sunflower_disk(int(n_rays))
    e_k = math.radians(el) + r * dy
    az_k = math.radians(az) + r * dx / np.cos(e_k)
    if limb == "darkened":
        wk = 1.0 - limb_darkening_u * (1.0 - np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0, 1)))
    else:
        wk = np.ones(dx.size)
    wk = wk / wk.sum()
    # Outside horizon per ray (a gridded mask uses each cell's own profile).
    if mask.gridded:
        mask_el = np.stack(
            [
                np.asarray(
                    mask.elevation_on_grid(math.degrees(a), shape=(nr, nc), resolution_m=res)
                )[rows, cols]
                for a in az_k
            ],
            axis=1,
        )
    else:
        mask_el = np.array([float(mask.elevation_deg(math.degrees(a))) for a in az_k])[None, :]
    clear = e_k[None, :] > np.radians(mask_el)  # (cells or 1, rays)
    # The Sun stands higher by u / R at a cell u metres towards it from the grid centre.
    ux = (cols + 0.5 - 0.5 * nc) * res
    uy = (0.5 * nr - rows - 0.5) * res
    tilt = (ux * math.sin(math.radians(az)) + uy * math.cos(math.radians(az))) / moon_radius_m
    drow, dcol = -np.cos(az_k), np.sin(az_k)  # per pixel of horizontal distance
    with np.errstate(divide="ignore"):
        inv_c = np.where(np.abs(dcol) > 1e-15, 1.0 / np.abs(dcol), np.inf)
        inv_r = np.where(np.abs(drow) > 1e-15, 1.0 / np.abs(drow), np.inf)
    zmax = float(np.nanmax(zz))
    z0 = zz[rows, cols]
    k2 = res * res / (2.0 * moon_radius_m)

    def excess(s, r0, c0, h0, kk, tk):
        """Terrain height above the rays at distance ``s`` px (NaN outside the grid)."""
        h = bilinear_rows(zz, r0 + drow[kk] * s, c0 + dcol[kk] * s)
        return h - (h0 + s * res * tk + s * s * k2)

    out = np.zeros(rows.size)
    n_k = dx.size
    per = max(1, int(chunk_rays) // n_k)
    for s0 in range(0, rows.size, per):
        s1 = min(s0 + per, rows.size)
        nb = s1 - s0
        ci = np.repeat(np.arange(nb), n_k)  # cell within the chunk
        ki = np.tile(np.arange(n_k), nb)  # ray
        R0 = rows[s0:s1][ci].astype(np.float64)
        C0 = cols[s0:s1][ci].astype(np.float64)
        H0 = z0[s0:s1][ci]
        TAN = np.tan(e_k[ki] + tilt[s0:s1][ci])  # ray slope at its cell
        vis = np.zeros(ci.size, dtype=bool)
        act = np.flatnonzero(~np.isnan(H0))
        # Distance (px) of the next column / row crossing of each ray, and the last point.
        next_c = inv_c[ki].copy()
        next_r = inv_r[ki].copy()
        s_prev = np.zeros(ci.size)
        f_prev = np.zeros(ci.size)  # excess at s_prev (0 at the start)
        while act.size:
            kk = ki[act]
            r0, c0, h0, tk = R0[act], C0[act], H0[act], TAN[act]
            sp = s_prev[act]
            sn = np.minimum(next_c[act], next_r[act])
            fn = excess(sn, r0, c0, h0, kk, tk)
            fm = excess(0.5 * (sp + sn), r0, c0, h0, kk, tk)
            f0 = f_prev[act]
            inside = ~np.isnan(fn)
            # Quadratic through (0, f0), (1/2, fm), (1, fn): a l^2 + b l + f0.
            a = 2.0 * f0 - 4.0 * fm + 2.0 * fn
            b = -3.0 * f0 + 4.0 * fm - fn
            with np.errstate(divide="ignore", invalid="ignore"):
                lv = -b / (2.0 * a)
                fv = np.where((a < 0) & (lv > 0) & (lv < 1), f0 - b * b / (4.0 * a), -np.inf)
            # Leaving the grid mid-segment: judge the part inside by its midpoint only.
            seg_max = np.where(inside, np.fmax(np.fmax(fn, fv), fm), fm)
            blocked = seg_max > 0
            ray_top = h0 + sn * res * tk + sn * sn * k2
            free = ~blocked & (~inside | (ray_top > zmax))
            ok = clear[s0 + ci[act], kk] if mask.gridded else clear[0, kk]
            vis[act[free & ok]] = True
            # Advance.
            step_c = next_c[act] <= next_r[act]
            next_c[act] += np.where(step_c, inv_c[kk], 0.0)
            next_r[act] += np.where(step_c, 0.0, inv_r[kk])
            s_prev[act] = sn
            f_prev[act] = fn
            act = act[~(blocked | free)]
        out[s0:s1] = (vis.reshape(nb, n_k) * wk[None, :]).sum(axis=1)
    out[np.isnan(z0)] = np.nan
    out = out.astype(np.float32)
    return out if pixels is not None else out.reshape(nr, nc)


# ----------------------------------------------------------------------------------------
# Command line: lunar-drake lightmap DEM.tif --utc ISO --out lightmap.tif
# ----------------------------------------------------------------------------------------
def add_arguments(parser) -> None:
    """Adds the ``lunar-drake lightmap`` arguments to an ``argparse`` (sub)parser."""
    parser.add_argument("dem", help="DEM GeoTIFF (m, projected CRS in metres)")
    parser.add_argument("--out", required=True, help="output lightmap GeoTIFF (float32)")
    parser.add_argument("--utc", default=None, help="UTC time, ISO 8601 (uses the ephemeris)")
    parser.add_argument(
        "--sun-az", type=float, default=None, help="Sun azimuth (deg clockwise from grid north)"
    )
    parser.add_argument("--sun-el", type=float, default=None, help="Sun elevation (deg)")
    parser.add_argument("--limb", choices=LIMBS, default="uniform", help="solar limb model")
    parser.add_argument(
        "--outside-horizon-deg",
        type=float,
        default=0.0,
        help="elevation of the horizon outside the DEM (deg, default 0: a level plain)",
    )
    parser.add_argument(
        "--no-outside-horizon",
        action="store_true",
        help="only the DEM casts shadows (no terrain outside it)",
    )
    parser.add_argument(
        "--max-shadow-m", type=float, default=None, help="reach of shadow casters (m)"
    )
    parser.add_argument("--tile", type=int, default=4096, help="tile side (px)")
    parser.add_argument("--workers", type=int, default=2, help="worker threads")
    parser.add_argument(
        "--compress", default="deflate", help="GeoTIFF compression (deflate, lzw, zstd, none)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def sun_in_grid_frame(hf, utc: str) -> tuple[float, float]:
    """Sun ``(azimuth from grid north, elevation)`` (deg) at the DEM's centre at ``utc``.

    Uses :mod:`lunar_drake.ephemeris` (imported lazily): the Sun in the site's ENU frame,
    whose azimuth is turned into the grid frame by the grid azimuth of true north at the
    site (from the DEM's CRS: the meridian convergence of a polar stereographic grid).

    Raises:
        ConfigError: the ephemeris module is not available (pass --sun-az/--sun-el).
    """
    try:
        from lunar_drake.ephemeris.sun_earth import SiteLocation, enu_basis, sun_earth_enu
    except ImportError as exc:
        raise ConfigError(
            f"--utc needs lunar_drake.ephemeris, which is not available ({exc}); pass "
            "--sun-az and --sun-el (deg, azimuth clockwise from grid north) instead"
        ) from exc
    site, beta = site_and_grid_north(hf, enu_basis=enu_basis, SiteLocation=SiteLocation)
    se = sun_earth_enu(utc=utc, site=site)
    return (float(se.sun_azimuth_deg) + beta) % 360.0, float(se.sun_elevation_deg)


def site_and_grid_north(hf, *, enu_basis, SiteLocation) -> tuple:
    """``(SiteLocation at the DEM's centre, grid azimuth of true north (deg))``: add the
    second to an ENU azimuth to get one from grid north (the meridian convergence of a
    polar stereographic grid)."""
    from lunar_drake.terrain.crs import MOON_RADIUS_M as R
    from lunar_drake.terrain.crs import lonlat_to_xy, xy_to_lonlat

    ox, oy = hf.origin_xy
    lon, lat = (float(v) for v in xy_to_lonlat(ox, oy, crs=hf.crs))
    site = SiteLocation(lat, lon, 0.0)
    # Grid azimuth of true north: step 1 m along the site's ENU north and project.
    _east, north, up = enu_basis(site)
    p = up * R + north * 1.0
    lat1 = math.degrees(math.asin(p[2] / np.linalg.norm(p)))
    lon1 = math.degrees(math.atan2(p[1], p[0]))
    x1, y1 = lonlat_to_xy(lon1, lat1, crs=hf.crs)
    return site, math.degrees(math.atan2(float(x1) - ox, float(y1) - oy))


def run_cli(args) -> int:
    """``lunar-drake lightmap``: bake a lightmap GeoTIFF; returns the exit status (0).
    Wired in by :mod:`lunar_drake.cli.lightmap`."""
    import time

    from lunar_drake.files import check_output_file
    from lunar_drake.terrain.geotiff import GeoTiffWriter, write_geotiff
    from lunar_drake.terrain.heightfield import Heightfield

    if (args.sun_az is None) != (args.sun_el is None):
        raise ConfigError("give both --sun-az and --sun-el (deg), or neither and --utc")
    if args.sun_az is None and args.utc is None:
        raise ConfigError("give --utc ISO (ephemeris) or --sun-az DEG --sun-el DEG")
    compress = None if str(args.compress).lower() == "none" else args.compress
    # An unwritable --out fails now, in one line, not after the bake.
    check_output_file(args.out, what="lightmap")
    t0 = time.perf_counter()
    with Heightfield.open(args.dem) as hf:
        if args.sun_az is not None:
            az, el = float(args.sun_az), float(args.sun_el)
            how = "given"
        else:
            az, el = sun_in_grid_frame(hf, args.utc)
            how = f"ephemeris at {args.utc} UTC"
        mask = (
            HorizonMask.none()
            if args.no_outside_horizon
            else HorizonMask.level(args.outside_horizon_deg)
        )
        arr = lightmap_dask(
            hf,
            sun_azimuth_deg=az,
            sun_elevation_deg=el,
            horizon_mask=mask,
            limb=args.limb,
            max_shadow_length_m=args.max_shadow_m,
            tile_px=args.tile,
            workers=args.workers,
            progress=not args.no_progress,
        )
        kw = dict(transform=hf.transform, crs=hf.crs, nodata=float("nan"), compress=compress)
        if isinstance(arr, np.ndarray):
            write_geotiff(args.out, arr, **kw)
            lit = float(np.nanmean(arr))
        else:
            import dask.array as da

            nr, nc = hf.shape
            with GeoTiffWriter(args.out, height=nr, width=nc, dtype="float32", **kw) as w:
                da.store(arr, w, lock=False, scheduler="threads", num_workers=args.workers)
            lit = float("nan")
    print(
        f"Sun azimuth {az:.3f} deg (grid), elevation {el:.3f} deg ({how}); "
        + (f"mean lit fraction {lit:.3f}; " if math.isfinite(lit) else "")
        + f"{time.perf_counter() - t0:.1f} s -> {args.out}"
    )
    return 0
