"""Illumination over a year and surface temperatures (numpy/scipy; no Drake).

Grid conventions of :mod:`lunar_drake.terrain`: ``z[row, col]`` (m), row 0 north,
column 0 west; x east, y north; azimuths clockwise from grid north.

* :func:`illumination`: for each sector of the Sun's envelope (:mod:`.sun_envelope`)
  one hull sweep (:mod:`.sweep`, tile-invariant) gives each cell's horizon along the
  sector's azimuth, hence its lit fraction at the sector's highest elevation (permanent
  shadow: never lit in any sector) and at its elevation quantiles (time-mean flux); the
  absorbed direct flux is ``(1 - A) S f cos(i)`` on the DEM's own slope. One more sweep
  gives the lit fraction and flux at the epoch.
* :func:`view_factor`: the cosine-weighted share of each cell's sky that terrain fills
  above its tangent plane, from horizons on coarse cells (:func:`sky_horizons`).
* :func:`terrain_source`: the terrain's direct flux averaged around each coarse cell
  (the source of the infrared and scattered light), upsampled bilinearly.
* :func:`temperature`: radiative equilibrium with the terrain's infrared and scattered
  light and the geothermal flux (see :class:`~.config.ThermalConfig` for the
  approximation).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numba
import numpy as np
from scipy import ndimage

from lunar_drake.errors import ConfigError
from lunar_drake.render.horizon import HorizonMask, sweep_orientation
from lunar_drake.render.lightmap import SUN_ANGULAR_RADIUS_DEG
from lunar_drake.science.config import ThermalConfig
from lunar_drake.science.sun_envelope import SunEnvelope
from lunar_drake.science.sweep import (
    EPOCH,
    SECTOR,
    Sweep,
    canonical_dem,
    horizon_tangents,
    set_threads,
)

#: Stefan-Boltzmann constant (W m^-2 K^-4).
SIGMA_SB = 5.670374419e-8


def surface_normals(z: np.ndarray, resolution_m: float) -> np.ndarray:
    """Unit normals ``(3, rows, cols)`` (x east, y north, z up) by central differences
    (one-sided at the edges)."""
    dz_dr, dz_dc = np.gradient(np.asarray(z, np.float64), resolution_m)
    n = np.stack([-dz_dc, dz_dr, np.ones_like(dz_dc)])  # dz/dy = -dz/drow
    return n / np.sqrt((n * n).sum(axis=0))


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector towards the Sun (x east, y north, z up)."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(a) * math.cos(e), math.cos(a) * math.cos(e), math.sin(e)])


@dc.dataclass(frozen=True)
class Illumination:
    """Direct sunlight over the envelope's span and at the epoch (canonical arrays of
    the DEM's shape).

    Attributes:
        ever_lit: uint8: some of the Sun's disk seen at some time (1).
        q_max_w_m2: highest absorbed direct flux (W/m^2, float32).
        q_mean_w_m2: time-mean absorbed direct flux (W/m^2, float32).
        q_now_w_m2: absorbed direct flux at the epoch (W/m^2, float32).
        lit_now: visible fraction of the Sun's disk at the epoch (float32).
    """

    ever_lit: np.ndarray
    q_max_w_m2: np.ndarray
    q_mean_w_m2: np.ndarray
    q_now_w_m2: np.ndarray
    lit_now: np.ndarray


def _mask_deg(mask: HorizonMask | None, azimuth_deg: float) -> float:
    """The outside horizon (deg) along an azimuth; a 1-D mask only."""
    if mask is None:
        return 0.0
    if not isinstance(mask, HorizonMask) or mask.gridded:
        raise ConfigError(
            f"horizon_mask = {mask!r} is invalid for the world model; a 1-D HorizonMask "
            "(one profile for the site) or None (a level plain)"
        )
    return float(mask.elevation_deg(azimuth_deg))


def sweep_jobs(envelope: SunEnvelope, *, sun_azimuth_deg: float, sun_elevation_deg: float,
               sun_distance_au: float, config: ThermalConfig,
               horizon_mask: HorizonMask | None) -> list:  # fmt: skip
    """The sweeps of :func:`illumination`: ``(azimuth_deg, elevations_deg, absorbed flux
    W/m^2, weight of each mean level, epoch?)`` per sector the Sun clears the outside
    horizon in, then the epoch's."""
    r = SUN_ANGULAR_RADIUS_DEG
    absorb = 1.0 - config.bond_albedo
    jobs = []
    for b in range(envelope.azimuth_deg.size):
        az = float(envelope.azimuth_deg[b])
        if envelope.weight[b] <= 0 or envelope.el_max_deg[b] + r <= _mask_deg(horizon_mask, az):
            continue
        levels = [float(e) for e in envelope.el_levels_deg[b]]
        flux = absorb * config.solar_constant_w_m2 / float(envelope.distance_au[b]) ** 2
        w = float(envelope.weight[b]) / len(levels)
        jobs.append((az, [float(envelope.el_max_deg[b]), *levels], flux, w, False))
    flux_now = absorb * config.solar_constant_w_m2 / float(sun_distance_au) ** 2
    jobs.append((float(sun_azimuth_deg) % 360.0, [float(sun_elevation_deg)], flux_now, 0.0, True))
    return jobs


