"""Tests for the camera sensor model (lunar_drake.render.sensor)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import sensor as sn

KEY = rng.stream_key(42, "camera/left")
P = sn.CMV4000_NAVCAM


def _flat(value, shape=(256, 256)):
    return np.full(shape, float(value))


def _radiance_for_electrons(n_e, exposure_s, params=P):
    """Band radiance that collects ``n_e`` photo-electrons in ``exposure_s``."""
    return n_e / (params.electrons_per_radiance * exposure_s)


def test_radiometry_by_hand():
    L = 10.0  # W m^-2 sr^-1
    a_pix = (5.5e-6) ** 2
    photon = 6.62607015e-34 * 299_792_458.0 / 0.55e-6
    want = L * math.pi * 0.85 / (4 * 8.0**2) * a_pix * 0.5 / photon
    assert float(sn.electron_rate(L)) == pytest.approx(want, rel=1e-12)
    assert float(sn.radiance_from_i_over_f(1.0)) == pytest.approx(540.0 / math.pi)
    assert float(sn.radiance_from_i_over_f(0.2, sun_distance_au=2.0)) == pytest.approx(
        0.2 * 540.0 / math.pi / 4
    )
    # a highland I/F of 0.1 saturates the preset at f/8 in about 1.8 ms
    t_sat = P.full_well_e / float(sn.electron_rate(sn.radiance_from_i_over_f(0.1)))
    assert 1e-3 < t_sat < 3e-3
    assert P.e_per_dn == pytest.approx(13_500 / 4095)


def test_bit_identical_and_frame_dependent():
    L = _flat(_radiance_for_electrons(2000, 1e-3), (64, 96))
    a = sn.expose(L, exposure_s=1e-3, key=KEY, frame_index=7)
    b = sn.expose(L, exposure_s=1e-3, key=KEY, frame_index=7)
    assert a.dtype == np.uint16 and a.shape == (64, 96)
    assert np.array_equal(a, b)
    c = sn.expose(L, exposure_s=1e-3, key=KEY, frame_index=8)
    d = sn.expose(L, exposure_s=1e-3, key=KEY + 1, frame_index=7)
    assert np.mean(a != c) > 0.8 and np.mean(a != d) > 0.8
    # noise of a pixel does not depend on the image size (counter-based per pixel)
    big = sn.expose(_flat(L[0, 0], (128, 128)), exposure_s=1e-3, key=KEY, frame_index=7)
    assert np.array_equal(big[:64, :96], a)


def test_mean_linear_in_exposure_until_saturation():
    t_sat = 2e-3
    L = _flat(_radiance_for_electrons(P.full_well_e, t_sat), (128, 128))
    ts = np.linspace(0.05, 0.8, 8) * t_sat
    means = np.array(
        [sn.expose(L, exposure_s=t, key=KEY, frame_index=i).mean() for i, t in enumerate(ts)]
    )
    slope, icpt = np.polyfit(ts, means, 1)
    assert np.max(np.abs(means - (slope * ts + icpt))) < 1e-3 * means.max()
    want_slope = (P.full_well_e / t_sat + P.dark_current_e_s) / P.e_per_dn
    assert slope == pytest.approx(want_slope, rel=2e-3)
    sat = sn.expose(L, exposure_s=3 * t_sat, key=KEY, frame_index=99)
    assert sat.max() == 4095 and sat.mean() > 4090
    assert sat.mean() < 0.5 * (slope * 3 * t_sat + icpt)  # far below the linear extrapolation


def test_photon_transfer_slope_is_conversion_gain():
    params = dataclasses.replace(P, read_noise_e=5.0, dark_current_e_s=0.0, black_level_dn=100)
    gain = 2.0
    k = gain / params.e_per_dn  # DN per electron
    t = 1e-3
    means, variances = [], []
    for i, n_e in enumerate([300, 800, 1500, 2500, 4000, 5500]):
        L = _flat(_radiance_for_electrons(n_e, t, params), (384, 384))
        raw = sn.expose(L, exposure_s=t, gain=gain, params=params, key=KEY, frame_index=i)
        dn = raw.astype(float) - params.black_level_dn
        means.append(dn.mean())
        variances.append(dn.var())
    slope, _ = np.polyfit(means, variances, 1)
    assert slope == pytest.approx(k, rel=0.1)
    assert slope == pytest.approx(k, rel=0.02)  # it is in fact much better than 10 %
    # the read-noise floor: a zero-signal frame's variance is (k sigma_read)^2 + 1/12
    zero = sn.expose(_flat(0.0, (384, 384)), exposure_s=t, gain=gain, params=params, key=KEY,
                     frame_index=50)  # fmt: skip
    assert zero.astype(float).var() == pytest.approx((k * 5.0) ** 2 + 1 / 12, rel=0.05)


def test_exact_poisson_for_small_means():
    lam = 3.0
    n = sn.shot_noise_electrons(_flat(lam, (512, 512)), key=KEY, frame_index=0)
    assert np.all(n == np.round(n)) and n.min() >= 0
    N = n.size
    for kk in range(9):
        pk = math.exp(-lam) * lam**kk / math.factorial(kk)
        freq = np.mean(n == kk)
        assert abs(freq - pk) < 4 * math.sqrt(pk * (1 - pk) / N) + 1e-4, kk
    # large means: Gaussian with the Poisson variance
    m = sn.shot_noise_electrons(_flat(400.0, (512, 512)), key=KEY, frame_index=0)
    assert m.mean() == pytest.approx(400.0, abs=0.2)
    assert m.var() == pytest.approx(400.0 + 1 / 12, rel=0.02)
    # mixed image: each pixel drawn by its own mean's law, bit-identical when repeated
    mixed = np.where(np.arange(256)[None, :] < 128, 2.0, 500.0) * np.ones((256, 1))
    a = sn.shot_noise_electrons(mixed, key=KEY, frame_index=3)
    assert np.array_equal(a, sn.shot_noise_electrons(mixed, key=KEY, frame_index=3))
    assert a[:, :128].mean() == pytest.approx(2.0, abs=0.05)
    assert a[:, 128:].mean() == pytest.approx(500.0, abs=0.5)


def test_dark_frame_and_read_noise():
    params = dataclasses.replace(P, black_level_dn=64)
    t = 0.5
    raw = sn.expose(_flat(0.0), exposure_s=t, params=params, key=KEY, frame_index=0)
    dark_dn = P.dark_current_e_s * t / P.e_per_dn
    assert raw.mean() == pytest.approx(64 + dark_dn, abs=0.1)
    want_var = (P.dark_current_e_s * t + P.read_noise_e**2) / P.e_per_dn**2 + 1 / 12
    assert raw.astype(float).var() == pytest.approx(want_var, rel=0.05)


def test_12bit_clipping_and_msb_alignment():
    rng_ = np.random.default_rng(0)
    L = rng_.uniform(0, 5 * _radiance_for_electrons(P.full_well_e, 1e-3), (128, 128))
    raw = sn.expose(L, exposure_s=1e-3, gain=4.0, key=KEY, frame_index=0)
    assert raw.dtype == np.uint16 and raw.max() == 4095 and raw.min() >= 0
    assert np.mean(raw == 4095) > 0.5
    msb = sn.expose(
        L, exposure_s=1e-3, gain=4.0, params=dataclasses.replace(P, msb_aligned=True),
        key=KEY, frame_index=0,
    )  # fmt: skip
    assert np.array_equal(msb, raw << 4) and msb.max() == 65520


@pytest.mark.parametrize("exposure_s", [0.0, -1e-3, float("nan"), 11.0, 1e-7])
def test_bad_exposure_raises(exposure_s):
    with pytest.raises(OutOfRangeError, match="exposure_s="):
        sn.expose(_flat(1.0, (4, 4)), exposure_s=exposure_s, key=KEY, frame_index=0)


@pytest.mark.parametrize("gain", [0.0, -2.0, 9.0, float("inf")])
def test_bad_gain_raises(gain):
    with pytest.raises(OutOfRangeError, match=f"gain={gain!r}"):
        sn.expose(_flat(1.0, (4, 4)), exposure_s=1e-3, gain=gain, key=KEY, frame_index=0)


def test_bad_inputs_raise():
    bad = _flat(1.0, (4, 4))
    bad[1, 1] = -1.0
    with pytest.raises(OutOfRangeError, match="radiance"):
        sn.expose(bad, exposure_s=1e-3, key=KEY, frame_index=0)
    bad[1, 1] = np.nan
    with pytest.raises(OutOfRangeError, match="non-finite"):
        sn.expose(bad, exposure_s=1e-3, key=KEY, frame_index=0)
    with pytest.raises(ConfigError, match="rows, cols"):
        sn.expose(np.ones(5), exposure_s=1e-3, key=KEY, frame_index=0)
    with pytest.raises(OutOfRangeError, match="frame_index"):
        sn.expose(_flat(1.0, (4, 4)), exposure_s=1e-3, key=KEY, frame_index=1 << 40)
    with pytest.raises(OutOfRangeError, match="mean electron"):
        sn.shot_noise_electrons(-np.ones((2, 2)), key=KEY, frame_index=0)
    with pytest.raises(OutOfRangeError, match="full_well_e"):
        sn.SensorParams(full_well_e=0.0)
    with pytest.raises(OutOfRangeError, match="adc_bits"):
        sn.SensorParams(adc_bits=20)
    with pytest.raises(OutOfRangeError, match="quantum_efficiency"):
        sn.SensorParams(quantum_efficiency=1.5)


def test_color_channels_have_independent_noise():
    L = np.full((64, 64, 3), _radiance_for_electrons(3000, 1e-3))
    raw = sn.expose(L, exposure_s=1e-3, key=KEY, frame_index=0)
    assert raw.shape == (64, 64, 3)
    assert np.mean(raw[..., 0] != raw[..., 1]) > 0.8
    mono = sn.expose(L[..., 0], exposure_s=1e-3, key=KEY, frame_index=0)
    assert np.array_equal(raw[..., 0], mono)
    np.testing.assert_allclose(raw.mean(axis=(0, 1)), 3000 / P.e_per_dn, rtol=0.01)


def test_exposure_for_level():
    L = sn.radiance_from_i_over_f(0.12)
    t = sn.exposure_for_level(L, level=0.5)
    raw = sn.expose(_flat(L), exposure_s=t, key=KEY, frame_index=0)
    assert raw.mean() == pytest.approx(0.5 * 4095, rel=0.01)
    assert sn.exposure_for_level(0.0) == P.max_exposure_s
    assert sn.exposure_for_level(1e9) == P.min_exposure_s


def test_paper_16bit_path():
    lin = np.array([[0.0, 0.25, 0.5], [1.0, 2.0, -0.1]])
    img16 = sn.quantize_16bit(lin, exposure=2.0)
    assert img16.dtype == np.uint16
    assert img16.tolist() == [[0, 32768, 65535], [65535, 65535, 0]]
    assert sn.downsample_bits(img16).tolist() == [[0, 2048, 4095], [4095, 4095, 0]]
    assert sn.downsample_bits(np.array([65535, 15], np.uint16), bits=8).tolist() == [255, 0]
    with pytest.raises(OutOfRangeError, match="exposure=0"):
        sn.quantize_16bit(lin, exposure=0.0)
    with pytest.raises(ConfigError, match="uint16"):
        sn.downsample_bits(np.zeros(3, np.int32))


def test_preview_8bit():
    raw = np.array([[0, 1024, 2048, 4095]], dtype=np.uint16)
    fixed = sn.to_preview_8bit(raw, auto=False)
    assert fixed.dtype == np.uint8
    assert fixed[0, 0] == 0 and fixed[0, 3] == 255
    assert fixed[0, 2] == round(255 * (2048 / 4095) ** (1 / 2.2))
    lin = sn.to_preview_8bit(raw, auto=False, gamma=1.0)
    assert lin[0, 1] == round(255 * 1024 / 4095)
    dim = np.linspace(100, 200, 1000).reshape(10, 100).astype(np.uint16)
    auto = sn.to_preview_8bit(dim, gamma=1.0)
    assert auto.min() == 0 and auto.max() == 255 and np.all(np.diff(auto.ravel().astype(int)) >= 0)
    flat = sn.to_preview_8bit(np.full((4, 4), 7, np.uint16))
    assert np.all(flat == 0)


def test_full_well_clips_before_the_adc():
    # at gain 0.5 the full well maps to ~2048 DN, below the ADC's top code
    L = _flat(_radiance_for_electrons(10 * P.full_well_e, 1e-3), (64, 64))
    raw = sn.expose(L, exposure_s=1e-3, gain=0.5, key=KEY, frame_index=0)
    assert raw.mean() == pytest.approx(0.5 * P.full_well_e / P.e_per_dn, abs=0.5)
    assert raw.max() < 2100


def test_read_noise_changes_every_frame():
    params = dataclasses.replace(P, dark_current_e_s=0.0, black_level_dn=200)
    a = sn.expose(_flat(0.0, (64, 64)), exposure_s=1e-3, params=params, key=KEY, frame_index=0)
    b = sn.expose(_flat(0.0, (64, 64)), exposure_s=1e-3, params=params, key=KEY, frame_index=1)
    assert a.std() > 3 and np.mean(a != b) > 0.7
