"""Tests for lunar_drake.terrain.fractal (fractal upscaling, tile by tile)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lunar_drake import rng
from lunar_drake.errors import ConfigError, NoDataError, OutOfRangeError
from lunar_drake.terrain import fractal as fr

PARAMS = fr.FractalParams()
FINE_RES = 0.04  # m per fine pixel in the statistical tests


def _coarse(n=8, seed=0, res=FINE_RES * 64):
    z = fr.coarse_fractal((n, n), resolution_m=res, rng=rng.generator(seed, "t"), params=PARAMS)
    return z * 20.0 + 0.5 * np.arange(n)[:, None] - 0.2 * np.arange(n)[None, :]


def _deviogram(z, lags):
    """RMS height deviation nu(lag) (m), averaged over row and column lags."""
    z = z.astype(np.float64)
    out = []
    for d in lags:
        a = np.mean((z[:, d:] - z[:, :-d]) ** 2)
        b = np.mean((z[d:] - z[:-d]) ** 2)
        out.append(np.sqrt(0.5 * (a + b)))
    return np.asarray(out)


LAGS = np.array([1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64])


# --- tile invariance ------------------------------------------------------------------


def test_upscale_high_tile_invariant_bit_identical():
    _, high = fr.split_frequencies(_coarse(), params=PARAMS)
    kw = dict(factor=64, key=12345, params=PARAMS, coarse_resolution_m=2.56)
    full = fr.upscale_high(high, **kw)
    assert full.shape == (512, 512) and full.dtype == np.float32
    for tile in (64, 128):
        tiled = np.empty_like(full)
        for r0 in range(0, 512, tile):
            for c0 in range(0, 512, tile):
                tiled[r0 : r0 + tile, c0 : c0 + tile] = fr.upscale_high(
                    high, window=(r0, c0, tile, tile), **kw
                )
        assert np.array_equal(tiled, full)
    for r0, c0, h, w in [(37, 91, 101, 77), (1, 1, 511, 511), (449, 3, 63, 509), (300, 5, 1, 1)]:
        win = fr.upscale_high(high, window=(r0, c0, h, w), **kw)
        assert np.array_equal(win, full[r0 : r0 + h, c0 : c0 + w])


def test_upscale_dem_and_low_tile_invariant():
    coarse = _coarse(seed=4)
    low, _ = fr.split_frequencies(coarse, params=PARAMS)
    kw = dict(factor=32, key=7, params=PARAMS, coarse_resolution_m=1.28)
    full = fr.upscale_dem(coarse, **kw)
    full_low = fr.upscale_low(low, factor=32)
    for win in [(0, 0, 64, 64), (64, 128, 64, 64), (13, 201, 99, 55), (255, 0, 1, 256)]:
        r0, c0, h, w = win
        assert np.array_equal(
            fr.upscale_dem(coarse, window=win, **kw), full[r0 : r0 + h, c0 : c0 + w]
        )
        assert np.array_equal(
            fr.upscale_low(low, factor=32, window=win), full_low[r0 : r0 + h, c0 : c0 + w]
        )


def test_noise_depends_on_key_and_levels_do_not_share_noise():
    zero = np.zeros((2, 2))
    kw = dict(factor=8, params=PARAMS, coarse_resolution_m=0.32)
    a = fr.upscale_high(zero, key=1, **kw)
    assert np.array_equal(a, fr.upscale_high(zero, key=1, **kw))
    assert not np.allclose(a, fr.upscale_high(zero, key=2, **kw))
    keys = fr._level_keys(1, 6)
    assert len(set(keys)) == 6


# --- alignment, decimation, low frequencies --------------------------------------------


def test_decimation_returns_coarse_and_block_means_keep_low_frequencies():
    F, n = 32, 24
    res = FINE_RES * F
    c = fr.coarse_fractal((n, n), resolution_m=res, rng=rng.generator(3, "blk"), params=PARAMS)
    c = c + 0.3 * np.arange(n)[:, None] - 0.1 * np.arange(n)[None, :]
    f = fr.upscale_dem(c, factor=F, key=5, params=PARAMS, coarse_resolution_m=res)
    assert f.shape == (n * F, n * F)
    # fine[::F, ::F] is the coarse DEM up to float32 rounding
    np.testing.assert_allclose(f[::F, ::F], c, rtol=0, atol=4 * np.spacing(np.float32(8.0)))
    h = F // 2
    f64 = f.astype(np.float64)
    bm = np.array(
        [
            [f64[i * F - h : i * F + h, j * F - h : j * F + h].mean() for j in range(1, n - 1)]
            for i in range(1, n - 1)
        ]
    )
    err = bm - c[1:-1, 1:-1]
    # coarse RMS step between neighbours is ~0.11 m plus the ramp; blocks stay within cm
    assert np.sqrt(np.mean(err**2)) < 0.03
    assert np.abs(err).max() < 0.1


def test_split_frequencies_identity_and_lowpass():
    c = _coarse(n=16, seed=2)
    low, high = fr.split_frequencies(c, params=PARAMS)
    np.testing.assert_allclose(low + high, c, rtol=0, atol=1e-12)
    assert np.std(np.diff(low, axis=1)) < 0.7 * np.std(np.diff(c, axis=1))
    low0, high0 = fr.split_frequencies(
        c, params=dataclasses.replace(PARAMS, lowpass_sigma_coarse_px=0)
    )
    assert np.array_equal(low0, c) and not high0.any()


def test_low_surface_at_matches_upscale_low_and_is_smooth():
    low, _ = fr.split_frequencies(_coarse(seed=5), params=PARAMS)
    F = 16
    up = fr.upscale_low(low, factor=F)
    rr, cc = np.meshgrid(np.arange(up.shape[0]), np.arange(up.shape[1]), indexing="ij")
    at = fr.low_surface_at(low, factor=F, rows=rr, cols=cc)
    assert at.dtype == np.float64
    assert np.abs(at - up).max() < 2e-6
    assert np.array_equal(at[::F, ::F], low)
    # continuous across coarse cell boundaries (C1 Catmull-Rom): tiny steps around them
    eps = 1e-6
    x = np.array([F * 3.0, F * 4.0])
    d = fr.low_surface_at(low, factor=F, rows=x + eps, cols=x) - fr.low_surface_at(
        low, factor=F, rows=x - eps, cols=x
    )
    assert np.abs(d).max() < 1e-4
    for method in ("cubic", "linear"):
        v = fr.low_surface_at(low, factor=F, rows=[-50.0, 1e4], cols=[3.5, -7.25], method=method)
        assert np.all(np.isfinite(v))


@pytest.mark.parametrize("method", ["cubic", "linear"])
def test_linear_ramp_reproduced_exactly(method):
    n, F = 6, 8
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    ramp = 3.0 * i - 2.0 * j + 1.0
    r, c = np.meshgrid(np.arange(n * F), np.arange(n * F), indexing="ij")
    expected = 3.0 * r / F - 2.0 * c / F + 1.0  # includes the extrapolated last F-1 px
    up = fr.upscale_low(ramp, factor=F, method=method)
    np.testing.assert_allclose(up, expected, rtol=0, atol=1e-5)
    rows, cols = np.array([-13.3, 2.5, 47.9, 70.1]), np.array([0.25, 60.0, -4.0, 33.3])
    np.testing.assert_allclose(
        fr.low_surface_at(ramp, factor=F, rows=rows, cols=cols, method=method),
        3.0 * rows / F - 2.0 * cols / F + 1.0,
        rtol=0,
        atol=1e-12,
    )


def test_catmull_rom_diamond_square_reproduces_ramp_without_noise():
    n, F = 12, 16
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    ramp = 3.0 * i - 2.0 * j
    quiet = dataclasses.replace(PARAMS, rms_deviation_m=0.0)
    up = fr.upscale_high(ramp, factor=F, key=1, params=quiet, coarse_resolution_m=1.0)
    r, c = np.meshgrid(np.arange(n * F), np.arange(n * F), indexing="ij")
    expected = ((3.0 * r - 2.0 * c) / F).astype(np.float32)
    # Exact (all weights are dyadic) wherever the stencils' reach (< 4 coarse cells)
    # stays clear of the clamped ghost nodes beyond the edges.
    interior = (slice(4 * F, (n - 5) * F + 1),) * 2
    assert np.array_equal(up[interior], expected[interior])
    # clamped edges: the high part continues flat beyond the last coarse sample
    assert not np.array_equal(up, expected)
    np.testing.assert_array_equal(up[::F, ::F], ramp.astype(np.float32))


# --- statistics -------------------------------------------------------------------------


@pytest.mark.parametrize("hurst", [0.5, 0.8])
def test_flat_input_hurst_and_rms(hurst):
    F = 256
    p = dataclasses.replace(PARAMS, hurst=hurst)
    nu = np.mean(
        [
            _deviogram(
                fr.upscale_dem(
                    np.zeros((4, 4)), factor=F, key=k, params=p, coarse_resolution_m=FINE_RES * F
                ),
                LAGS,
            )
            for k in range(2)
        ],
        axis=0,
    )
    h_fit = np.polyfit(np.log(LAGS), np.log(nu), 1)[0]
    assert abs(h_fit - hurst) < 0.15
    nu_ref = np.exp(np.interp(np.log(p.ref_baseline_m / FINE_RES), np.log(LAGS), np.log(nu)))
    assert 1 / 1.5 < nu_ref / p.rms_deviation_m < 1.5


def test_fractal_coarse_input_follows_target_law():
    """Coarse fBm + upscaling reproduces nu(dx) = nu_ref (dx / ref)^H at all lags."""
    F, n = 128, 16
    res = FINE_RES * F
    ratios, fits = [], []
    for k in range(2):
        c = fr.coarse_fractal((n, n), resolution_m=res, rng=rng.generator(k, "law"), params=PARAMS)
        f = fr.upscale_dem(
            c, factor=F, key=k, params=PARAMS, coarse_resolution_m=res, window=(0, 0, 1024, 1024)
        )
        nu = _deviogram(f, LAGS)
        ratios.append(nu / (PARAMS.rms_deviation_m * (LAGS * FINE_RES) ** PARAMS.hurst))
        fits.append(np.polyfit(np.log(LAGS), np.log(nu), 1)[0])
    assert np.all(np.abs(np.log(np.mean(ratios, axis=0))) < np.log(1.25))
    assert abs(np.mean(fits) - PARAMS.hurst) < 0.1


def test_coarse_fractal_law_and_determinism():
    p = dataclasses.replace(PARAMS, hurst=0.7)
    res = 5.0
    z = fr.coarse_fractal((256, 200), resolution_m=res, rng=rng.generator(1, "c"), params=p)
    assert z.shape == (256, 200) and z.dtype == np.float64
    assert abs(z.mean()) < 1e-12
    assert np.array_equal(
        z, fr.coarse_fractal((256, 200), resolution_m=res, rng=rng.generator(1, "c"), params=p)
    )
    lags = np.array([1, 2, 4, 8, 16])
    nu = _deviogram(z, lags)
    assert abs(np.polyfit(np.log(lags), np.log(nu), 1)[0] - 0.7) < 0.1
    target = p.rms_deviation_m * (res / p.ref_baseline_m) ** p.hurst
    assert 0.8 < nu[0] / target < 1.25


# --- artifacts --------------------------------------------------------------------------


def _flat_upscales(n_seeds, N=512, F=64):
    for k in range(n_seeds):
        f = fr.upscale_dem(
            np.zeros((N // F, N // F)),
            factor=F,
            key=1000 + k,
            params=PARAMS,
            coarse_resolution_m=FINE_RES * F,
        ).astype(np.float64)
        yield f - f.mean()


def test_spectrum_isotropic_without_harmonic_spikes():
    N, F = 512, 64
    win = np.hanning(N)
    p2 = np.zeros((N, N))
    p1 = np.zeros(N // 2 + 1)
    for f in _flat_upscales(16, N, F):
        p2 += np.abs(np.fft.fft2(f * np.outer(win, win))) ** 2
        p1 += np.mean(np.abs(np.fft.rfft((f - f.mean(1, keepdims=True)) * win, axis=1)) ** 2, 0)
        p1 += np.mean(np.abs(np.fft.rfft((f - f.mean(0)) * win[:, None], axis=0)) ** 2, 1)
    k = np.fft.fftfreq(N) * N
    ky, kx = np.meshgrid(k, k, indexing="ij")
    kr = np.hypot(kx, ky)
    ang = np.degrees(np.arctan2(np.abs(ky), np.abs(kx)))
    lo = N / F
    while lo < 0.4 * N:
        ring = (kr >= lo) & (kr < lo * 2**0.25)
        axes = p2[ring & ((ang < 6) | (ang > 84))].mean()
        diag = p2[ring & (np.abs(ang - 45) < 6)].mean()
        assert 0.5 < axes / diag < 2.0, (lo, axes / diag)
        lo *= 2**0.25
    # power falls like k^-(2H+2) (a few tenths of slack for the finite, pinned surface)
    ir = np.rint(kr).astype(int)
    radial = np.bincount(ir.ravel(), p2.ravel()) / np.bincount(ir.ravel())
    kk = np.arange(N // F, N // 4)
    slope = np.polyfit(np.log(kk), np.log(radial[kk]), 1)[0]
    assert abs(slope + (2 * PARAMS.hurst + 2)) < 0.5
    # no spikes at the harmonics n * N / 2^m of every level's spacing
    for h in range(N // F, N // 2 - 2, N // F):
        assert p1[h] / np.sqrt(p1[h - 2] * p1[h + 2]) < 3.0
        assert radial[h] / np.sqrt(radial[h - 2] * radial[h + 2]) < 3.0


def test_no_periodic_variance_pattern_within_coarse_cells():
    """Roughness (squared Laplacian) is the same at every phase of the coarse cell.

    Linear diamond-square or inconsistent diamond/square noise gives phase-to-phase
    spreads of 30-100 %; Catmull-Rom with consistent noise stays at sampling noise.
    """
    N, F = 512, 64
    acc = np.zeros((F, F))
    cnt = np.zeros((F, F))
    for f in _flat_upscales(16, N, F):
        lap = np.zeros((N, N))
        lap[1:-1, 1:-1] = (
            f[2:, 1:-1] + f[:-2, 1:-1] + f[1:-1, 2:] + f[1:-1, :-2] - 4 * f[1:-1, 1:-1]
        ) ** 2
        ok = np.zeros((N, N))
        ok[1:-1, 1:-1] = 1.0  # the image border has no Laplacian
        acc += lap.reshape(N // F, F, N // F, F).sum(axis=(0, 2))
        cnt += ok.reshape(N // F, F, N // F, F).sum(axis=(0, 2))
    phase = acc / cnt
    mean = phase.mean()
    assert phase.std() / mean < 0.12
    for i in (0, 1):
        for j in (0, 1):
            assert abs(phase[i::2, j::2].mean() / mean - 1) < 0.1
    assert abs(phase[0, :].mean() / mean - 1) < 0.1  # along coarse grid lines
    assert abs(phase[:, 0].mean() / mean - 1) < 0.1
    assert abs(phase[F // 2, :].mean() / mean - 1) < 0.1  # and half-way between them


def test_noise_std_consistent_between_half_steps():
    sd, ss = fr.level_noise_std(3, params=PARAMS, coarse_resolution_m=8.0)
    assert sd / ss == pytest.approx(2 ** (PARAMS.hurst / 2))
    sd2, _ = fr.level_noise_std(4, params=PARAMS, coarse_resolution_m=8.0)
    assert ss / sd2 == pytest.approx(2 ** (PARAMS.hurst / 2))


# --- errors -----------------------------------------------------------------------------


@pytest.mark.parametrize("factor", [3, 0, -2, 6, 2.0, True])
def test_bad_factor(factor):
    z = np.zeros((4, 4))
    for call in (
        lambda: fr.upscale_low(z, factor=factor),
        lambda: fr.upscale_high(z, factor=factor, key=1, params=PARAMS, coarse_resolution_m=1.0),
        lambda: fr.low_surface_at(z, factor=factor, rows=0.0, cols=0.0),
    ):
        with pytest.raises(ConfigError, match=f"factor={factor!r}"):
            call()


def test_nan_input_rejected_with_value():
    z = np.zeros((4, 4))
    z[2, 1] = np.nan
    with pytest.raises(NoDataError, match=r"row 2, col 1: nan"):
        fr.split_frequencies(z, params=PARAMS)
    with pytest.raises(NoDataError, match="nan"):
        fr.upscale_high(z, factor=4, key=1, params=PARAMS, coarse_resolution_m=1.0)
    with pytest.raises(NoDataError, match="nan"):
        fr.upscale_dem(z, factor=4, key=1, params=PARAMS, coarse_resolution_m=1.0)


@pytest.mark.parametrize(
    "field, value",
    [
        ("hurst", 1.0),
        ("hurst", 0.0),
        ("hurst", float("nan")),
        ("rms_deviation_m", -0.1),
        ("ref_baseline_m", 0.0),
        ("lowpass_sigma_coarse_px", -1.0),
    ],
)
def test_params_validated(field, value):
    with pytest.raises(OutOfRangeError, match=f"{field}={value!r}"):
        fr.FractalParams(**{field: value})


def test_other_bad_arguments():
    z = np.zeros((4, 4))
    with pytest.raises(ConfigError, match="low_interpolation='nearest'"):
        fr.FractalParams(low_interpolation="nearest")
    with pytest.raises(OutOfRangeError, match=r"window=\(0, 0, 17, 4\)"):
        fr.upscale_low(z, factor=4, window=(0, 0, 17, 4))
    with pytest.raises(OutOfRangeError, match="coarse_resolution_m=-1"):
        fr.upscale_high(z, factor=4, key=1, params=PARAMS, coarse_resolution_m=-1)
    with pytest.raises(ConfigError, match="key=-5"):
        fr.upscale_high(z, factor=4, key=-5, params=PARAMS, coarse_resolution_m=1.0)
    with pytest.raises(OutOfRangeError, match="shape"):
        fr.coarse_fractal((0, 3), resolution_m=1.0, rng=rng.generator(0, "x"), params=PARAMS)


def test_factor_one_is_identity():
    c = _coarse(n=5)
    low, high = fr.split_frequencies(c, params=PARAMS)
    np.testing.assert_array_equal(fr.upscale_low(low, factor=1), low.astype(np.float32))
    out = fr.upscale_high(high, factor=1, key=3, params=PARAMS, coarse_resolution_m=1.0)
    np.testing.assert_array_equal(out, high.astype(np.float32))
