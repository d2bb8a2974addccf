"""Neutron Spectrometer System (NSS): count rates from the hydrogen under the rover
(numpy; no Drake). The plant sensor and the ground's inversion both call this core.

Hydrogen as water-equivalent hydrogen (WEH, wt%): hydrogen-bearing minerals everywhere
(``h_minerals_ppm`` of hydrogen by mass is ``9e-4`` wt% WEH per ppm: water is 1/9
hydrogen by mass), plus water ice (``ice_wt_pct``) below the dry layer
(``dry_layer_m``). OH and frost live in the top microns to millimetres and are
invisible to neutrons.

**Depth.** Neutrons leaking from the surface sample the top metre with a sensitivity
falling as ``exp(-z / depth_scale_m)``; the weight of the ice below a dry layer ``d``
is ``(e^(-d/L) - e^(-z_max/L)) / (1 - e^(-z_max/L))``.

**Footprint.** A surface element at horizontal distance ``r`` from a detector ``h``
above the ground contributes in proportion to ``h / (h^2 + r^2)^(3/2)`` (its solid angle
from the detector), out to ``footprint_radius_m``.

**Counts.** Epithermal neutrons are moderated away by hydrogen: ``C_epi = C_epi0 / (1 +
k_epi W)``; thermal neutrons first grow as hydrogen moderates fast neutrons down, then
saturate: ``C_th = C_th0 (1 + a W) / (1 + b W)``; each integration draws Poisson counts.
The forms and the dry rates (a rover-borne 3He spectrometer class: hundreds of counts
per second) are our parameterisation, in the spirit of Elphic et al. (2015, Adv. Space
Res. 55, 2438: rover-borne neutron prospecting for the Resource Prospector); the
orbital relations are not rover footprints.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import OutOfBoundsError, check_range
from lunar_drake.sensors.sampling import check_sampling

#: WEH (wt%) per ppm of hydrogen by mass.
WEH_PER_H_PPM = 9.0e-4


@dc.dataclass
class NSSConfig:
    """The neutron spectrometer (see the module docstring).

    Attributes:
        enabled: carried by the rover (off by default).
        rate_hz: integrations per second; each lasts ``1 / rate_hz`` (Hz), (0, 100].
        delay_s: delivery delay (s).
        height_m: detector above the ground (m), (0, 5].
        x_m: detector ahead of the chassis centre (m), |x| <= 5.
        footprint_radius_m: ground beyond this is ignored (m), (0, 20].
        depth_scale_m: e-folding depth of the sensitivity (m), (0, 5].
        max_depth_m: deepest layer sensed (m), (0, 10].
        epithermal_dry_cps, thermal_dry_cps: count rates over dry regolith (1/s), > 0.
        epithermal_per_wt_pct: ``k_epi`` (1/wt%), > 0.
        thermal_gain_per_wt_pct, thermal_saturation_per_wt_pct: ``a`` and ``b`` (1/wt%).
    """

    enabled: bool = False
    rate_hz: float = 1.0
    delay_s: float = 0.0
    height_m: float = 0.5
    x_m: float = 0.9
    footprint_radius_m: float = 2.0
    depth_scale_m: float = 0.25
    max_depth_m: float = 1.0
    epithermal_dry_cps: float = 250.0
    thermal_dry_cps: float = 150.0
    epithermal_per_wt_pct: float = 0.2
    thermal_gain_per_wt_pct: float = 0.6
    thermal_saturation_per_wt_pct: float = 0.3

    def validate(self) -> None:
        check_sampling(self.rate_hz, self.delay_s, max_rate_hz=100.0)
        check_range("height_m", self.height_m, 0.0, 5.0, lo_open=True, unit=" m")
        check_range("x_m", self.x_m, -5.0, 5.0, unit=" m")
        check_range(
            "footprint_radius_m", self.footprint_radius_m, 0.0, 20.0, lo_open=True, unit=" m"
        )
        check_range("depth_scale_m", self.depth_scale_m, 0.0, 5.0, lo_open=True, unit=" m")
        check_range("max_depth_m", self.max_depth_m, 0.0, 10.0, lo_open=True, unit=" m")
        for name in ("epithermal_dry_cps", "thermal_dry_cps", "epithermal_per_wt_pct"):
            check_range(name, getattr(self, name), 0.0, 1e7, lo_open=True)
        check_range("thermal_gain_per_wt_pct", self.thermal_gain_per_wt_pct, 0.0, 100.0)
        check_range("thermal_saturation_per_wt_pct", self.thermal_saturation_per_wt_pct, 0.0, 100.0)


@dc.dataclass(frozen=True)
class HydrogenMap:
    """The layers NSS reads, on one grid (row 0 north; x east, y north, site metres).

    Attributes:
        dry_layer_m, ice_wt_pct, h_minerals_ppm: ``(rows, cols)`` arrays.
        x0_m, y1_m: west and north edges (m). resolution_m: pixel (m).
    """

    dry_layer_m: np.ndarray
    ice_wt_pct: np.ndarray
    h_minerals_ppm: np.ndarray
    x0_m: float
    y1_m: float
    resolution_m: float

    @classmethod
    def centred(cls, *, dry_layer_m, ice_wt_pct, h_minerals_ppm, resolution_m: float):
        """A map whose grid is centred on the site origin (as site rasters are)."""
        rows, cols = np.shape(dry_layer_m)
        return cls(
            np.asarray(dry_layer_m),
            np.asarray(ice_wt_pct),
            np.asarray(h_minerals_ppm),
            -0.5 * cols * resolution_m,
            0.5 * rows * resolution_m,
            float(resolution_m),
        )


def ice_depth_weight(dry_layer_m, *, config: NSSConfig) -> np.ndarray:
    """Share of the depth sensitivity that lies below a dry layer (-), in [0, 1]."""
    L, zmax = config.depth_scale_m, config.max_depth_m
    d = np.clip(np.asarray(dry_layer_m, np.float64), 0.0, zmax)
    return (np.exp(-d / L) - math.exp(-zmax / L)) / (1.0 - math.exp(-zmax / L))


def weh_column(hmap: HydrogenMap, *, config: NSSConfig, window=None) -> np.ndarray:
    """Depth-weighted WEH (wt%) of each cell of ``window = (r0, r1, c0, c1)`` (default
    all)."""
    r0, r1, c0, c1 = (
        window
        if window is not None
        else (0, hmap.dry_layer_m.shape[0], 0, hmap.dry_layer_m.shape[1])
    )
    d = hmap.dry_layer_m[r0:r1, c0:c1]
    ice = np.asarray(hmap.ice_wt_pct[r0:r1, c0:c1], np.float64)
    h = np.asarray(hmap.h_minerals_ppm[r0:r1, c0:c1], np.float64)
    return WEH_PER_H_PPM * h + ice * ice_depth_weight(d, config=config)


def footprint_weh(hmap: HydrogenMap, x_m: float, y_m: float, *, config: NSSConfig) -> float:
    """Footprint-weighted, depth-weighted WEH (wt%) seen by a detector above (x, y)."""
    res = hmap.resolution_m
    R, h = config.footprint_radius_m, config.height_m
    rows, cols = hmap.dry_layer_m.shape
    c = (x_m - hmap.x0_m) / res - 0.5
    r = (hmap.y1_m - y_m) / res - 0.5
    k = math.ceil(R / res)
    r0, r1 = max(0, math.floor(r) - k), min(rows, math.ceil(r) + k + 1)
    c0, c1 = max(0, math.floor(c) - k), min(cols, math.ceil(c) + k + 1)
    if r0 >= r1 or c0 >= c1:
        raise OutOfBoundsError(
            f"NSS footprint at ({x_m:.2f}, {y_m:.2f}) m lies outside the world model's "
            f"grid (x from {hmap.x0_m:g} m, y up to {hmap.y1_m:g} m, {cols} x {rows} px)"
        )
    xs = hmap.x0_m + (np.arange(c0, c1) + 0.5) * res
    ys = hmap.y1_m - (np.arange(r0, r1) + 0.5) * res
    d2 = (xs[None, :] - x_m) ** 2 + (ys[:, None] - y_m) ** 2
    w = np.where(d2 <= R * R, h / (h * h + d2) ** 1.5, 0.0)
    total = w.sum()
    if total <= 0.0:
        raise OutOfBoundsError(f"NSS footprint at ({x_m:.2f}, {y_m:.2f}) m holds no cell")
    return float((w * weh_column(hmap, config=config, window=(r0, r1, c0, c1))).sum() / total)


def footprint_share(x_m, y_m, *, x_west_m, y_south_m, cell_m: float, config: NSSConfig,
                    step_m: float = 0.05) -> np.ndarray:  # fmt: skip
    """Share (-) of the response of a detector above each point (x, y) (site m) that
    comes from the square ``[x_west, x_west + cell_m) x [y_south, y_south + cell_m)``
    (arrays of the same length as ``x_m``): the footprint weight ``h / (h^2 + r^2)^1.5``
    over the square (midpoint rule, samples ``step_m`` apart or finer) over its
    integral over the disk of ``footprint_radius_m``, ``2 pi (1 - h / sqrt(h^2 +
    R^2))``."""
    x = np.atleast_1d(np.asarray(x_m, np.float64))
    y = np.atleast_1d(np.asarray(y_m, np.float64))
    xw = np.broadcast_to(np.asarray(x_west_m, np.float64), x.shape)
    ys = np.broadcast_to(np.asarray(y_south_m, np.float64), x.shape)
    n = max(1, math.ceil(cell_m / step_m))
    u = (np.arange(n) + 0.5) * (cell_m / n)
    h, R = config.height_m, config.footprint_radius_m
    total = 2.0 * math.pi * (1.0 - h / math.hypot(h, R))
    out = np.empty(x.shape)
    for k in range(x.size):
        d2 = (xw[k] + u[None, :] - x[k]) ** 2 + (ys[k] + u[:, None] - y[k]) ** 2
        w = np.where(d2 <= R * R, h / (h * h + d2) ** 1.5, 0.0)
        out[k] = w.sum() * (cell_m / n) ** 2 / total
    return out


def count_rates(weh_wt_pct, *, config: NSSConfig) -> tuple:
    """Expected ``(epithermal, thermal)`` count rates (1/s) at WEH ``weh_wt_pct``."""
    w = np.asarray(weh_wt_pct, np.float64)
    epi = config.epithermal_dry_cps / (1.0 + config.epithermal_per_wt_pct * w)
    th = (
        config.thermal_dry_cps
        * (1.0 + config.thermal_gain_per_wt_pct * w)
        / (1.0 + config.thermal_saturation_per_wt_pct * w)
    )
    return epi, th


def draw_counts(weh_wt_pct: float, generator: np.random.Generator, *, config: NSSConfig):
    """One integration: Poisson ``(epithermal, thermal)`` counts over ``1 / rate_hz`` s."""
    epi, th = count_rates(weh_wt_pct, config=config)
    t = 1.0 / config.rate_hz
    return int(generator.poisson(epi * t)), int(generator.poisson(th * t))


def weh_from_epithermal(counts, seconds, *, config: NSSConfig) -> np.ndarray:
    """The ground's WEH estimate (wt%) from epithermal counts over ``seconds``: the
    inverse of :func:`count_rates` (negative values kept: they are noise)."""
    rate = np.asarray(counts, np.float64) / np.asarray(seconds, np.float64)
    with np.errstate(divide="ignore"):
        return (config.epithermal_dry_cps / rate - 1.0) / config.epithermal_per_wt_pct


def weh_sigma_from_epithermal(counts, seconds, *, config: NSSConfig) -> np.ndarray:
    """One standard deviation (wt%) of :func:`weh_from_epithermal` from the counts'
    Poisson noise, to first order: ``C0 T / (k N^1.5)`` for ``N`` counts over ``T`` s
    (infinite at 0 counts). Pooling records (their summed counts over their summed
    seconds, the Poisson maximum-likelihood rate) shrinks it as ``1 / sqrt(records)``
    and removes most of a single record's convexity bias (about ``C0 T / (k N^2)``)."""
    n = np.asarray(counts, np.float64)
    t = np.asarray(seconds, np.float64)
    with np.errstate(divide="ignore"):
        return config.epithermal_dry_cps * t / (config.epithermal_per_wt_pct * n**1.5)


__all__ = [
    "WEH_PER_H_PPM",
    "HydrogenMap",
    "NSSConfig",
    "count_rates",
    "draw_counts",
    "footprint_share",
    "footprint_weh",
    "ice_depth_weight",
    "weh_column",
    "weh_from_epithermal",
    "weh_sigma_from_epithermal",
]
