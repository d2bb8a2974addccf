"""Terrain horizons along a Sun azimuth: the banded sweep engine, horizon angles, masks.

Conventions (see :mod:`lunar_drake.terrain`): ``z[row, col]`` in metres, row 0 north,
column 0 west; azimuths in degrees clockwise from grid north; elevations in degrees (or
radians where the name says ``_rad``) above the local horizontal. A cell's horizon
elevation ``h`` along an azimuth is the largest elevation angle of the terrain seen from
the cell centre, on the bilinear surface, along that azimuth.

Sweep lines
-----------
The grid is turned (transposed and/or flipped, never resampled) into a *canonical* frame
``(R, C)`` in which the Sun lies towards decreasing ``C`` and one step towards the Sun
moves ``(dR, dC) = (sigma, -1)``, ``|sigma| <= 1``. Sweep line ``k`` (an integer) crosses
canonical column ``C`` at fractional row ``k - sigma C``, where its height is linear
between the two rows around it (the bilinear surface there); samples are
``step = res sqrt(1 + sigma**2)`` apart. Pixel ``(R, C)`` lies between lines
``a = R + floor(sigma C)`` and ``a + 1`` at weight ``w = sigma C - floor(sigma C)``.

Banded horizons (:func:`band_plan`, :class:`BandPlan`)
------------------------------------------------------
Only the horizon inside a band ``[lo, hi]`` of elevations is resolved (for a lightmap,
the Sun's disk ``e -+ r``). A cell is lit at slope ``t`` iff no caster key
``zhat_j + tau x_j`` within the shadow reach exceeds its own (see curvature below). For
``M`` slopes ``tau_m`` spanning the band the maximum key over the reach is a
sliding-window maximum along each line (van Herk 1992, Pattern Recogn. Lett. 13, 517;
Gil & Werman 1993, IEEE PAMI 15, 504: three vector operations per sample whatever the
window), so every slope costs a few vectorised passes over the sheared grid (numpy,
float32 where its rounding is negligible). A pixel's caster envelope
``F(t) = S(t) - z`` (convex, decreasing in ``t``) is interpolated between its two lines,
and its root -- the tangent of ``h`` -- is the secant between the bracketing slopes
(exact where one caster dominates across the interval).

Interpolating between lines errs most for near casters (a lateral offset of a fraction
of a pixel changes their elevation angle a lot), so the first ``near_steps`` (default
16) steps of each cell's *own* ray are computed exactly: every column and row crossing
(linear between grid posts), the slope of the bilinear surface as the ray leaves the
cell centre (self-shadowing), and over the first ``near_interior_steps`` (3) steps the
interior maximum of the elevation angle of each quadratic piece of the surface between
grid lines (closed form). The sweep covers steps ``near + 1 .. reach``.

Shadow reach and tiling: casters farther than ``D = relief / tan(lo)`` cannot rise into
the band (``relief`` = max - min of the whole DEM); ``D`` is capped at ``halo_cap_px``
pixels (default 4096) or set explicitly. Casters beyond ``D`` are ignored everywhere --
in a whole-grid computation too -- and belong in the outside :class:`HorizonMask`. Large
grids are computed in tiles (dask, threads), each read with a halo of ``D`` towards the
Sun; every quantity is defined on global indices and a pixel only meets exact operations
(+, -, *, /, max, floor, sqrt), so a cell's value is bit-identical whatever the tiling.

Lunar curvature
---------------
A caster at horizontal distance ``d`` lies ``d**2 / (2 R)`` below the receiver's tangent
plane (R = 1737.4 km, IAU 2015 sphere; Archinal et al. 2018). Along a line with
coordinate ``x`` this is exact (to the parabolic approximation) with
``zhat = z - x**2 / (2 R)``::

    z_j - z_i - d**2 / (2 R) - t d  =  (zhat_j + tau x_j) - (zhat_i + tau x_i),
    tau = t + x_i / R

so a horizon of slope ``t`` at receiver ``i`` is a flat-ground horizon of slope ``tau``
in ``zhat``; the slope grid is widened by ``x / R`` across the grid to cover every
receiver. The effect is small on rover-scale DEMs (0.005 deg at 300 m) but reaches
0.5 deg at 30 km.

Approximations: within a pixel's far field (beyond ``near_steps``) heights come from
the two sweep lines around its ray (second order in the lateral offset); samples there
are taken at column crossings only; the secant root between sampled slopes.
"""

from __future__ import annotations

import itertools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.terrain.crs import MOON_RADIUS_M

__all__ = [
    "MOON_RADIUS_M",
    "BandPlan",
    "HorizonField",
    "HorizonMask",
    "SweepOrientation",
    "band_plan",
    "horizon_angles",
    "horizon_profile",
    "sweep_orientation",
]

NEG = -1.0e30
"""Height (m) standing for "no caster" (outside the grid or nodata); finite so that
linear interpolation never produces NaN."""