def illumination(
    z: np.ndarray,
    *,
    resolution_m: float,
    envelope: SunEnvelope,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    sun_distance_au: float = 1.0,
    config: ThermalConfig | None = None,
    horizon_mask: HorizonMask | None = None,
    chunk: int = 512,
    near: int = 3,
    workers: int = 2,
    progress=None,
) -> Illumination:
    """Permanent shadow and direct fluxes of DEM ``z`` (see the module docstring): one
    hull sweep (:mod:`.sweep`) per sector of ``envelope`` and one at the epoch's Sun.

    ``horizon_mask``: terrain outside the DEM along each azimuth (a 1-D mask; default a
    level plain, 0 deg). ``progress(done, total)`` is called after each sweep.
    """
    cfg = config or ThermalConfig()
    z = np.asarray(z)
    shape = z.shape
    r = SUN_ANGULAR_RADIUS_DEG
    lit = np.zeros(shape, np.uint8)
    q_max = np.zeros(shape, np.float32)
    q_mean = np.zeros(shape, np.float32)
    q_now = np.zeros(shape, np.float32)
    lit_now = np.zeros(shape, np.float32)
    jobs = sweep_jobs(envelope, sun_azimuth_deg=sun_azimuth_deg,
                      sun_elevation_deg=sun_elevation_deg, sun_distance_au=sun_distance_au,
                      config=cfg, horizon_mask=horizon_mask)  # fmt: skip
    set_threads(workers)
    # Sweeps sharing a canonical frame share one canonical copy of the DEM.
    jobs.sort(key=lambda j: (sweep_orientation(j[0], shape).transpose,
                             sweep_orientation(j[0], shape).flip))  # fmt: skip
    zc, key = None, None
    for i, (az, els, flux, w, epoch) in enumerate(jobs):
        o = sweep_orientation(az, shape)
        if (o.transpose, o.flip) != key:
            key, zc = (o.transpose, o.flip), None
            zc = canonical_dem(z, o)
        sw = Sweep(z, azimuth_deg=az, resolution_m=resolution_m, chunk=chunk, near=near,
                   canonical=zc)  # fmt: skip
        par = sw.sun_par(flux_w_m2=flux, mask_deg=_mask_deg(horizon_mask, az),
                         radius_deg=r, w_mean=w)  # fmt: skip
        if epoch:
            sw.run(EPOCH, par, els, o.canon(lit_now), o.canon(q_now), o.canon(lit))
        else:
            sw.run(SECTOR, par, els, o.canon(q_max), o.canon(q_mean), o.canon(lit))
        if progress is not None:
            progress(i + 1, len(jobs))
    return Illumination(lit, q_max, q_mean, q_now, lit_now)


def coarse_factor(resolution_m: float, config: ThermalConfig | None = None) -> int:
    """Pixels per side of the coarse cells of the view factor and the terrain's infrared
    (``config.view_resolution_m``; at least 1)."""
    cfg = config or ThermalConfig()
    return max(1, round(cfg.view_resolution_m / resolution_m))


