"""Sub-cell regolith texture (render/regolith.py) and the smooth lightmap reconstruction
(render/soft_shadow.py): determinism, band limit, numba/numpy agreement, straight
sub-cell shadow edges, and more local contrast in rendered frames."""

import itertools
import math

import numba
import numpy as np
import pytest

from lunar_drake.errors import OutOfRangeError
from lunar_drake.render.camera import CameraConfig, TerrainCameraRenderer
from lunar_drake.render.regolith import (
    RegolithTextureConfig,
    build_texture,
    inverse_footprint,
    sample_texture,
    sample_texture_nb,
)
from lunar_drake.render.shading import RasterSampler
from lunar_drake.render.soft_shadow import soft_lightmap, soft_lightmap_at
from lunar_drake.terrain.heightfield import Heightfield


def _points(n=4000, seed=1, half=40.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-half, half, n), rng.uniform(-half, half, n)


def test_config_validation_names_the_value():
    with pytest.raises(OutOfRangeError, match=r"albedo_contrast = 0\.9"):
        RegolithTextureConfig(albedo_contrast=0.9)
    with pytest.raises(OutOfRangeError, match="table_size = 100"):
        RegolithTextureConfig(table_size=100)
    with pytest.raises(OutOfRangeError, match="shortest_wavelength_m"):
        RegolithTextureConfig(shortest_wavelength_m=0.2)
    with pytest.raises(OutOfRangeError, match="seed"):
        RegolithTextureConfig(seed=-1)
    assert RegolithTextureConfig().octaves == 5  # 8, 4, 2, 1, 0.5 cm


def test_texture_is_a_deterministic_function_of_site_position_and_seed():
    x, y = _points()
    near = np.full(x.size, 1e4, np.float32)  # 0.1 mm footprint: every octave on
    tex = build_texture(RegolithTextureConfig())
    a1 = sample_texture(tex, x, y, near)
    # the same points in another order and another batch: same values, bit for bit
    perm = np.random.default_rng(5).permutation(x.size)
    a2 = sample_texture(tex, x[perm], y[perm], near[perm])
    for u, v in zip(a1, a2, strict=True):
        assert u[perm].tobytes() == v.tobytes()
    # a fresh build (no cache) gives the same table
    fresh = build_texture.__wrapped__(RegolithTextureConfig())
    assert fresh.top.tobytes() == tex.top.tobytes()
    # another seed: another texture
    other = sample_texture(build_texture(RegolithTextureConfig(seed=15)), x, y, near)
    assert np.corrcoef(a1[1], other[1])[0, 1] < 0.1
    # amplitudes as configured (all octaves on): rms albedo, rms slope
    cfg = tex.config
    assert np.std(a1[0]) == pytest.approx(cfg.albedo_contrast, rel=0.15)
    slope = np.degrees(np.arctan(np.sqrt(np.mean(a1[1] ** 2 + a1[2] ** 2))))
    assert slope == pytest.approx(cfg.rms_slope_deg, rel=0.15)
    # periodic with the documented period (whole texture), float32-exact up to rounding
    P = cfg.period_m
    b = sample_texture(tex, x + P, y - 2 * P, near)
    np.testing.assert_allclose(b[1], a1[1], atol=2e-3)


def _rolled_pose(p, *, tilt_deg, roll_deg):
    t = math.radians(tilt_deg)
    z = np.array([math.cos(t), 0.0, -math.sin(t)])
    x = np.array([0.0, -1.0, 0.0])
    yv = np.cross(z, x)
    r = math.radians(roll_deg)
    x, yv = math.cos(r) * x + math.sin(r) * yv, -math.sin(r) * x + math.cos(r) * yv
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, yv, z])
    X[:3, 3] = p
    return X


@pytest.mark.parametrize("engine", ["raycast", "heightfield"])
def test_two_camera_poses_see_the_same_texture_on_the_same_ground(engine):
    """A square camera rolled by 90 deg about its axis casts the same rays, permuted:
    each ground point is seen by both poses, and its textured radiance is the same
    (the texture depends on (x, y), not on the camera)."""
    n = 256
    hf = Heightfield.from_array(np.zeros((n, n), np.float32), resolution_m=0.1)
    model = CameraConfig(width=96, height=96, fov_y_deg=40.0, engine=engine)
    r = TerrainCameraRenderer(heightfield=hf, model=model)
    il, _ = r.illumination(sun_dir_W=(0.3, 0.5, 0.81))
    p = [0.0, 0.0, 1.5]
    a = r.shade(X_WC=_rolled_pose(p, tilt_deg=70.0, roll_deg=0.0), illumination=il).radiance
    b = r.shade(X_WC=_rolled_pose(p, tilt_deg=70.0, roll_deg=90.0), illumination=il).radiance
    rel = min(float(np.median(np.abs(np.rot90(b, k) - a) / a)) for k in (1, -1))
    assert rel < 1e-3
    # and the texture is there: the flat plane is not uniformly shaded
    assert a.std() > 0.02 * a.mean()


