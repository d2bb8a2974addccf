"""NIRVSS and LCS core: spot means, band depths, noise in sunlight and under the lamp."""

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, OutOfBoundsError
from lunar_drake.science import nirvss
from lunar_drake.science.config import MINERALS


def _smap(n=60, res=0.05, lit=1.0):
    south, x = (np.mgrid[0:n, 0:n] + 0.5 - n / 2) * res
    y = -south  # row 0 north
    layers = {
        "frost_area_frac": np.where(x > 0, 0.08, 0.0),
        "oh_ppm": np.full((n, n), 600.0),
        "ice_wt_pct": np.full((n, n), 3.0),
        "dry_layer_m": np.where(y > 0, 0.0, 0.4),
        "minerals": np.stack([np.full((n, n), v) for v in (70.0, 20.0, 8.0, 2.0)]),
        "temperature_K": 100.0 + 10.0 * x,
        "lit_fraction": np.full((n, n), lit),
    }
    return nirvss.SurfaceMap.centred(layers, resolution_m=res), x, y


def test_spot_means_are_smooth_disk_averages():
    smap, _x, _y = _smap()
    # A symmetric average of a linear field is its value at the centre.
    spot = nirvss.spot_means(smap, 0.3, 0.2, radius_m=0.15)
    assert spot["temperature_K"] == pytest.approx(100.0 + 10.0 * 0.3, abs=0.02)
    assert spot["frost_area_frac"] == pytest.approx(0.08)
    assert np.allclose(spot["minerals"], [70.0, 20.0, 8.0, 2.0])
    # It moves smoothly: a 2 mm step changes it by about the gradient times the step.
    step = nirvss.spot_means(smap, 0.302, 0.2, radius_m=0.15)["temperature_K"]
    assert step - spot["temperature_K"] == pytest.approx(0.02, abs=0.005)
    with pytest.raises(OutOfBoundsError, match="outside"):
        nirvss.spot_means(smap, 5.0, 0.0, radius_m=0.15)


def test_band_depths_follow_abundances():
    cfg = nirvss.NIRVSSConfig()
    smap, _x, _y = _smap()
    wet = nirvss.band_depths(nirvss.spot_means(smap, 0.5, 0.5, radius_m=0.1), config=cfg)
    dry = nirvss.band_depths(nirvss.spot_means(smap, -0.5, -0.5, radius_m=0.1), config=cfg)
    b = dict(zip(nirvss.BANDS, wet, strict=True))
    assert b["frost"] == pytest.approx(0.5 * 0.08)
    assert b["oh"] == pytest.approx(1.5e-4 * 600.0)
    assert b["ice"] == pytest.approx(0.05 * 3.0)  # ice exposed: no dry layer
    d = dict(zip(nirvss.BANDS, dry, strict=True))
    assert d["frost"] == 0.0 and d["ice"] == 0.0  # no frost; ice under a dry layer
    assert [b[m] for m in MINERALS] == pytest.approx(
        [k * v for k, v in zip(cfg.mineral_per_wt_pct, (70.0, 20.0, 8.0, 2.0), strict=True)]
    )
    drilled = nirvss.band_depths(nirvss.spot_means(smap, -0.5, -0.5, radius_m=0.1), config=cfg,
                                 ice_wt_pct=4.0)  # fmt: skip
    assert drilled[2] == pytest.approx(0.2)


@pytest.mark.parametrize(("lit", "sigma"), [(1.0, 0.002), (0.0, 0.006)])
def test_noise_in_sunlight_and_under_the_lamp(lit, sigma):
    cfg = nirvss.NIRVSSConfig()
    smap, _x, _y = _smap(lit=lit)
    spot = nirvss.spot_means(smap, 0.5, 0.5, radius_m=0.1)
    clean = nirvss.band_depths(spot, config=cfg)
    g = np.random.default_rng(1)
    m = np.array([nirvss.measure(spot, g, config=cfg) for _ in range(3000)])
    oh = m[:, 1] - clean[1]
    assert oh.mean() == pytest.approx(0.0, abs=4 * sigma / np.sqrt(3000))
    assert oh.std() == pytest.approx(sigma, rel=0.05)
    assert m[:, -1].std() == pytest.approx(1.0, rel=0.05)  # LCS, K
    assert m[:, -1].mean() == pytest.approx(spot["temperature_K"], abs=0.1)


def test_bad_nirvss_config():
    with pytest.raises(ConfigError, match="mineral_per_wt_pct"):
        nirvss.NIRVSSConfig(mineral_per_wt_pct=[0.1]).validate()


def test_drill_samples_hold_no_ice_above_the_dry_layer():
    from lunar_drake.science.drill import ice_at_depth, read_sample

    g = np.random.default_rng(0)
    depths = [0.1, 0.2, 0.3, 0.4, 0.5]
    read = [read_sample(ice_at_depth(0.25, 4.0, d), g, ice_per_wt_pct=0.05, sigma=0.0)
            for d in depths]  # fmt: skip
    assert read == pytest.approx([0.0, 0.0, 0.2, 0.2, 0.2])  # 0.05 per wt% below 0.25 m