def block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """Means over ``k x k`` blocks (the edge rows and columns repeated to fill the last
    ones), float64."""
    a = np.asarray(a)
    if k == 1:
        return a.astype(np.float64)
    rows, cols = a.shape
    out = np.empty((-(-rows // k), -(-cols // k)))
    _block_mean(a, int(k), out)
    return out


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _block_mean(a, k, out):  # pragma: no cover - numba
    rows, cols = a.shape
    for bi in numba.prange(out.shape[0]):
        for bj in range(out.shape[1]):
            total = 0.0
            for i in range(bi * k, bi * k + k):
                ii = min(i, rows - 1)
                for j in range(bj * k, bj * k + k):
                    total += a[ii, min(j, cols - 1)]
            out[bi, bj] = total / (k * k)


def upsample(coarse: np.ndarray, k: int, rows: range, ncols: int) -> np.ndarray:
    """Bilinear values of ``coarse`` (cells of ``k x k`` pixels) at the centres of pixel
    rows ``rows`` and columns ``0..ncols-1`` (edge values held beyond the outer
    centres); each pixel's value depends only on its global position."""
    out = np.empty((len(rows), ncols))
    _bilinear_rows(np.asarray(coarse, np.float64), int(k), rows.start, out)
    return out


@numba.njit(cache=True, error_model="numpy", inline="always")
def _axis(i, k, n):  # pragma: no cover - numba
    """Lower coarse index and weight of pixel index ``i`` (cells of ``k`` pixels)."""
    u = min(max((i + 0.5) / k - 0.5, 0.0), n - 1.0)
    i0 = min(math.floor(u), max(n - 2, 0))
    return i0, min(i0 + 1, n - 1), u - i0


@numba.njit(cache=True, error_model="numpy", inline="always")
def _bilinear(coarse, k, r, c):  # pragma: no cover - numba
    r0, r1, fr = _axis(r, k, coarse.shape[0])
    c0, c1, fc = _axis(c, k, coarse.shape[1])
    top = coarse[r0, c0] * (1.0 - fc) + coarse[r0, c1] * fc
    bottom = coarse[r1, c0] * (1.0 - fc) + coarse[r1, c1] * fc
    return top * (1.0 - fr) + bottom * fr


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _bilinear_rows(coarse, k, r0, out):  # pragma: no cover - numba
    for i in numba.prange(out.shape[0]):
        for c in range(out.shape[1]):
            out[i, c] = _bilinear(coarse, k, r0 + i, c)


def sky_horizons(
    z: np.ndarray, *, resolution_m: float, config: ThermalConfig | None = None, workers: int = 2
) -> np.ndarray:
    """``sin^2`` of the horizon at ``config.view_azimuths`` azimuths on the DEM
    block-averaged by :func:`coarse_factor` (``(n_az, rows_c, cols_c)``), the horizon
    clipped to ``[0, view_max_deg]``."""
    cfg = config or ThermalConfig()
    k = coarse_factor(resolution_m, cfg)
    return sky_horizons_coarse(block_mean(z, k), resolution_m=resolution_m * k, config=cfg,
                               workers=workers)  # fmt: skip


def sky_horizons_coarse(zc: np.ndarray, *, resolution_m: float,
                        config: ThermalConfig | None = None,
                        workers: int = 2) -> np.ndarray:  # fmt: skip
    """:func:`sky_horizons` of the DEM already block-averaged (``zc``, pixel
    ``resolution_m``)."""
    cfg = config or ThermalConfig()
    hi = math.radians(cfg.view_max_deg)
    out = np.empty((cfg.view_azimuths, *zc.shape))
    for j in range(cfg.view_azimuths):
        t = horizon_tangents(zc, azimuth_deg=360.0 * j / cfg.view_azimuths,
                             resolution_m=resolution_m, workers=workers)  # fmt: skip
        out[j] = np.sin(np.clip(np.arctan(t), 0.0, hi)) ** 2
    return out


def view_factor_rows(z: np.ndarray, sin2_h: np.ndarray, *, resolution_m: float, k: int,
                     rows: range) -> np.ndarray:  # fmt: skip
    """The view factor (-) of pixel ``rows`` (see :func:`view_factor`) from the coarse
    horizons ``sin2_h`` of :func:`sky_horizons`."""
    out = np.empty((len(rows), z.shape[1]), np.float64)
    sin_a, cos_a = _view_azimuths(sin2_h.shape[0])
    _view_rows(np.asarray(z), sin2_h, sin_a, cos_a, float(resolution_m), int(k), rows.start, out)
    return out


def _view_azimuths(n: int) -> tuple[np.ndarray, np.ndarray]:
    a = 2.0 * np.pi * np.arange(n) / n
    return np.sin(a), np.cos(a)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _view_at(z, zr0, nr, sin2_h, sin_a, cos_a, res, k, r, c):  # pragma: no cover - numba
    """View factor of pixel ``(r, c)`` of a grid of ``nr`` rows whose rows ``zr0..`` are
    ``z`` (holding ``r``'s neighbours): the coarse horizons above its tangent plane."""
    nc = z.shape[1]
    i = r - zr0
    # dz/dx (east) and dz/dy (north) per metre, central (one-sided at the edges).
    if nc == 1:
        gx = 0.0
    elif c == 0:
        gx = (z[i, 1] - z[i, 0]) / res
    elif c == nc - 1:
        gx = (z[i, c] - z[i, c - 1]) / res
    else:
        gx = (z[i, c + 1] - z[i, c - 1]) / (2.0 * res)
    if nr == 1:
        gy = 0.0
    elif r == 0:
        gy = -(z[i + 1, c] - z[i, c]) / res
    elif r == nr - 1:
        gy = -(z[i, c] - z[i - 1, c]) / res
    else:
        gy = -(z[i + 1, c] - z[i - 1, c]) / (2.0 * res)
    f = 0.0
    rc, cc = r // k, c // k
    for j in range(sin_a.size):
        tan_e = max(0.0, gx * sin_a[j] + gy * cos_a[j])
        f += max(0.0, sin2_h[j, rc, cc] - tan_e * tan_e / (1.0 + tan_e * tan_e))
    return f / sin_a.size


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _view_rows(z, sin2_h, sin_a, cos_a, res, k, r0, out):  # pragma: no cover - numba
    for i in numba.prange(out.shape[0]):
        for c in range(out.shape[1]):
            out[i, c] = _view_at(z, 0, z.shape[0], sin2_h, sin_a, cos_a, res, k, r0 + i, c)


def temperature_rows(z: np.ndarray, q_w_m2: np.ndarray, sources: np.ndarray, sin2_h: np.ndarray,
                     *, resolution_m: float, rows: range, z_row0: int = 0,
                     grid_rows: int | None = None,
                     config: ThermalConfig | None = None) -> np.ndarray:  # fmt: skip
    """Temperatures (K, float32 ``(n, len(rows), cols)``) of pixel ``rows`` of DEM ``z``
    for ``n`` absorbed direct fluxes ``q_w_m2`` (``(n, len(rows), cols)``), with their
    coarse terrain sources ``sources`` (``(n, rows_c, cols_c)``, :func:`terrain_source`)
    and the coarse horizons ``sin2_h`` (:func:`sky_horizons`).

    Radiative equilibrium ``eps sigma T^4 = q + Q_env + q_geo`` with the terrain's
    infrared and scattered sunlight ``Q_env = F (eps M_ir + (1 - A) M_vis)``: ``F`` the
    view factor (:func:`view_factor`), the terrain's emission at its direct-light
    equilibrium ``M_ir = S + q_geo`` and its scattered light ``M_vis = A S / (1 - A)``,
    ``S`` the source upsampled bilinearly (see :class:`~.config.ThermalConfig`).

    ``z`` may be a window of the DEM: its rows ``z_row0..`` of a grid of ``grid_rows``
    (holding the row before and after ``rows`` where the grid has them)."""
    cfg = config or ThermalConfig()
    k = coarse_factor(resolution_m, cfg)
    sin_a, cos_a = _view_azimuths(sin2_h.shape[0])
    out = np.empty(np.shape(q_w_m2), np.float32)
    consts = np.array([cfg.emissivity, cfg.bond_albedo, cfg.geothermal_w_m2, SIGMA_SB])
    z = np.asarray(z)
    nr = z.shape[0] if grid_rows is None else int(grid_rows)
    _temperature_rows(z, int(z_row0), nr, np.asarray(q_w_m2), np.asarray(sources, np.float64),
                      sin2_h, sin_a, cos_a, float(resolution_m), int(k), rows.start, consts,
                      out)  # fmt: skip
    return out


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _temperature_rows(z, zr0, nr, q, src, sin2_h, sin_a, cos_a, res, k, r0, consts,
                      out):  # fmt: skip  # pragma: no cover
    eps, a, q_geo, sigma = consts[0], consts[1], consts[2], consts[3]
    for i in numba.prange(out.shape[1]):
        r = r0 + i
        for c in range(out.shape[2]):
            view = _view_at(z, zr0, nr, sin2_h, sin_a, cos_a, res, k, r, c)
            for m in range(out.shape[0]):
                s = _bilinear(src[m], k, r, c)
                total = q[m, i, c] + view * ((eps + a) * s + eps * q_geo) + q_geo
                out[m, i, c] = math.sqrt(math.sqrt(total / (eps * sigma)))


def view_factor(
    z: np.ndarray,
    *,
    resolution_m: float,
    config: ThermalConfig | None = None,
    workers: int = 2,
) -> np.ndarray:
    """Cosine-weighted share of each cell's sky filled by terrain that rises above the
    cell's own tangent plane (-): ``mean_k (sin^2 h_k - sin^2 e_k)``, ``h_k`` the horizon
    of the cell's coarse block (:func:`sky_horizons`: the DEM block-averaged to about
    ``config.view_resolution_m``, resolved to ``config.view_max_deg``; the infrared
    environment is a large-scale effect) and ``e_k`` the tangent plane's elevation along
    azimuth ``k`` of ``config.view_azimuths`` (a uniform slope sees no terrain: 0)."""
    cfg = config or ThermalConfig()
    z = np.asarray(z, np.float64)
    sin2_h = sky_horizons(z, resolution_m=resolution_m, config=cfg, workers=workers)
    k = coarse_factor(resolution_m, cfg)
    return view_factor_rows(z, sin2_h, resolution_m=resolution_m, k=k, rows=range(z.shape[0]))


def terrain_source(q_abs_w_m2: np.ndarray, *, resolution_m: float,
                   config: ThermalConfig | None = None) -> np.ndarray:  # fmt: skip
    """The terrain's absorbed direct flux averaged over a square of side ``2
    env_radius_m`` (W/m^2), on the coarse cells of :func:`coarse_factor`."""
    cfg = config or ThermalConfig()
    k = coarse_factor(resolution_m, cfg)
    return source_of_means(block_mean(q_abs_w_m2, k), resolution_m=resolution_m, config=cfg)


def source_of_means(q_mean_k: np.ndarray, *, resolution_m: float,
                    config: ThermalConfig | None = None) -> np.ndarray:  # fmt: skip
    """:func:`terrain_source` from the flux's means over the coarse cells (``q_mean_k``;
    ``resolution_m`` the DEM's pixel)."""
    cfg = config or ThermalConfig()
    k = coarse_factor(resolution_m, cfg)
    size = 2 * max(1, round(cfg.env_radius_m / (resolution_m * k))) + 1
    return ndimage.uniform_filter(q_mean_k, size=size, mode="nearest")


def equilibrium_temperature(q_w_m2, *, config: ThermalConfig | None = None) -> np.ndarray:
    """``((q + q_geo) / (emissivity sigma))^(1/4)`` (K) of absorbed flux ``q`` (W/m^2)."""
    cfg = config or ThermalConfig()
    q = np.asarray(q_w_m2, np.float64) + cfg.geothermal_w_m2
    return (q / (cfg.emissivity * SIGMA_SB)) ** 0.25


def temperature(
    q_direct_w_m2: np.ndarray,
    *,
    z: np.ndarray,
    resolution_m: float,
    config: ThermalConfig | None = None,
    workers: int = 2,
) -> np.ndarray:
    """Surface temperature (K) of DEM ``z`` from the absorbed direct flux, with the
    terrain's infrared and scattered light and the geothermal flux (see
    :func:`temperature_rows`)."""
    cfg = config or ThermalConfig()
    q = np.asarray(q_direct_w_m2, np.float32)
    sin2_h = sky_horizons(z, resolution_m=resolution_m, config=cfg, workers=workers)
    src = terrain_source(q, resolution_m=resolution_m, config=cfg)
    return temperature_rows(z, q[None], src[None], sin2_h, resolution_m=resolution_m,
                            rows=range(q.shape[0]), config=cfg)[0]  # fmt: skip


def direct_flux_at(z: np.ndarray, *, resolution_m: float, sun_azimuth_deg: float,
                   sun_elevation_deg: float, distance_au: float = 1.0,
                   config: ThermalConfig | None = None, horizon_mask: HorizonMask | None = None,
                   workers: int = 2, with_lit_fraction: bool = False):  # fmt: skip
    """Absorbed direct sunlight (W/m^2) at one Sun position (one hull sweep, as in
    :func:`illumination`); with ``with_lit_fraction``, also the visible fraction of the
    disk."""
    cfg = config or ThermalConfig()
    z = np.asarray(z, np.float64)
    q = np.zeros(z.shape, np.float32)
    f = np.zeros(z.shape, np.float32)
    sw = Sweep(z, azimuth_deg=sun_azimuth_deg, resolution_m=resolution_m)
    par = sw.sun_par(
        flux_w_m2=(1.0 - cfg.bond_albedo) * cfg.solar_constant_w_m2 / distance_au**2,
        mask_deg=_mask_deg(horizon_mask, sun_azimuth_deg),
        radius_deg=SUN_ANGULAR_RADIUS_DEG,
    )
    set_threads(workers)
    o = sw.orient
    sw.run(EPOCH, par, [float(sun_elevation_deg)], o.canon(f), o.canon(q),
           np.zeros((1, 1), np.uint8))  # fmt: skip
    return (q, f) if with_lit_fraction else q


__all__ = [
    "SIGMA_SB",
    "Illumination",
    "block_mean",
    "coarse_factor",
    "direct_flux_at",
    "equilibrium_temperature",
    "illumination",
    "sky_horizons",
    "sun_vector",
    "surface_normals",
    "temperature",
    "temperature_rows",
    "terrain_source",
    "upsample",
    "view_factor",
    "view_factor_rows",
]