def test_high_octaves_fade_with_the_pixel_footprint():
    x, y = _points(20000)
    tex = build_texture(RegolithTextureConfig())
    lam = tex.config.wavelengths_m
    var = []
    feet = [1e-4, lam[-1], lam[2], lam[0] / 2.0, lam[0] / 1.5, lam[0]]
    for f in feet:
        _, gx, gy = sample_texture(tex, x, y, np.full(x.size, 1.0 / f, np.float32))
        var.append(float(np.mean(gx * gx + gy * gy)))
    assert all(a >= b for a, b in itertools.pairwise(var))  # monotone
    # footprints of half the longest wavelength and more: even the coarsest octave is
    # off (it fades out at two footprints per wavelength)
    assert var[3] == 0.0 and var[-1] == 0.0
    # a footprint of the finest wavelength: the octaves down to 2 footprints remain
    sw = tex.params[:, 7] * 31.0 / 4.0  # per-axis slope rms of each octave
    on = lam >= 4.0 * feet[1]
    assert var[1] == pytest.approx(2.0 * float(np.sum(sw[on] ** 2)), rel=0.2)


def test_numba_and_numpy_samplers_agree():
    x, y = _points(5000, seed=3, half=500.0)  # far from the origin too
    rng = np.random.default_rng(4)
    ifoot = (1.0 / rng.uniform(1e-4, 0.05, x.size)).astype(np.float32)
    tex = build_texture(RegolithTextureConfig())
    ref = sample_texture(tex, x, y, ifoot)
    out = [np.empty(x.size, np.float32) for _ in range(3)]
    sample_texture_nb(tex.top, tex.bottom, tex.params, tex.period, tex.fade, x, y, ifoot, *out)
    for a, b in zip(ref, out, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)


def test_inverse_footprint():
    f = inverse_footprint(np.array([10.0]), 1e-3, np.array([0.25]))
    assert float(f[0]) == pytest.approx(0.5 / 0.01)


# ----------------------------------------------------------------------------------------
# soft shadow edges
# ----------------------------------------------------------------------------------------
@numba.njit
def _soft_nb(a, p, x, y, out):
    for i in range(x.size):
        out[i] = soft_lightmap_at(a, p, x[i], y[i])


def _half_plane_lightmap(n=64, slope=0.23, offset=0.37):
    """A lightmap of 1 m cells, lit (1) on one side of the line y = slope x + offset
    (cell centres), dark (0) on the other: a shadow edge sharper than a cell."""
    c = np.arange(n) + 0.5 - n / 2  # cell centre coordinates (site m)
    X, Y = np.meshgrid(c, c[::-1])
    return (Y > slope * X + offset).astype(np.float32)


def _edge_residual(sampler_fn, slope=0.23, offset=0.37, n=64):
    """RMS distance (cells) between the 0.5 contour of the reconstruction, found per
    column of a fine grid, and the true straight edge."""
    xs = np.linspace(-20.0, 20.0, 401)
    ys = np.linspace(-25.0, 25.0, 2001)
    X, Y = np.meshgrid(xs, ys)
    f = sampler_fn(X.ravel(), Y.ravel()).reshape(X.shape)
    err = []
    for j, x in enumerate(xs):
        col = f[:, j] - 0.5
        pos = col > 0
        k = np.flatnonzero(pos[:-1] != pos[1:])
        assert k.size == 1  # one crossing: no wiggles across the edge
        k = k[0]
        y0 = ys[k] - col[k] * (ys[k + 1] - ys[k]) / (col[k + 1] - col[k])
        err.append(y0 - (slope * x + offset))
    err = np.asarray(err)
    return float(np.sqrt(np.mean((err - err.mean()) ** 2)))


