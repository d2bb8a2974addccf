"""NIRVSS (Near-Infrared Volatiles Spectrometer System) and its LCS (Longwave
Calibration Sensor): band depths and surface temperature under the rover (numpy; no
Drake).

NIRVSS looks at a spot of ``spot_radius_m`` under the instrument and reports
continuum-removed band depths (-), each linear in what the world model holds in the
spot (the spot mean of each layer):

=================  =================================================================
band               depth
=================  =================================================================
``frost``          ``frost_per_area_frac`` x surface frost area fraction (1.5/2 um)
``oh``             ``oh_per_ppm`` x surface OH (ppm) (the 3 um band)
``ice``            ``ice_per_wt_pct`` x ice wt% where the dry layer is 0 (regolith
                   brought up by the drill reads its own depth's ice)
``pyroxene``, ...  ``mineral_per_wt_pct[k]`` x mineral wt% (1, 1.05, 1.25 um, dark
                   ilmenite)
=================  =================================================================

Noise is Gaussian per band with ``sigma_sun`` where the spot is sunlit (``lit_fraction``
of the world at the epoch >= 0.5) and ``sigma_lamp`` where the instrument's own lamp
lights it (fewer photons in the bands: noisier); band depths are clipped to [0, 1].
The LCS reads the spot's mean ``temperature_K`` with ``lcs_sigma_K`` noise. The
coefficients are our parameterisation (the shapes follow laboratory band-depth
calibrations: depth grows linearly with abundance at low abundance).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import OutOfBoundsError, check_range
from lunar_drake.science.config import MINERALS
from lunar_drake.sensors.sampling import check_sampling

#: NIRVSS bands, in record order (the LCS temperature follows them).
BANDS = ("frost", "oh", "ice", *MINERALS)
#: Layers NIRVSS reads.
LAYERS = ("frost_area_frac", "oh_ppm", "ice_wt_pct", "dry_layer_m", "minerals",
          "temperature_K", "lit_fraction")  # fmt: skip


@dc.dataclass
class NIRVSSConfig:
    """NIRVSS and its LCS (see the module docstring).

    Attributes:
        enabled: carried by the rover (off by default).
        rate_hz, delay_s: sampling (Hz, s).
        x_m: spot centre ahead of the chassis centre (m).
        spot_radius_m: spot radius (m), (0, 2].
        frost_per_area_frac, oh_per_ppm, ice_per_wt_pct: band depth per unit (-).
        mineral_per_wt_pct: band depth per wt% of each mineral (plagioclase, pyroxene,
            olivine, ilmenite).
        sigma_sun, sigma_lamp: band-depth noise (1 sigma) in sunlight and under the lamp.
        lcs_sigma_K: LCS temperature noise (K, 1 sigma).
    """

    enabled: bool = False
    rate_hz: float = 0.5
    delay_s: float = 0.0
    x_m: float = 0.9
    spot_radius_m: float = 0.15
    frost_per_area_frac: float = 0.5
    oh_per_ppm: float = 1.5e-4
    ice_per_wt_pct: float = 0.05
    mineral_per_wt_pct: list[float] = dc.field(default_factory=lambda: [0.001, 0.004, 0.004,
                                                                         0.003])  # fmt: skip
    sigma_sun: float = 0.002
    sigma_lamp: float = 0.006
    lcs_sigma_K: float = 1.0

    def validate(self) -> None:
        check_sampling(self.rate_hz, self.delay_s, max_rate_hz=100.0)
        check_range("x_m", self.x_m, -5.0, 5.0, unit=" m")
        check_range("spot_radius_m", self.spot_radius_m, 0.0, 2.0, lo_open=True, unit=" m")
        for name in ("frost_per_area_frac", "oh_per_ppm", "ice_per_wt_pct"):
            check_range(name, getattr(self, name), 0.0, 10.0)
        if len(self.mineral_per_wt_pct) != len(MINERALS):
            from lunar_drake.errors import ConfigError

            raise ConfigError(
                f"mineral_per_wt_pct has {len(self.mineral_per_wt_pct)} values; one per "
                f"mineral {MINERALS} is required"
            )
        for n, v in zip(MINERALS, self.mineral_per_wt_pct, strict=True):
            check_range(f"mineral_per_wt_pct[{n}]", v, 0.0, 1.0)
        check_range("sigma_sun", self.sigma_sun, 0.0, 1.0)
        check_range("sigma_lamp", self.sigma_lamp, 0.0, 1.0)
        check_range("lcs_sigma_K", self.lcs_sigma_K, 0.0, 100.0, unit=" K")


@dc.dataclass(frozen=True)
class SurfaceMap:
    """The layers NIRVSS reads (``layers``: name -> array; ``minerals`` (4, rows,
    cols)), on a grid with west edge ``x0_m``, north edge ``y1_m`` and ``resolution_m``."""

    layers: dict
    x0_m: float
    y1_m: float
    resolution_m: float

    @classmethod
    def centred(cls, layers: dict, *, resolution_m: float) -> "SurfaceMap":
        rows, cols = np.shape(layers["temperature_K"])
        return cls(dict(layers), -0.5 * cols * resolution_m, 0.5 * rows * resolution_m,
                   float(resolution_m))  # fmt: skip


def spot_means(smap: SurfaceMap, x_m: float, y_m: float, *, radius_m: float) -> dict:
    """Area-weighted mean of each layer over a disk of ``radius_m`` about (x, y): each
    cell weighs the share of it inside the disk, approximated by a ramp one cell wide
    across the rim, so that the mean moves smoothly with the spot."""
    res = smap.resolution_m
    t = smap.layers["temperature_K"]
    rows, cols = t.shape
    c = (x_m - smap.x0_m) / res - 0.5
    r = (smap.y1_m - y_m) / res - 0.5
    if not (-0.5 <= r <= rows - 0.5 and -0.5 <= c <= cols - 0.5):
        raise OutOfBoundsError(
            f"NIRVSS spot at ({x_m:.2f}, {y_m:.2f}) m lies outside the world model's grid"
        )
    k = math.ceil(radius_m / res) + 1
    r0, r1 = max(0, math.floor(r) - k), min(rows, math.ceil(r) + k + 1)
    c0, c1 = max(0, math.floor(c) - k), min(cols, math.ceil(c) + k + 1)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    d = np.hypot((rr - r) * res, (cc - c) * res)
    w = np.clip((radius_m - d) / res + 0.5, 0.0, 1.0)
    if w.sum() <= 0.0:
        w = ((rr == round(r)) & (cc == round(c))).astype(np.float64)
    w = w / w.sum()
    out = {}
    for name, a in smap.layers.items():
        a = np.asarray(a)
        if a.ndim == 3:
            out[name] = (a[:, r0:r1, c0:c1].astype(np.float64) * w).sum(axis=(1, 2))
        else:
            out[name] = float((a[r0:r1, c0:c1].astype(np.float64) * w).sum())
    return out


def band_depths(spot: dict, *, config: NIRVSSConfig, ice_wt_pct: float | None = None):
    """Noise-free band depths (:data:`BANDS` order) of a spot's layer means; ``ice_wt_pct``
    overrides the spot's exposed ice (a drilled sample's)."""
    ice = (spot["ice_wt_pct"] if spot["dry_layer_m"] <= 0.0 else 0.0) if ice_wt_pct is None \
        else ice_wt_pct  # fmt: skip
    minerals = np.asarray(spot["minerals"], np.float64)
    return np.concatenate([
        [config.frost_per_area_frac * spot["frost_area_frac"], config.oh_per_ppm * spot["oh_ppm"],
         config.ice_per_wt_pct * ice],
        np.asarray(config.mineral_per_wt_pct) * minerals,
    ])  # fmt: skip


def measure(spot: dict, generator: np.random.Generator, *, config: NIRVSSConfig) -> np.ndarray:
    """One NIRVSS + LCS record: band depths with noise (clipped to [0, 1]), then the LCS
    temperature (K). Draws len(BANDS) + 1 normals."""
    sunlit = spot["lit_fraction"] >= 0.5
    sigma = config.sigma_sun if sunlit else config.sigma_lamp
    noise = generator.standard_normal(len(BANDS) + 1)
    bd = np.clip(band_depths(spot, config=config) + sigma * noise[:-1], 0.0, 1.0)
    return np.append(bd, spot["temperature_K"] + config.lcs_sigma_K * noise[-1])


__all__ = ["BANDS", "LAYERS", "NIRVSSConfig", "SurfaceMap", "band_depths", "measure",
           "spot_means"]  # fmt: skip