# ----------------------------------------------------------------------------------------
# Orientation
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepOrientation:
    """How a grid is turned into the canonical sweep frame for one azimuth.

    Attributes:
        transpose: canonical ``(R, C)`` = ``(col, row)`` (else ``(row, col)``).
        flip: canonical ``C`` runs backwards (``C = n - 1 - ...``).
        sigma: canonical rows moved per step towards the Sun, ``|sigma| <= 1``.
        step_px: horizontal distance per step (pixels), ``sqrt(1 + sigma**2)``.
        shape: canonical global shape ``(NR, NC)``.
    """

    transpose: bool
    flip: bool
    sigma: float
    step_px: float
    shape: tuple[int, int]

    def canon(self, a: np.ndarray) -> np.ndarray:
        """View of a grid-shaped array in the canonical frame."""
        if self.transpose:
            a = a.T
        if self.flip:
            a = a[:, ::-1]
        return a

    def uncanon(self, a: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`canon` (a view)."""
        if self.flip:
            a = a[:, ::-1]
        if self.transpose:
            a = a.T
        return a

    def rect_to_canon(self, r0: int, r1: int, c0: int, c1: int) -> tuple[int, int, int, int]:
        """Grid rectangle ``[r0, r1) x [c0, c1)`` -> canonical ``(R0, R1, C0, C1)``."""
        R0, R1, C0, C1 = (c0, c1, r0, r1) if self.transpose else (r0, r1, c0, c1)
        if self.flip:
            NC = self.shape[1]
            C0, C1 = NC - C1, NC - C0
        return R0, R1, C0, C1

    def rect_from_canon(self, R0: int, R1: int, C0: int, C1: int) -> tuple[int, int, int, int]:
        """Canonical rectangle -> grid ``(r0, r1, c0, c1)``."""
        if self.flip:
            NC = self.shape[1]
            C0, C1 = NC - C1, NC - C0
        return (C0, C1, R0, R1) if self.transpose else (R0, R1, C0, C1)


def _check_azimuth(azimuth_deg) -> float:
    a = float(azimuth_deg)
    if not math.isfinite(a):
        raise OutOfRangeError(f"azimuth = {azimuth_deg!r} deg is invalid; must be finite")
    return a


def sweep_orientation(azimuth_deg: float, shape: tuple[int, int]) -> SweepOrientation:
    """Canonical sweep frame for a Sun azimuth (deg clockwise from grid north)."""
    a = math.radians(_check_azimuth(azimuth_deg))
    dc, dr = math.sin(a), -math.cos(a)  # pixel-space direction towards the Sun
    nr, nc = int(shape[0]), int(shape[1])
    if abs(dc) >= abs(dr):
        transpose, flip, sigma, cshape = False, dc > 0, dr / abs(dc), (nr, nc)
    else:
        transpose, flip, sigma, cshape = True, dr > 0, dc / abs(dr), (nc, nr)
    # Snap round-off so exact axis / diagonal azimuths give exact line geometry.
    if abs(sigma) < 1e-12:
        sigma = 0.0
    elif abs(abs(sigma) - 1.0) < 1e-12:
        sigma = math.copysign(1.0, sigma)
    return SweepOrientation(
        transpose=transpose,
        flip=flip,
        sigma=float(sigma),
        step_px=math.sqrt(1.0 + sigma * sigma),
        shape=cshape,
    )


def line_shifts(sigma: float, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(floor(sigma C), sigma C - floor(sigma C))`` for global canonical columns ``C``."""
    sc = sigma * np.asarray(C, dtype=np.float64)
    s = np.floor(sc)
    return s.astype(np.int64), sc - s


def _padded_rows(
    zt: np.ndarray, lo: int, hi: int, *, edge_lo: bool = False, edge_hi: bool = False
) -> tuple[np.ndarray, int]:
    """``zt`` (steps, rows) as float64 with NaN -> NEG, padded with NEG so that row
    indices ``lo..hi`` (inclusive, window coordinates) are valid; returns (array, offset).

    ``edge_lo``/``edge_hi``: the first/last row is the grid's edge; one row beyond it
    repeats it (heights are clamped within one pixel of the grid, as
    :meth:`Heightfield.height` does in its half-pixel edge band), so that lines grazing
    the edge still see the edge row.
    """
    n = zt.shape[0 if zt.ndim == 1 else 1]
    pad_lo, pad_hi = max(0, -lo), max(0, hi - (n - 1))
    dt = zt.dtype if zt.dtype in (np.float32, np.float64) else np.float64
    out = np.empty((zt.shape[0], n + pad_lo + pad_hi), dtype=dt)
    out[:, :pad_lo] = NEG
    out[:, pad_lo + n :] = NEG
    body = out[:, pad_lo : pad_lo + n]
    body[...] = zt
    np.copyto(body, NEG, where=np.isnan(body), casting="unsafe")
    if edge_lo and pad_lo:
        out[:, pad_lo - 1] = out[:, pad_lo]
    if edge_hi and pad_hi:
        out[:, pad_lo + n] = out[:, pad_lo + n - 1]
    return out, pad_lo


# ----------------------------------------------------------------------------------------
# Outside-horizon masks
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HorizonMask:
    """Horizon of the terrain outside the DEM, as a function of azimuth.

    A 1-D profile (one site) or one profile per coarse cell. A DEM cell's effective
    horizon is ``max(local horizon, mask(azimuth))``.

    Attributes:
        azimuths_deg: strictly increasing azimuths (deg clockwise from grid north) within
            one turn (``a[-1] - a[0] < 360``); interpolation is linear and wraps around.
        elevations_deg: horizon elevation (deg) at each azimuth: shape ``(n_az,)`` for one
            profile, or ``(n_az, ny, nx)`` for a grid of profiles over ``bounds``.
        bounds: for gridded masks, ``(left, bottom, right, top)`` in site metres of the
            ``ny x nx`` cells (north-up, row 0 north); a DEM cell uses the profile of the
            coarse cell containing it (nearest, no blending across cells). None for 1-D.
    """

    azimuths_deg: tuple[float, ...]
    elevations_deg: np.ndarray
    bounds: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        az = np.asarray(self.azimuths_deg, dtype=np.float64).ravel()
        el = np.asarray(self.elevations_deg, dtype=np.float64)
        if az.size < 1 or not np.isfinite(az).all():
            raise ConfigError(
                f"HorizonMask.azimuths_deg = {self.azimuths_deg!r} is invalid; need >= 1 "
                "finite azimuth (deg)"
            )
        if az.size > 1 and (np.any(np.diff(az) <= 0) or az[-1] - az[0] >= 360.0):
            raise ConfigError(
                f"HorizonMask.azimuths_deg = {self.azimuths_deg!r} is invalid; need strictly "
                "increasing azimuths spanning less than 360 deg"
            )
        if el.ndim not in (1, 3) or el.shape[0] != az.size:
            raise ConfigError(
                f"HorizonMask.elevations_deg has shape {el.shape}; expected ({az.size},) or "
                f"({az.size}, ny, nx)"
            )
        if not np.isfinite(el).all() or np.any(np.abs(el) > 90.0):
            raise OutOfRangeError(
                "HorizonMask.elevations_deg must be finite and within [-90, 90] deg; got "
                f"range [{np.nanmin(el):g}, {np.nanmax(el):g}]"
            )
        if el.ndim == 3:
            if self.bounds is None or len(self.bounds) != 4:
                raise ConfigError(
                    "HorizonMask.bounds = (left, bottom, right, top) (site m) is required for "
                    f"a gridded mask; got {self.bounds!r}"
                )
            l, b, r, t = (float(v) for v in self.bounds)
            if not (r > l and t > b):
                raise ConfigError(f"HorizonMask.bounds = {self.bounds!r} is empty")
        object.__setattr__(self, "azimuths_deg", tuple(float(v) for v in az))
        el = el.copy()
        el.flags.writeable = False
        object.__setattr__(self, "elevations_deg", el)

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def level(cls, elevation_deg: float = 0.0) -> HorizonMask:
        """The same horizon elevation in every direction (default 0: a level horizon)."""
        return cls((0.0,), np.array([float(elevation_deg)]))

    @classmethod
    def none(cls) -> HorizonMask:
        """No outside terrain: only the DEM casts shadows (-90 deg everywhere)."""
        return cls.level(-90.0)

    @classmethod
    def from_dem(
        cls,
        z,
        *,
        resolution_m: float,
        points_xy,
        azimuths_deg,
        min_distance_m: float = 0.0,
        max_distance_m: float | None = None,
        moon_radius_m: float = MOON_RADIUS_M,
    ) -> HorizonMask:
        """A 1-D mask for one site point from a (coarse, regional) DEM.

        See :func:`horizon_profile`; ``points_xy`` is one ``(x, y)`` (site metres of the
        coarse DEM, origin at its centre) and the site height is taken from the DEM.
        """
        el = horizon_profile(
            z,
            resolution_m=resolution_m,
            points_xy=np.asarray(points_xy, dtype=np.float64).reshape(1, 2),
            azimuths_deg=azimuths_deg,
            min_distance_m=min_distance_m,
            max_distance_m=max_distance_m,
            moon_radius_m=moon_radius_m,
        )[0]
        return cls(tuple(np.asarray(azimuths_deg, dtype=np.float64)), el)

    @classmethod
    def from_dem_grid(
        cls,
        z,
        *,
        resolution_m: float,
        bounds: tuple[float, float, float, float],
        cells: tuple[int, int],
        azimuths_deg,
        origin_xy: tuple[float, float] = (0.0, 0.0),
        min_distance_m: float = 0.0,
        max_distance_m: float | None = None,
        moon_radius_m: float = MOON_RADIUS_M,
    ) -> HorizonMask:
        """A gridded mask: one profile per coarse cell over a local site's ``bounds``.

        Args:
            z: the regional (coarse) DEM (m), covering the site and its surroundings.
            resolution_m: its pixel size (m).
            bounds: ``(left, bottom, right, top)`` of the local DEM in *its* site frame
                (e.g. ``Heightfield.bounds``).
            cells: ``(ny, nx)`` profiles across the bounds (cell centres are the viewpoints).
            origin_xy: the local site origin in the regional DEM's site frame (m).
            min_distance_m: skip terrain closer than this (the part the local DEM holds);
                terrain counted twice does no harm (the effective horizon is a maximum)
                unless the coarse DEM is higher than the fine one there.
        """
        ny, nx = (int(v) for v in cells)
        if ny < 1 or nx < 1:
            raise OutOfRangeError(f"cells = {cells!r} is invalid; need (ny, nx) >= (1, 1)")
        l, b, r, t = (float(v) for v in bounds)
        cx = l + (np.arange(nx) + 0.5) * (r - l) / nx
        cy = t - (np.arange(ny) + 0.5) * (t - b) / ny
        X, Y = np.meshgrid(cx + float(origin_xy[0]), cy + float(origin_xy[1]))
        az = np.asarray(azimuths_deg, dtype=np.float64).ravel()
        el = horizon_profile(
            z,
            resolution_m=resolution_m,
            points_xy=np.stack([X.ravel(), Y.ravel()], axis=1),
            azimuths_deg=az,
            min_distance_m=min_distance_m,
            max_distance_m=max_distance_m,
            moon_radius_m=moon_radius_m,
        )
        return cls(tuple(az), el.T.reshape(az.size, ny, nx), bounds=(l, b, r, t))

    # -- queries ----------------------------------------------------------------------------
    @property
    def gridded(self) -> bool:
        return self.elevations_deg.ndim == 3

    def min_elevation_deg(self) -> float:
        return float(self.elevations_deg.min())

    def _interp_weights(self, azimuth_deg: float) -> tuple[int, int, float]:
        az = np.asarray(self.azimuths_deg)
        n = az.size
        if n == 1:
            return 0, 0, 0.0
        a0 = az[0]
        a = (float(azimuth_deg) - a0) % 360.0
        rel = az - a0
        i = int(np.searchsorted(rel, a, side="right")) - 1
        j = (i + 1) % n
        span = (rel[j] if j else 360.0) - rel[i]
        return i, j, (a - rel[i]) / span

    def elevation_deg(self, azimuth_deg: float) -> np.ndarray:
        """Horizon elevation (deg) at an azimuth: a 0-d array, or ``(ny, nx)`` if gridded."""
        i, j, f = self._interp_weights(azimuth_deg)
        e = self.elevations_deg
        return np.asarray(e[i] + f * (e[j] - e[i]))

    def elevation_on_grid(
        self, azimuth_deg: float, *, shape: tuple[int, int], resolution_m: float, window=None
    ) -> np.ndarray | float:
        """Horizon elevation (deg) at the DEM pixels of ``window`` (default: all).

        A scalar for a 1-D mask; for a gridded mask, a float64 array of the window's shape
        (each pixel takes the coarse cell containing its centre, clamped at the edges).
        """
        e = self.elevation_deg(azimuth_deg)
        if not self.gridded:
            return float(e)
        nrows, ncols = shape
        r0, c0, nr, nc = window if window is not None else (0, 0, nrows, ncols)
        x = (np.arange(c0, c0 + nc) + 0.5 - 0.5 * ncols) * resolution_m
        y = (0.5 * nrows - np.arange(r0, r0 + nr) - 0.5) * resolution_m
        l, b, r, t = self.bounds  # type: ignore[misc]
        ny, nx = e.shape
        ci = np.clip(np.floor((x - l) / (r - l) * nx).astype(np.int64), 0, nx - 1)
        ri = np.clip(np.floor((t - y) / (t - b) * ny).astype(np.int64), 0, ny - 1)
        return e[np.ix_(ri, ci)]

    def tan_on_grid(
        self, azimuth_deg: float, *, shape: tuple[int, int], resolution_m: float, window=None
    ) -> np.ndarray | float:
        """``tan`` of :meth:`elevation_on_grid` (evaluated on the coarse grid first, so a
        pixel's value never depends on the window)."""
        e = self.elevation_deg(azimuth_deg)
        if not self.gridded:
            return math.tan(math.radians(float(e)))
        t = np.tan(np.radians(e))
        nrows, ncols = shape
        r0, c0, nr, nc = window if window is not None else (0, 0, nrows, ncols)
        x = (np.arange(c0, c0 + nc) + 0.5 - 0.5 * ncols) * resolution_m
        y = (0.5 * nrows - np.arange(r0, r0 + nr) - 0.5) * resolution_m
        l, b, r, top = self.bounds  # type: ignore[misc]
        ny, nx = t.shape
        ci = np.clip(np.floor((x - l) / (r - l) * nx).astype(np.int64), 0, nx - 1)
        ri = np.clip(np.floor((top - y) / (top - b) * ny).astype(np.int64), 0, ny - 1)
        return t[np.ix_(ri, ci)]


def bilinear_rows(z: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """Bilinear heights at fractional (row, col); NaN outside ``[0, n-1]``."""
    nr, nc = z.shape
    inside = (row >= 0) & (row <= nr - 1) & (col >= 0) & (col <= nc - 1)
    r = np.clip(row, 0, nr - 1)
    c = np.clip(col, 0, nc - 1)
    r0 = np.minimum(np.floor(r).astype(np.int64), max(nr - 2, 0))
    c0 = np.minimum(np.floor(c).astype(np.int64), max(nc - 2, 0))
    fr, fc = r - r0, c - c0
    r1, c1 = np.minimum(r0 + 1, nr - 1), np.minimum(c0 + 1, nc - 1)
    top = z[r0, c0] + fc * (z[r0, c1] - z[r0, c0])
    bot = z[r1, c0] + fc * (z[r1, c1] - z[r1, c0])
    out = top + fr * (bot - top)
    return np.where(inside, out, np.nan)


def horizon_profile(
    z,
    *,
    resolution_m: float,
    points_xy,
    azimuths_deg,
    min_distance_m: float = 0.0,
    max_distance_m: float | None = None,
    step_px: float = 0.5,
    moon_radius_m: float = MOON_RADIUS_M,
) -> np.ndarray:
    """Horizon elevation (deg) seen from points of a DEM, per azimuth, by ray marching.

    For each point (on the surface, height bilinear from ``z``) and azimuth, the maximum
    elevation angle ``atan((z(d) - z0 - d**2 / (2 R)) / d)`` over distances
    ``min_distance_m <= d <= max_distance_m`` (default: to the DEM edge) in steps of
    ``step_px`` pixels, heights bilinear. Use ``min_distance_m`` = the distance to the
    edge of a local DEM to get the part of the horizon that lies *outside* it, e.g. from
    a decimated regional DEM (:meth:`Heightfield.decimated`). -90 where no sample exists.

    Args:
        z: 2-D DEM (m), row 0 north; NaN cells are skipped.
        resolution_m: pixel size (m).
        points_xy: ``(n, 2)`` site coordinates (m; origin at the DEM centre).
        azimuths_deg: azimuths (deg clockwise from grid north).

    Returns:
        ``(n, n_az)`` float64 elevations (deg).
    """
    zz = np.asarray(z, dtype=np.float64)
    if zz.ndim != 2:
        raise ConfigError(f"z has shape {zz.shape}; a 2-D grid is required")
    res = float(resolution_m)
    if not (math.isfinite(res) and res > 0):
        raise OutOfRangeError(f"resolution_m = {resolution_m!r} is invalid; must be > 0 (m)")
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    az = np.radians(np.asarray(azimuths_deg, dtype=np.float64).ravel())
    nr, nc = zz.shape
    prow = nr / 2 - 0.5 - pts[:, 1] / res
    pcol = pts[:, 0] / res + nc / 2 - 0.5
    z0 = bilinear_rows(zz, prow, pcol)
    if np.isnan(z0).any():
        i = int(np.flatnonzero(np.isnan(z0))[0])
        raise OutOfRangeError(f"points_xy[{i}] = {tuple(pts[i])} m is outside the DEM or on nodata")
    dmax = math.hypot(nr, nc) * res if max_distance_m is None else float(max_distance_m)
    d = np.arange(max(float(min_distance_m), step_px * res), dmax + 1e-9, step_px * res)
    out = np.full((pts.shape[0], az.size), -90.0)
    if d.size == 0:
        return out
    dc, dr = np.sin(az), -np.cos(az)
    for i in range(pts.shape[0]):
        rows = prow[i] + dr[:, None] * d[None, :] / res
        cols = pcol[i] + dc[:, None] * d[None, :] / res
        h = bilinear_rows(zz, rows, cols)
        ang = (h - z0[i] - d * d / (2.0 * moon_radius_m)) / d
        best = np.fmax.reduce(ang, axis=1)
        ok = ~np.isnan(best)
        out[i, ok] = np.degrees(np.arctan(best[ok]))
    return out


# ----------------------------------------------------------------------------------------
# Banded horizon engine
# ----------------------------------------------------------------------------------------
def _running_max(k: np.ndarray, out: np.ndarray, *, reverse: bool = False) -> None:
    """``out[..., i, :] = max(k[..., 0..i, :])`` along axis -2 (or from the end), one
    vector operation per position (numpy's ``accumulate`` along a non-last axis is
    several times slower). ``k`` and ``out`` may have a leading block axis."""
    n = k.shape[-2]
    idx = range(n - 1, -1, -1) if reverse else range(n)
    prev = None
    for i in idx:
        if prev is None:
            out[..., i, :] = k[..., i, :]
        else:
            np.maximum(out[..., prev, :], k[..., i, :], out=out[..., i, :])
        prev = i


def _window_max_excl(k: np.ndarray, W: int, j0: int, skip: int = 0) -> np.ndarray:
    """``V[j] = max(k[max(0, j - W) : j - skip])`` (NEG when empty), ``j = j0 .. n-1``.

    Van Herk (1992) / Gil & Werman (1993): with blocks of ``W' = W - skip`` rows aligned
    at row 0, an inclusive window ``[i - W' + 1, i]`` is the suffix maximum of one block
    and the prefix maximum of the next, so a row costs three maxima whatever ``W``; all
    blocks advance together (``W'`` vector operations per pass).
    """
    n, L = k.shape
    Wp = W - skip  # inclusive window length, G[i] = max(k[i - Wp + 1 .. i]), V[j] = G[j-skip-1]
    out = np.empty((n - j0, L), dtype=k.dtype)
    a = max(j0, skip + 1)  # first j with a non-empty window
    if a >= n or Wp < 1:
        out[...] = NEG
        return out
    i0, i1 = a - skip - 1, n - skip - 1  # rows of G needed: [i0, i1)
    o0 = a - j0
    out[:o0] = NEG
    if Wp >= i1:  # every window starts at row 0: a prefix maximum
        g = np.empty((i1, L), dtype=k.dtype)
        _running_max(k[:i1], g)
        out[o0:] = g[i0:i1]
        return out
    base = (max(0, i0 - Wp + 1) // Wp) * Wp  # first row of the first block touched
    nb = -(-(i1 - base) // Wp)
    kb = np.empty((nb * Wp, L), dtype=k.dtype)
    kb[: i1 - base] = k[base:i1]
    kb[i1 - base :] = NEG
    g = np.empty_like(kb)
    h = np.empty_like(kb)
    _running_max(kb.reshape(nb, Wp, L), g.reshape(nb, Wp, L))
    _running_max(kb.reshape(nb, Wp, L), h.reshape(nb, Wp, L), reverse=True)
    split = min(max(i0, Wp - 1), i1)  # rows i < Wp - 1 have windows starting at row 0
    if split > i0:
        out[o0 : o0 + split - i0] = g[i0 - base : split - base]
    if i1 > split:
        np.maximum(
            h[split - Wp + 1 - base : i1 - Wp + 1 - base],
            g[split - base : i1 - base],
            out=out[o0 + split - i0 :],
        )
    return out


@dataclass(frozen=True)
class _Band:
    """Global parameters of one bake (identical for every tile)."""

    sigma: float
    step_m: float
    NR: int  # canonical global rows
    NC: int  # canonical global columns (x origin at NC / 2)
    taus: np.ndarray  # (M,) slope grid (tan)
    dtau: float
    W: int  # shadow reach in steps
    near: int  # steps computed exactly per pixel (near field)
    near_interior: int  # steps over which interior maxima of the bilinear pieces are found
    zref: float  # global reference height (m) for float32 near-field arithmetic
    dtype: type  # far-field float type (float32 where its rounding is negligible)
    moon_radius_m: float


@dataclass(frozen=True)
class BandPlan:
    """Global geometry of one banded-horizon computation (identical for every tile).

    Attributes:
        orient: sweep frame. band: kernel parameters. shape: grid shape.
        resolution_m: pixel size. azimuth_deg: azimuth of the rays (deg).
        tan_range: ``(tan lo, tan hi)`` of the elevation band.
        reach_m: distance up to which casters are considered (m).
    """

    orient: SweepOrientation
    band: _Band
    shape: tuple[int, int]
    resolution_m: float
    azimuth_deg: float
    tan_range: tuple[float, float]
    reach_m: float

    def halo_window(self, r0: int, r1: int, c0: int, c1: int):
        """Canonical receiver rectangle of grid rows [r0, r1) x cols [c0, c1) and the
        canonical window (with its halo of ``reach`` towards the Sun) that determines it."""
        o = self.orient
        Ra, Rb, Ca, Cb = o.rect_to_canon(r0, r1, c0, c1)
        C0 = max(0, Ca - self.band.W)
        drift = o.sigma * (Cb - C0)  # rows a ray drifts over the processed steps
        R0 = max(0, Ra - 3 + min(0, math.floor(drift)))
        R1 = min(o.shape[0], Rb + 3 + max(0, math.ceil(drift)))
        return (Ra, Rb, Ca, Cb), (R0, R1, C0, Cb)

    def tile(self, read, r0: int, r1: int, c0: int, c1: int, *, workers: int = 1):
        """Horizon tangents (float32, grid frame) of rows [r0, r1) x cols [c0, c1).

        ``read(row0, col0, nrows, ncols)`` returns heights of a grid window. Values: the
        tangent of the horizon elevation (curvature included) where it lies in the band;
        outside it any value <= tan lo / >= tan hi (-inf/+inf when only the band's
        slopes were tested); NaN on nodata.
        """
        o = self.orient
        recv, win = self.halo_window(r0, r1, c0, c1)
        gr0, gr1, gc0, gc1 = o.rect_from_canon(*win)
        zwin = np.asarray(read(gr0, gc0, gr1 - gr0, gc1 - gc0))
        t = _band_tan_canonical(
            o.canon(zwin), R0=win[0], C0=win[2], recv=recv, band=self.band, workers=workers
        )
        return o.uncanon(t)


def band_plan(
    shape,
    resolution_m: float,
    zrange: tuple[float, float],
    *,
    azimuth_deg: float,
    tan_lo: float,
    tan_hi: float,
    max_dtau: float,
    near_steps: int = 16,
    near_interior_steps: int = 3,
    max_shadow_length_m: float | None = None,
    halo_cap_px: int = 4096,
    moon_radius_m: float = MOON_RADIUS_M,
) -> BandPlan:
    """Plan a banded horizon computation (see the module docstring).

    ``[tan_lo, tan_hi]``: band of horizon slopes resolved; ``max_dtau``: largest spacing
    of the sampled slopes; ``zrange``: (min, max) height of the whole DEM (m). The
    shadow reach is ``relief / tan_lo`` (casters farther away cannot rise above the band)
    capped at ``halo_cap_px`` pixels, or ``max_shadow_length_m``.
    """
    for name, v, lo in (
        ("near_steps", near_steps, 0),
        ("near_interior_steps", near_interior_steps, 0),
        ("halo_cap_px", halo_cap_px, 1),
    ):
        if not (isinstance(v, int | np.integer) and not isinstance(v, bool) and v >= lo):
            raise OutOfRangeError(f"{name} = {v!r} is invalid; an integer >= {lo}")
    R = float(moon_radius_m)
    if not (math.isfinite(R) and R > 0):
        raise OutOfRangeError(f"moon_radius_m = {moon_radius_m!r} is invalid; must be > 0 (m)")
    res = float(resolution_m)
    orient = sweep_orientation(azimuth_deg, shape)
    step_m = res * orient.step_px
    zmin, zmax = zrange
    if max_shadow_length_m is not None:
        reach = float(max_shadow_length_m)
        if not (math.isfinite(reach) and reach > 0):
            raise OutOfRangeError(
                f"max_shadow_length_m = {max_shadow_length_m!r} is invalid; must be > 0 (m)"
            )
    else:
        reach = (zmax - zmin) / tan_lo if tan_lo > 0 else math.inf
        reach = min(reach, int(halo_cap_px) * res)
    W = max(1, math.ceil(reach / step_m))
    NR, NC = orient.shape
    x_min, x_max = -NC / 2.0 * step_m, (NC / 2.0 - 1.0) * step_m
    tau0 = tan_lo + x_min / R  # receiver i tests t = tau - x_i / R: cover the band for all x
    tau1 = tan_hi + x_max / R
    M = max(2, math.ceil((tau1 - tau0) / max_dtau - 1e-9) + 1)
    dtau = (tau1 - tau0) / (M - 1)
    # Far-field keys zhat + tau x in float32 if their rounding, seen from the nearest
    # far-field caster, stays below 1e-5 rad (0.0014 in lit fraction); else float64.
    x_abs = max(abs(x_min), abs(x_max))
    key_max = (zmax - zmin) + max(abs(tau0), abs(tau1)) * x_abs + x_abs**2 / (2 * R) + 1.0
    far_d = (int(near_steps) + 1) * step_m
    dtype = np.float32 if key_max * 2.0**-23 / far_d < 1e-5 else np.float64
    band = _Band(
        sigma=orient.sigma,
        step_m=step_m,
        NR=NR,
        NC=NC,
        taus=tau0 + np.arange(M) * dtau,
        dtau=dtau,
        W=W,
        near=int(near_steps),
        near_interior=int(near_interior_steps),
        zref=float(zmin),
        dtype=dtype,
        moon_radius_m=R,
    )
    return BandPlan(
        orient=orient,
        band=band,
        shape=(int(shape[0]), int(shape[1])),
        resolution_m=res,
        azimuth_deg=float(azimuth_deg),
        tan_range=(float(tan_lo), float(tan_hi)),
        reach_m=W * step_m,
    )


def _band_tan_canonical(
    zc: np.ndarray,
    *,
    R0: int,
    C0: int,
    recv: tuple[int, int, int, int],
    band: _Band,
    workers: int = 1,
) -> np.ndarray:
    """Tangent of the local horizon (curvature included) for receivers, canonical frame.

    ``zc``: heights (m, NaN nodata) of the canonical window whose top-left pixel has global
    canonical index ``(R0, C0)``; ``recv = (Ra, Rb, Ca, Cb)``: global canonical receiver
    rectangle inside it. Returns float32 ``(Rb - Ra, Cb - Ca)``: the exact near-field
    horizon or, where the far field is higher, ``-inf`` (lit at the lowest slope of the
    band), ``+inf`` (shadowed at the highest) or the secant root in between; NaN on nodata.
    """
    Ra, Rb, Ca, Cb = recv
    far = np.full((Rb - Ra, Cb - Ca), -np.inf, dtype=np.float32)
    near = np.empty_like(far)
    # Jobs write disjoint parts: far-field line chunks own disjoint pixels, near-field
    # jobs disjoint rows of their own array; the two are combined at the end.
    jobs = []
    if band.W > band.near:
        sweep = _Sweep(zc, R0=R0, C0=C0, recv=recv, band=band)
        jobs += [(lambda p=p: sweep.run(p, far)) for p in sweep.parts(workers)]

    def near_rows(r0: int, r1: int) -> None:
        near[r0 - Ra : r1 - Ra] = _near_field(zc, R0=R0, C0=C0, recv=(r0, r1, Ca, Cb), band=band)

    for p in np.array_split(np.arange(Ra, Rb), max(1, min(workers, Rb - Ra))):
        if p.size:
            jobs.append(lambda p=p: near_rows(int(p[0]), int(p[-1]) + 1))
    if workers > 1 and len(jobs) > 1:
        with ThreadPoolExecutor(max_workers=workers) as ex:
            for f in [ex.submit(j) for j in jobs]:
                f.result()
    else:
        for j in jobs:
            j()
    np.fmax(far, near, out=far)
    far[np.isnan(zc[Ra - R0 : Rb - R0, Ca - C0 : Cb - C0])] = np.nan
    return far


class _Sweep:
    """Far field (steps ``near + 1 .. W``) of one window, on sheared sweep lines.

    Line profiles ``prof[j, k]`` (line ``a_lo + k`` at window step ``j``) and receiver
    heights ``zpix[j, a]`` (pixel on line ``a`` at receiver step ``j``) are built once,
    as ``zhat - zref``, and line chunks are then swept independently (threads).
    """

    def __init__(self, zc, *, R0: int, C0: int, recv, band: _Band) -> None:
        Ra, Rb, Ca, Cb = recv
        nr = zc.shape[0]
        self.recv, self.band = recv, band
        self.nC = nC = Cb - C0
        self.jr0 = jr0 = Ca - C0
        Cg = np.arange(C0, Cb, dtype=np.int64)
        s, w = line_shifts(band.sigma, Cg)
        self.sr = sr = s[jr0:]
        self.a_lo = a_lo = Ra + int(sr.min())  # receiver lines: pixel R on line R + s_C
        self.a_hi = a_hi = Rb - 1 + int(sr.max())
        n = a_hi - a_lo + 1
        dt = band.dtype
        self.x = x = (Cg - band.NC / 2.0) * band.step_m
        zrel = x * x / (2.0 * band.moon_radius_m)  # zhat - zref = (z - zref) - zrel
        lo = a_lo - int(s.max()) - 1 - R0
        hi = a_hi + 1 - int(s.min()) - R0
        zt = (zc[:, :nC].T - band.zref).astype(np.float32)  # small numbers: float32 is fine
        zt_pad, pad = _padded_rows(zt, lo, hi, edge_lo=R0 == 0, edge_hi=R0 + nr == band.NR)
        self.prof = prof = np.empty((nC, n + 1), dtype=dt)
        self.zpix = zpix = np.empty((nC - jr0, n), dtype=dt)
        for j in range(nC):
            # Line k passes (1 - w) of the way from row k - s - 1 to row k - s.
            o = a_lo - int(s[j]) - 1 - R0 + pad
            a = zt_pad[j, o : o + n + 1]
            b = zt_pad[j, o + 1 : o + n + 2]
            np.subtract(a, b, out=prof[j], dtype=dt)
            prof[j] *= w[j]
            prof[j] += b
            prof[j] -= zrel[j]
            if j >= jr0:
                zpix[j - jr0] = b[:n]  # pixel row a - s = line a's lower row
                zpix[j - jr0] -= zrel[j]
        self.w = w[jr0:, None].astype(dt)

    def parts(self, workers: int) -> list[tuple[int, int]]:
        """Line ranges ``[a0, a1)`` of ~4 M samples each (and at least one per worker)."""
        n = self.a_hi - self.a_lo + 1
        per = max(32, min(n, (1 << 22) // max(1, self.nC)))
        k = max(-(-n // per), min(workers, -(-n // 32)))
        edges = np.linspace(self.a_lo, self.a_hi + 1, k + 1).round().astype(int)
        return [(int(a), int(b)) for a, b in itertools.pairwise(edges) if b > a]

    def run(self, lines: tuple[int, int], out: np.ndarray) -> None:
        """Writes ``max(out, t)`` for receivers on lines ``[a0, a1)``, ``t`` being -inf
        (lit at the lowest slope), +inf (dark at the highest) or the secant root of
        ``F(t) = S(t) - z = 0`` between the bracketing slopes."""
        band, jr0 = self.band, self.jr0
        Ra, Rb, Ca, Cb = self.recv
        a0, a1 = lines
        k0 = a0 - self.a_lo
        n = a1 - a0
        dt = band.dtype
        prof = self.prof[:, k0 : k0 + n + 1]
        zpix = self.zpix[:, k0 : k0 + n]
        x, xr = self.x, self.x[jr0:]
        key = np.empty(prof.shape, dtype=dt)
        F = np.empty(zpix.shape, dtype=dt)
        F_prev = np.empty_like(F)
        t = np.full(zpix.shape, np.inf, dtype=np.float32)
        for m, tau in enumerate(band.taus):
            np.add(prof, (tau * x).astype(dt)[:, None], out=key)
            V = _window_max_excl(key, band.W, jr0, skip=band.near)
            np.subtract(V[:, 1:], V[:, :-1], out=F)
            F *= self.w
            F += V[:, :-1]
            F -= zpix
            F -= (tau * xr).astype(dt)[:, None]  # F = S(t) - z at t = tau - x / R
            if m == 0:
                t[F <= 0] = -np.inf
            else:
                cross = (F <= 0) & (F_prev > 0)
                if cross.any():
                    fa, fb = F_prev[cross].astype(np.float64), F[cross].astype(np.float64)
                    xs = np.broadcast_to(xr[:, None], cross.shape)[cross]
                    ta = band.taus[m - 1] - xs / band.moon_radius_m
                    t[cross] = (ta + fa / (fa - fb) * band.dtau).astype(np.float32)
            F, F_prev = F_prev, F
        # Unshear into the receiver frame: pixel (R, C) is line a = R + s_C.
        sr = self.sr
        for j in range(Cb - Ca):
            r_lo = max(Ra, a0 - int(sr[j]))
            r_hi = min(Rb, a1 - int(sr[j]))
            if r_hi > r_lo:
                o = r_lo + int(sr[j]) - a0
                dst = out[r_lo - Ra : r_hi - Ra, j]
                np.fmax(dst, t[j, o : o + r_hi - r_lo], out=dst)


def _near_field(zc, *, R0, C0, recv, band: _Band) -> np.ndarray:
    """Exact tangent of the horizon from the first ``band.near`` steps of each receiver's
    own ray (float32; -inf where no sample exists).

    Along a ray the bilinear surface is a quadratic between consecutive grid-line
    crossings. The horizon is sampled at every column and row crossing (linear between
    the two grid posts there), plus the slope at the start (the ray leaves the cell
    centre inside the first cell, whose maximum elevation is at one of its ends) and,
    over the first ``band.near_interior`` steps, the interior maximum of the elevation
    angle of each quadratic piece (from its midpoint; closed form). Interpolating
    between sweep lines errs most for near casters, hence this exact near field. All
    offsets are the same for every receiver, so each sample is a shifted slice; rows are
    processed in cache-sized blocks.
    """
    Ra, Rb, Ca, Cb = recv
    nr = zc.shape[0]
    sig = band.sigma
    m0 = min(band.near, band.W)
    # Window padded with NaN (a ray leaving the grid meets no caster): rows by the drift
    # of m0 steps + 2 each side, columns on the left by m0 + 1.
    drift = math.ceil(abs(sig) * m0) + 2
    pc = m0 + 1
    zp = np.full((Rb - Ra + 2 * drift, Cb - C0 + pc), np.nan, dtype=np.float32)
    rs0, rs1 = max(0, Ra - drift - R0), min(nr, Rb + drift - R0)  # source rows (window)
    zp[rs0 + R0 - Ra + drift : rs1 + R0 - Ra + drift, pc:] = zc[rs0:rs1, : Cb - C0] - band.zref
    c0, c1 = Ca - C0 + pc, Cb - C0 + pc
    # Sample plan: (mu, row offset, col offset, row fraction, col fraction) per crossing.
    mus = {float(m) for m in range(1, m0 + 1)}
    if sig != 0.0:
        mus |= {n / abs(sig) for n in range(1, math.floor(abs(sig) * m0) + 1)}
    mus = sorted(mus)

    def offsets(mu: float):
        y = sig * mu
        ri, ci = math.floor(y), math.floor(mu)
        return ri, ci, np.float32(y - ri), np.float32(mu - ci)

    inv_step = np.float32(1.0 / band.step_m)
    dsign = 1 if sig >= 0 else -1
    out = np.empty((Rb - Ra, Cb - Ca), dtype=np.float32)
    block = max(1, (1 << 16) // max(1, Cb - Ca))
    for b0 in range(0, Rb - Ra, block):
        b1 = min(b0 + block, Rb - Ra)
        r0, r1 = b0 + drift, b1 + drift

        def at(dr: int, dc: int, r0=r0, r1=r1) -> np.ndarray:
            return zp[r0 + dr : r1 + dr, c0 - dc : c1 - dc]

        z0 = at(0, 0)

        def height(mu: float, z0=z0, at=at) -> np.ndarray:
            """Bilinear height above the receiver ``mu`` steps towards the Sun."""
            ri, ci, fy, fx = offsets(mu)
            a = at(ri, ci)
            h = a - z0
            if fx:
                h += fx * (at(ri, ci + 1) - a)
            if fy:
                top = at(ri + 1, ci) - a
                if fx:
                    top += fx * (at(ri + 1, ci + 1) - at(ri, ci + 1) - top)
                h += fy * top
            return h

        # Self-shadowing slope at the centre: d/dmu of the bilinear surface, first cell.
        best = at(0, 1) - z0
        if sig != 0.0:
            best += np.float32(abs(sig)) * (at(dsign, 0) - z0)
        best *= inv_step
        best[np.isnan(best)] = -np.inf
        prev_mu, prev_h = 0.0, None
        for mu in mus:
            h = height(mu)
            dm = mu * band.step_m
            g = h - np.float32(dm * dm / (2 * band.moon_radius_m))
            g *= np.float32(1.0 / dm)
            np.fmax(best, g, out=best)
            if prev_h is not None and mu <= band.near_interior:
                # q(lam) = A lam^2 + B lam + fa over the piece, distance u = D + E lam:
                # g(u) = q / u = alpha u + beta + gamma / u has an interior maximum
                # beta - 2 sqrt(alpha gamma) at u* = sqrt(gamma / alpha) if alpha, gamma < 0.
                fm = height(0.5 * (prev_mu + mu))
                D = np.float32(prev_mu * band.step_m)
                E = np.float32((mu - prev_mu) * band.step_m)
                A = 2.0 * (prev_h + h) - 4.0 * fm
                B = 4.0 * fm - 3.0 * prev_h - h
                alpha = A * np.float32(1.0 / (E * E))
                beta = B * np.float32(1.0 / E) - (2.0 * D) * alpha
                gamma = (alpha * D - B * np.float32(1.0 / E)) * D + prev_h
                with np.errstate(invalid="ignore", divide="ignore"):
                    ag = alpha * gamma
                    us2 = gamma / alpha  # u*^2
                    ok = (alpha < 0) & (gamma < 0) & (us2 > D * D) & (us2 < (D + E) * (D + E))
                    v = np.where(ok, beta - 2.0 * np.sqrt(np.where(ok, ag, 0)), -np.inf)
                np.fmax(best, v, out=best)
            prev_mu, prev_h = mu, h
        out[b0:b1] = best
    return out


# ----------------------------------------------------------------------------------------
# Grid sources and tiling
# ----------------------------------------------------------------------------------------
def as_grid(dem, resolution_m):
    """``(source, shape, resolution, reader)``: reader(r0, c0, nr, nc) -> float array."""
    from lunar_drake.terrain.heightfield import Heightfield

    if isinstance(dem, Heightfield):
        if resolution_m is not None and not math.isclose(
            float(resolution_m), dem.resolution_m, rel_tol=1e-9
        ):
            raise ConfigError(
                f"resolution_m = {resolution_m!r} disagrees with the Heightfield's "
                f"{dem.resolution_m!r} m; leave it out"
            )
        return dem, dem.shape, dem.resolution_m, dem.read_window
    z = np.asarray(dem)
    if z.ndim != 2 or z.size == 0 or z.dtype.kind not in "fiu":
        raise ConfigError(
            f"dem has shape {z.shape} and dtype {z.dtype}; a non-empty 2-D numeric grid or a "
            "Heightfield is required"
        )
    if resolution_m is None:
        raise ConfigError("resolution_m (m) is required when dem is an array")
    res = float(resolution_m)
    if not (math.isfinite(res) and res > 0):
        raise OutOfRangeError(f"resolution_m = {resolution_m!r} is invalid; must be > 0 (m)")
    if z.dtype not in (np.float32, np.float64):
        z = z.astype(np.float64)

    def read(r0, c0, nr, nc):
        return z[r0 : r0 + nr, c0 : c0 + nc]

    return z, z.shape, res, read


def height_range(src) -> tuple[float, float]:
    """``(min, max)`` height (m) of the whole DEM (a file is scanned once, by windows)."""
    from lunar_drake.terrain.heightfield import Heightfield

    if isinstance(src, Heightfield):
        m, n = max(src.shape), 1
        while m > 1:
            m, n = -(-m // 2), n + 1
        zmin, zmax = src.pyramid(start_level=n - 1).levels[-1]
        lo, hi = float(zmin[0, 0]), float(zmax[0, 0])
    else:
        lo, hi = float(np.nanmin(src)), float(np.nanmax(src))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        from lunar_drake.errors import NoDataError

        raise NoDataError("the DEM holds no valid data: every cell is nodata")
    return lo, hi


def compute_tiled(tile_fn, shape, *, tile_px: int, workers: int, progress: bool, desc: str):
    """Run ``tile_fn(r0, r1, c0, c1, workers) -> float32 block`` over the grid: directly
    (threads inside) when it fits one tile, else per ``tile_px`` block on dask's threaded
    scheduler (see :func:`tiled_dask`). Returns a numpy array."""
    arr = tiled_dask(tile_fn, shape, tile_px=tile_px, workers=workers, progress=progress, desc=desc)
    if isinstance(arr, np.ndarray):
        return arr
    return arr.compute(scheduler="threads", num_workers=int(workers))


def tiled_dask(tile_fn, shape, *, tile_px: int, workers: int, progress: bool, desc: str):
    """A lazy dask array of ``tile_fn`` blocks (``tile_px`` chunks) for grids larger than
    one tile; the computed numpy array otherwise."""
    if not (isinstance(tile_px, int | np.integer) and tile_px >= 16):
        raise OutOfRangeError(f"tile_px = {tile_px!r} is invalid; an integer >= 16 px")
    if not (isinstance(workers, int | np.integer) and workers >= 1):
        raise OutOfRangeError(f"workers = {workers!r} is invalid; an integer >= 1")
    nr, nc = shape
    tile = int(tile_px)
    if max(nr, nc) <= tile:
        return tile_fn(0, nr, 0, nc, int(workers))
    import dask.array as da

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=-(-nr // tile) * -(-nc // tile), desc=desc, unit="tile")

    def block(x, block_info=None):
        (r0, r1), (c0, c1) = block_info[None]["array-location"]
        out = tile_fn(r0, r1, c0, c1, 1)
        if bar is not None:
            bar.update(1)
        return out

    template = da.zeros(shape, chunks=(tile, tile), dtype=np.uint8)
    return template.map_blocks(block, dtype=np.float32, meta=np.empty((0, 0), np.float32))


# ----------------------------------------------------------------------------------------
# Horizon angles over an elevation band, at a few azimuths
# ----------------------------------------------------------------------------------------
def horizon_angles(
    dem,
    *,
    azimuth_deg: float,
    resolution_m: float | None = None,
    elevation_range_deg: tuple[float, float] = (-2.0, 20.0),
    resolution_deg: float = 0.05,
    near_steps: int = 16,
    near_interior_steps: int = 3,
    max_shadow_length_m: float | None = None,
    halo_cap_px: int = 4096,
    tile_px: int = 4096,
    workers: int = 2,
    moon_radius_m: float = MOON_RADIUS_M,
    progress: bool = False,
) -> np.ndarray:
    """Elevation (rad) of each cell's horizon along ``azimuth_deg``, from the DEM itself.

    The maximum elevation angle of the terrain seen from the cell centre (on the
    surface) along the azimuth, lunar curvature included, clipped to
    ``elevation_range_deg``: a value at a bound means "at or beyond". Same engine as
    :func:`lunar_drake.render.lightmap.lightmap` with the band widened to the range:
    slopes are sampled every ``resolution_deg`` and the horizon is the secant root between
    them (exact where one caster dominates across the interval), so the cost grows with
    ``range / resolution``. Bit-identical for any ``tile_px``/``workers``.

    Args:
        dem: Heightfield or 2-D array (m; then ``resolution_m`` is required).
        azimuth_deg: deg clockwise from grid north.
        elevation_range_deg: ``(lo, hi)`` band resolved, within (-89, 89).

    Returns:
        float32 ``(rows, cols)`` elevations (rad); NaN on nodata.
    """
    src, shape, res, read = as_grid(dem, resolution_m)
    lo, hi = (float(v) for v in elevation_range_deg)
    if not (-89.0 < lo < hi < 89.0):
        raise OutOfRangeError(
            f"elevation_range_deg = {elevation_range_deg!r} is invalid; need -89 < lo < hi < 89"
        )
    if not (math.isfinite(float(resolution_deg)) and 0 < float(resolution_deg) <= hi - lo):
        raise OutOfRangeError(
            f"resolution_deg = {resolution_deg!r} is invalid; allowed (0, {hi - lo:g}] deg"
        )
    t_lo, t_hi = math.tan(math.radians(lo)), math.tan(math.radians(hi))
    plan = band_plan(
        shape,
        res,
        height_range(src),
        azimuth_deg=_check_azimuth(azimuth_deg) % 360.0,
        tan_lo=t_lo,
        tan_hi=t_hi,
        max_dtau=math.radians(float(resolution_deg)),
        near_steps=near_steps,
        near_interior_steps=near_interior_steps,
        max_shadow_length_m=max_shadow_length_m,
        halo_cap_px=halo_cap_px,
        moon_radius_m=moon_radius_m,
    )

    def tile(r0, r1, c0, c1, wk):
        t = plan.tile(read, r0, r1, c0, c1, workers=wk)
        out = np.arctan(np.clip(t, np.float32(t_lo), np.float32(t_hi)))
        return out.astype(np.float32)

    return compute_tiled(
        tile, shape, tile_px=tile_px, workers=workers, progress=progress, desc="horizon"
    )


@dataclass(frozen=True)
class HorizonField:
    """Per-cell horizon elevations at a few azimuths, interpolated in between.

    At the poles the Sun's azimuth moves ~0.5 deg/hour, so horizons at a few azimuths
    spanning a period give the lit fraction at any time of it cheaply
    (:func:`lunar_drake.render.lightmap.lightmap_from_horizon`). Interpolation is linear
    in elevation between the two bracketing azimuths -- an approximation where a caster's
    silhouette changes quickly with azimuth (shadow edges parallel to the Sun direction).

    Attributes:
        azimuths_deg: strictly increasing azimuths (deg), spanning < 360.
        elevations_rad: float32 ``(n_az, rows, cols)`` horizon elevations (rad), clipped
            to ``elevation_range_deg``.
        elevation_range_deg: band the elevations resolve.
    """

    azimuths_deg: tuple[float, ...]
    elevations_rad: np.ndarray
    elevation_range_deg: tuple[float, float]

    def __post_init__(self) -> None:
        az = np.asarray(self.azimuths_deg, dtype=np.float64).ravel()
        el = np.asarray(self.elevations_rad)
        if az.size < 1 or np.any(np.diff(az) <= 0) or (az[-1] - az[0] >= 360.0):
            raise ConfigError(
                f"HorizonField.azimuths_deg = {self.azimuths_deg!r} is invalid; need strictly "
                "increasing azimuths spanning less than 360 deg"
            )
        if el.ndim != 3 or el.shape[0] != az.size:
            raise ConfigError(
                f"HorizonField.elevations_rad has shape {el.shape}; expected ({az.size}, rows, "
                "cols)"
            )
        object.__setattr__(self, "azimuths_deg", tuple(float(v) for v in az))

    @classmethod
    def compute(cls, dem, *, azimuths_deg, **kwargs) -> HorizonField:
        """:func:`horizon_angles` at each azimuth (same keyword arguments)."""
        az = [float(a) for a in np.asarray(azimuths_deg, dtype=np.float64).ravel()]
        rng = kwargs.get("elevation_range_deg", (-2.0, 20.0))
        maps = [horizon_angles(dem, azimuth_deg=a, **kwargs) for a in az]
        return cls(tuple(az), np.stack(maps), (float(rng[0]), float(rng[1])))

    def at(self, azimuth_deg: float) -> np.ndarray:
        """Horizon elevations (rad, float32) at an azimuth within the field's span."""
        az = np.asarray(self.azimuths_deg)
        a = az[0] + (float(azimuth_deg) - az[0]) % 360.0
        if a > az[-1] + 1e-9:
            raise OutOfRangeError(
                f"azimuth {azimuth_deg!r} deg is outside the field's azimuths "
                f"[{az[0]:g}, {az[-1]:g}] deg"
            )
        if az.size == 1:
            return self.elevations_rad[0]
        i = min(int(np.searchsorted(az, a, side="right")) - 1, az.size - 2)
        f = np.float32((a - az[i]) / (az[i + 1] - az[i]))
        e0, e1 = self.elevations_rad[i], self.elevations_rad[i + 1]
        return e0 + f * (e1 - e0)