@pytest.mark.parametrize("slope", [0.23, 0.5, 1.0])
def test_soft_lightmap_edge_of_binary_cells_is_sub_cell_and_no_worse(slope):
    """A shadow edge sharper than a cell (binary cells of a half-plane): the 0.5 contour
    of the B-spline stays within a quarter cell rms of the true line and closer to it
    than bilinear's (a 3 x 3 kernel cannot straighten the steps of a shallow edge --
    the cells carry no sub-cell position; see docs/lighting.md)."""
    lm = _half_plane_lightmap(slope=slope)
    s = RasterSampler(lm, bounds=(-32.0, -32.0, 32.0, 32.0), outside=1.0)
    soft = _edge_residual(lambda x, y: soft_lightmap(s, x, y), slope=slope)
    bil = _edge_residual(lambda x, y: s(x, y), slope=slope)
    assert soft < 0.25 and soft < bil


def test_soft_lightmap_interpolates_a_resolved_penumbra_exactly():
    """Where the penumbra spans cells (the fraction linear across them, as under a low
    Sun along its azimuth) the B-spline reproduces it: no cell pattern at all."""
    c = np.arange(64) + 0.5 - 32
    X, _ = np.meshgrid(c, c[::-1])
    lm = np.clip(0.5 + 0.1 * X, 0.0, 1.0).astype(np.float32)  # a 10-cell ramp
    s = RasterSampler(lm, bounds=(-32.0, -32.0, 32.0, 32.0))
    x = np.linspace(-4.0, 4.0, 801)
    y = np.full(x.size, 0.3)
    np.testing.assert_allclose(soft_lightmap(s, x, y), 0.5 + 0.1 * x, atol=1e-5)


def test_soft_lightmap_is_smooth_inside_cells_and_numba_matches_numpy():
    lm = _half_plane_lightmap()
    s = RasterSampler(lm, bounds=(-32.0, -32.0, 32.0, 32.0), outside=0.25)
    rng = np.random.default_rng(7)
    x = rng.uniform(-40.0, 40.0, 20000)  # also beyond the raster: the outside value
    y = rng.uniform(-40.0, 40.0, 20000)
    ref = soft_lightmap(s, x, y)
    out = np.empty(x.size, np.float32)
    from lunar_drake.render.fast_engine import _tex_args

    a, p = _tex_args(s)
    _soft_nb(a, p, x, y, out)
    np.testing.assert_allclose(out, ref, atol=2e-6)
    assert (ref[(np.abs(x) > 32.5) | (np.abs(y) > 32.5)] == np.float32(0.25)).all()
    # C1: along a line across the edge the second difference stays small (bilinear
    # has kinks at cell boundaries: spikes in its second difference)
    t = np.linspace(-3.0, 3.0, 6001)
    xl, yl = 0.5 + 0.0 * t, t + 0.37
    d2s = np.abs(np.diff(soft_lightmap(s, xl, yl).astype(np.float64), 2)).max()
    d2b = np.abs(np.diff(s(xl, yl).astype(np.float64), 2)).max()
    assert d2s < 0.1 * d2b


# ----------------------------------------------------------------------------------------
# rendered frames
# ----------------------------------------------------------------------------------------
def _highpass_std(img):
    import cv2

    blur = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.5)
    return float((img - blur).std())


@pytest.mark.parametrize("engine", ["heightfield", "raycast"])
def test_texture_adds_local_contrast_in_the_foreground(engine):
    yy, xx = np.mgrid[0:200, 0:200] * 0.1
    z = (0.2 * np.sin(xx / 1.9) * np.cos(yy / 2.7)).astype(np.float32)
    hf = Heightfield.from_array(z, resolution_m=0.1)
    model = CameraConfig(width=192, height=144, fov_y_deg=40.0, engine=engine)
    t = math.radians(35.0)
    zc = np.array([math.cos(t), 0.0, -math.sin(t)])
    xc = np.array([0.0, -1.0, 0.0])
    X = np.eye(4)
    X[:3, :3] = np.column_stack([xc, np.cross(zc, xc), zc])
    X[:3, 3] = [-4.0, 0.0, float(hf.height(np.array([-4.0]), np.array([0.0]))[0]) + 1.5]
    out = {}
    for on in (False, True):
        r = TerrainCameraRenderer(
            heightfield=hf, model=model, texture=RegolithTextureConfig(enabled=on)
        )
        il, _ = r.illumination(sun_dir_W=(0.5, 0.6, 0.62))
        img = r.shade(X_WC=X, illumination=il)
        fg = img.radiance[model.height // 2 :]  # the lower half: the foreground
        assert (img.label[model.height // 2 :] == 1).all()
        out[on] = _highpass_std(fg)
    assert out[True] > 3.0 * out[False]
