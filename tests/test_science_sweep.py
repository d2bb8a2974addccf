"""The world model's hull sweep: exact along the grid's axes, close to an independent
ray march and to the render engine's banded horizons elsewhere, chunk-invariant."""

import math

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from lunar_drake.render.horizon import horizon_angles
from lunar_drake.science.sweep import NO_CASTER, horizon_tangents
from lunar_drake.terrain.crs import MOON_RADIUS_M as R

RES = 0.5


def _terrain(n: int = 64, seed: int = 1) -> np.ndarray:
    """Rough, float32-representable heights (m): hills plus a random walk along rows."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n]
    z = np.sin(x / 7.0) * 1.5 + np.cos(y / 5.0) + np.cumsum(rng.normal(size=(n, n)), axis=1) * 0.05
    return z.astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("azimuth", [0.0, 90.0, 180.0, 270.0])
def test_axis_azimuths_are_the_exact_maximum_over_the_row_or_column(azimuth):
    z = _terrain()
    n = z.shape[0]
    t = horizon_tangents(z, azimuth_deg=azimuth, resolution_m=RES)
    # Towards the Sun: north = row - k, east = col + k, south = row + k, west = col - k.
    dr, dc = {0.0: (-1, 0), 90.0: (0, 1), 180.0: (1, 0), 270.0: (0, -1)}[azimuth]
    ref = np.full(z.shape, NO_CASTER)
    for r in range(n):
        for c in range(n):
            k = np.arange(1, n)
            rr, cc = r + dr * k, c + dc * k
            ok = (rr >= 0) & (rr < n) & (cc >= 0) & (cc < n)
            if ok.any():
                d = k[ok] * RES
                ref[r, c] = np.max((z[rr[ok], cc[ok]] - z[r, c] - d * d / (2 * R)) / d)
    # The slope leaving the centre adds d / 2R (1e-7) over the first sample's.
    assert np.allclose(t, ref, rtol=1e-6, atol=2e-6)


def _ray_march(z: np.ndarray, azimuth: float, pixels) -> np.ndarray:
    """Horizon tangents at ``pixels`` by marching each one's own ray over the bilinear
    surface in 0.05-pixel steps (an independent reference)."""
    n = z.shape[0]
    a = math.radians(azimuth)
    dc, dr = math.sin(a), -math.cos(a)
    steps = np.arange(1, 40 * n) * 0.05
    out = []
    for r, c in pixels:
        rr, cc = r + dr * steps, c + dc * steps
        ok = (rr >= 0) & (rr <= n - 1) & (cc >= 0) & (cc <= n - 1)
        if not ok.any():
            out.append(NO_CASTER)
            continue
        d = steps[ok] * RES
        zs = map_coordinates(z, [rr[ok], cc[ok]], order=1)
        out.append(np.max((zs - z[r, c] - d * d / (2 * R)) / d))
    return np.array(out)


@pytest.mark.parametrize("near", [3, 8])  # 3: what the world model's sweeps use
@pytest.mark.parametrize("azimuth", [33.0, 45.0, 200.0, 301.7])
def test_any_azimuth_matches_a_ray_march_on_the_bilinear_surface(azimuth, near):
    y, x = np.mgrid[0:64, 0:64]
    z = (np.sin(x / 7.0) * 1.5 + np.cos(y / 5.0)).astype(np.float32).astype(np.float64)
    t = horizon_tangents(z, azimuth_deg=azimuth, resolution_m=RES, near=near)
    pixels = [(r, c) for r in range(2, 62, 3) for c in range(2, 62, 3)]
    ref = _ray_march(z, azimuth, pixels)
    got = np.array([t[r, c] for r, c in pixels])
    seen = ref > 0.5 * NO_CASTER
    assert np.array_equal(seen, got > 0.5 * NO_CASTER)
    err = np.degrees(np.abs(np.arctan(got[seen]) - np.arctan(ref[seen])))
    assert np.median(err) < 0.01 and np.percentile(err, 95) < 0.25, (np.median(err), err.max())


@pytest.mark.parametrize(("near", "p95_deg", "disagree"), [(3, 0.3, 0.007), (8, 0.15, 0.005)])
def test_agrees_with_the_render_engines_banded_horizons_on_rough_terrain(near, p95_deg, disagree):
    # near 3 is what the world model's sweeps use (measured: p95 0.25-0.27 deg and
    # 0.56-0.62 % of cells disagreeing); 8 is horizon_tangents' default.
    # Two independent engines: render.horizon resolves the band by slopes, exact near
    # field; the sweep by hulls. Fractal-like roughness at 4 cm, as the world model sees.
    rng = np.random.default_rng(4)
    f = np.fft.fftfreq(192)
    k = np.hypot(*np.meshgrid(f, f))
    k[0, 0] = 1.0
    spec = rng.normal(size=k.shape) + 1j * rng.normal(size=k.shape)
    z = np.real(np.fft.ifft2(spec * k**-1.6))
    z = (0.05 * z / z.std()).astype(np.float32).astype(np.float64)  # 5 cm rms
    for az in (7.5, 112.5, 247.5):
        h_new = np.degrees(np.arctan(horizon_tangents(z, azimuth_deg=az, resolution_m=0.04,
                                                      near=near)))  # fmt: skip
        h_old = horizon_angles(
            z, azimuth_deg=az, resolution_m=0.04, elevation_range_deg=(-1.0, 8.0),
            resolution_deg=0.05,
        )  # fmt: skip
        h_old = np.degrees(h_old)
        band = (h_old > -0.9) & (h_old < 7.9)
        err = np.abs(np.clip(h_new, -1.0, 8.0) - h_old)[band]
        assert band.mean() > 0.5
        assert np.percentile(err, 95) < p95_deg, (az, np.percentile(err, 95))
        lit_new, lit_old = h_new < 3.0, h_old < 3.0
        assert np.mean(lit_new != lit_old) < disagree, az


def test_chunking_never_changes_a_byte():
    z = _terrain(80, seed=3)
    for az in (12.0, 135.0, 251.0):
        a = horizon_tangents(z, azimuth_deg=az, resolution_m=RES, chunk=7, workers=1)
        b = horizon_tangents(z, azimuth_deg=az, resolution_m=RES, chunk=4096, workers=2)
        assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("azimuth", [10.0, 60.0, 150.0, 250.0])
def test_the_canonical_dem_is_the_turned_grid(azimuth):
    from lunar_drake.render.horizon import sweep_orientation
    from lunar_drake.science.sweep import canonical_dem

    z = np.random.default_rng(4).normal(size=(70, 131)).astype(np.float32)
    o = sweep_orientation(azimuth, z.shape)
    zc = canonical_dem(z, o)
    assert zc.dtype == np.float32 and zc.flags.c_contiguous  # float32 stays float32
    assert np.array_equal(zc, o.canon(z))
    z64 = canonical_dem(z.astype(np.float64) / 3.0, o)
    assert z64.dtype == np.float64 and np.array_equal(z64, o.canon(z.astype(np.float64) / 3.0))


@pytest.mark.parametrize("azimuth", [33.0, 200.0])
def test_float32_heights_give_the_bytes_of_their_float64_copy(azimuth):
    # The kernels widen each float32 height as they load it: the sunlight of every mode
    # is bit-identical to that of the same heights held as float64.
    from lunar_drake.science.sweep import EPOCH, SECTOR, TANGENT, Sweep

    z32 = _terrain(72, seed=5).astype(np.float32) * np.float32(0.37)  # odd float32 values
    out = {}
    for z in (z32, z32.astype(np.float64)):
        sw = Sweep(z, azimuth_deg=azimuth, resolution_m=RES, chunk=16, near=3)
        assert sw.zc.dtype == z.dtype
        par = sw.sun_par(flux_w_m2=1000.0, mask_deg=0.0, radius_deg=0.27, w_mean=0.25)
        res = []
        for mode, els in ((SECTOR, [3.0, 1.0, 2.0, 2.5, 2.9]), (EPOCH, [2.0]), (TANGENT, [0.0])):
            a = np.zeros(sw.orient.shape, np.float32)
            b, lit = np.zeros_like(a), np.zeros(a.shape, np.uint8)
            sw.run(mode, par, els, a, b, lit)
            res.append((a.tobytes(), b.tobytes(), lit.tobytes()))
            assert (mode == TANGENT or (lit.any() and not lit.all())), mode
        out[z.dtype] = res
    assert out[np.dtype(np.float32)] == out[np.dtype(np.float64)]
