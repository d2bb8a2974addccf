"""Illumination over a year and surface temperatures (numpy/scipy; no Drake).

Grid conventions of :mod:`lunar_drake.terrain`: ``z[row, col]`` (m), row 0 north,
column 0 west; x east, y north; azimuths clockwise from grid north.

* :func:`illumination`: for each sector of the Sun's envelope
  (:mod:`.sun_envelope`) one banded horizon computation
  (:func:`lunar_drake.render.horizon.horizon_angles`, tile-invariant) gives each cell's
  lit fraction at the sector's highest elevation (permanent shadow: never lit in any
  sector) and at its elevation quantiles (time-mean flux); the absorbed direct flux is
  ``(1 - A) S f cos(i)`` on the DEM's own slope.
* :func:`view_factor`: the cosine-weighted share of each cell's sky that terrain fills,
  ``mean over azimuths of sin^2(horizon)``.
* :func:`temperature`: radiative equilibrium with the terrain's infrared and scattered
  light and the geothermal flux (see :class:`~.config.ThermalConfig` for the
  approximation).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
from scipy import ndimage

from lunar_drake.render.horizon import HorizonMask, horizon_angles
from lunar_drake.render.lightmap import SUN_ANGULAR_RADIUS_DEG, lightmap_from_horizon
from lunar_drake.science.config import ThermalConfig
from lunar_drake.science.sun_envelope import SunEnvelope

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


def cos_incidence(normals: np.ndarray, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """``max(0, n . s)``: cosine of the Sun's incidence on each cell's slope."""
    s = sun_vector(azimuth_deg, elevation_deg)
    return np.maximum(0.0, np.tensordot(s, normals, axes=1))


@dc.dataclass(frozen=True)
class Illumination:
    """Direct sunlight over the envelope's span.

    Attributes:
        ever_lit: bool ``(rows, cols)``: some of the Sun's disk seen at some time.
        q_max_w_m2: highest absorbed direct flux (W/m^2).
        q_mean_w_m2: time-mean absorbed direct flux (W/m^2).
    """

    ever_lit: np.ndarray
    q_max_w_m2: np.ndarray
    q_mean_w_m2: np.ndarray


def illumination(
    z: np.ndarray,
    *,
    resolution_m: float,
    envelope: SunEnvelope,
    config: ThermalConfig | None = None,
    horizon_mask: HorizonMask | None = None,
    horizon_resolution_deg: float = 0.1,
    tile_px: int = 2048,
    workers: int = 2,
    progress=None,
) -> Illumination:
    """Permanent shadow and direct fluxes of DEM ``z`` (see the module docstring).

    ``horizon_mask``: terrain outside the DEM (default a level plain, horizon 0 deg).
    ``progress(done, total)`` is called after each sector.
    """
    cfg = config or ThermalConfig()
    mask = horizon_mask if horizon_mask is not None else HorizonMask.level(0.0)
    z = np.asarray(z, np.float64)
    normals = surface_normals(z, resolution_m)
    r = SUN_ANGULAR_RADIUS_DEG
    lit = np.zeros(z.shape, bool)
    q_max = np.zeros(z.shape)
    q_mean = np.zeros(z.shape)
    low = mask.min_elevation_deg() - r
    todo = [
        b
        for b in range(envelope.azimuth_deg.size)
        if envelope.weight[b] > 0 and envelope.el_max_deg[b] + r > low
    ]
    for i, b in enumerate(todo):
        az = float(envelope.azimuth_deg[b])
        s = cfg.solar_constant_w_m2 / float(envelope.distance_au[b]) ** 2
        el_max = float(envelope.el_max_deg[b])
        levels = [float(e) for e in envelope.el_levels_deg[b]]
        lo = max(min(levels) - r - 0.05, low - 0.05)
        hi = el_max + r + 0.05
        h = horizon_angles(
            z,
            azimuth_deg=az,
            resolution_m=resolution_m,
            elevation_range_deg=(lo, max(hi, lo + horizon_resolution_deg)),
            resolution_deg=horizon_resolution_deg,
            tile_px=tile_px,
            workers=workers,
        )

        def absorbed(el: float, h=h, az=az, s=s) -> tuple[np.ndarray, np.ndarray]:
            if el + r <= low:  # below every horizon
                return np.zeros(z.shape), np.zeros(z.shape)
            f = lightmap_from_horizon(
                h,
                sun_azimuth_deg=az,
                sun_elevation_deg=el,
                resolution_m=resolution_m,
                horizon_mask=mask,
            )
            return (1.0 - cfg.bond_albedo) * s * f * cos_incidence(normals, az, el), f

        q, f = absorbed(el_max)
        lit |= f > 0.0
        np.maximum(q_max, q, out=q_max)
        mean = sum(absorbed(el)[0] for el in levels)
        q_mean += envelope.weight[b] * mean / len(levels)
        if progress is not None:
            progress(i + 1, len(todo))
    return Illumination(ever_lit=lit, q_max_w_m2=q_max, q_mean_w_m2=q_mean)


def view_factor(
    z: np.ndarray,
    *,
    resolution_m: float,
    config: ThermalConfig | None = None,
    tile_px: int = 2048,
    workers: int = 2,
) -> np.ndarray:
    """Cosine-weighted share of each cell's sky filled by terrain that rises above the
    cell's own tangent plane (-): ``mean_k (sin^2 h_k - sin^2 e_k)``, ``h_k`` the horizon
    (from :func:`~lunar_drake.render.horizon.horizon_angles` on the DEM block-averaged to
    about ``config.view_resolution_m``, resolved to ``config.view_max_deg``; the infrared
    environment is a large-scale effect) and ``e_k`` the tangent plane's elevation along
    azimuth ``k`` of ``config.view_azimuths`` (a uniform slope sees no terrain: 0)."""
    cfg = config or ThermalConfig()
    z = np.asarray(z, np.float64)
    rows, cols = z.shape
    k = max(1, round(cfg.view_resolution_m / resolution_m))
    zc = z
    if k > 1:
        pr, pc = (-rows) % k, (-cols) % k
        zp = np.pad(z, ((0, pr), (0, pc)), mode="edge")
        zc = zp.reshape(zp.shape[0] // k, k, zp.shape[1] // k, k).mean(axis=(1, 3))
    n = surface_normals(z, resolution_m)
    f = np.zeros(z.shape)
    for j in range(cfg.view_azimuths):
        az = 360.0 * j / cfg.view_azimuths
        h = horizon_angles(
            zc,
            azimuth_deg=az,
            resolution_m=resolution_m * k,
            elevation_range_deg=(0.0, cfg.view_max_deg),
            resolution_deg=1.0,
            tile_px=tile_px,
            workers=workers,
        )
        h = np.repeat(np.repeat(h, k, axis=0), k, axis=1)[:rows, :cols]
        a = math.radians(az)
        tan_e = np.maximum(0.0, -(n[0] * math.sin(a) + n[1] * math.cos(a)) / n[2])
        sin2_e = tan_e * tan_e / (1.0 + tan_e * tan_e)
        f += np.maximum(0.0, np.sin(np.maximum(h.astype(np.float64), 0.0)) ** 2 - sin2_e)
    return f / cfg.view_azimuths


def environment_flux(
    q_abs_w_m2: np.ndarray,
    *,
    view: np.ndarray,
    resolution_m: float,
    config: ThermalConfig | None = None,
) -> np.ndarray:
    """Infrared and scattered sunlight absorbed from the surrounding terrain (W/m^2):
    ``view (emissivity M_ir + (1 - A) M_vis)`` with the terrain's emission (at its
    direct-light equilibrium) and scattered light averaged over a square of side
    ``2 env_radius_m`` (see :class:`~.config.ThermalConfig`)."""
    cfg = config or ThermalConfig()
    a, eps = cfg.bond_albedo, cfg.emissivity
    emitted = q_abs_w_m2 + cfg.geothermal_w_m2  # eps sigma T^4 at direct equilibrium
    scattered = a * q_abs_w_m2 / (1.0 - a)
    size = 2 * max(1, round(cfg.env_radius_m / resolution_m)) + 1
    m_ir = ndimage.uniform_filter(emitted, size=size, mode="nearest")
    m_vis = ndimage.uniform_filter(scattered, size=size, mode="nearest")
    return view * (eps * m_ir + (1.0 - a) * m_vis)


def equilibrium_temperature(q_w_m2, *, config: ThermalConfig | None = None) -> np.ndarray:
    """``((q + q_geo) / (emissivity sigma))^(1/4)`` (K) of absorbed flux ``q`` (W/m^2)."""
    cfg = config or ThermalConfig()
    q = np.asarray(q_w_m2, np.float64) + cfg.geothermal_w_m2
    return (q / (cfg.emissivity * SIGMA_SB)) ** 0.25


def temperature(
    q_direct_w_m2: np.ndarray,
    *,
    view: np.ndarray,
    resolution_m: float,
    config: ThermalConfig | None = None,
) -> np.ndarray:
    """Surface temperature (K) from the absorbed direct flux, with the terrain's infrared
    and scattered light (:func:`environment_flux`) and the geothermal flux."""
    q_env = environment_flux(q_direct_w_m2, view=view, resolution_m=resolution_m, config=config)
    return equilibrium_temperature(q_direct_w_m2 + q_env, config=config)


def direct_flux_at(z: np.ndarray, *, resolution_m: float, sun_azimuth_deg: float,
                   sun_elevation_deg: float, distance_au: float = 1.0,
                   config: ThermalConfig | None = None, horizon_mask: HorizonMask | None = None,
                   tile_px: int = 2048, workers: int = 2,
                   with_lit_fraction: bool = False):  # fmt: skip
    """Absorbed direct sunlight (W/m^2) at one Sun position (lit fraction from
    :func:`lunar_drake.render.lightmap.lightmap`); with ``with_lit_fraction``, also that
    fraction."""
    from lunar_drake.render.lightmap import lightmap

    cfg = config or ThermalConfig()
    z = np.asarray(z, np.float64)
    f = lightmap(z, sun_azimuth_deg=sun_azimuth_deg, sun_elevation_deg=sun_elevation_deg,
                 resolution_m=resolution_m, horizon_mask=horizon_mask, tile_px=tile_px,
                 workers=workers)  # fmt: skip
    s = cfg.solar_constant_w_m2 / distance_au**2
    cosi = cos_incidence(surface_normals(z, resolution_m), sun_azimuth_deg, sun_elevation_deg)
    q = (1.0 - cfg.bond_albedo) * s * f * cosi
    return (q, np.asarray(f)) if with_lit_fraction else q


__all__ = [
    "SIGMA_SB",
    "Illumination",
    "cos_incidence",
    "direct_flux_at",
    "environment_flux",
    "equilibrium_temperature",
    "illumination",
    "sun_vector",
    "surface_normals",
    "temperature",
    "view_factor",
]
