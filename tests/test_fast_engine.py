"""The fast Hapke camera engine: DEM ray marching, the reflectance table, rover pixels,
and agreement with the Embree reference engine."""

import dataclasses as dc
import functools
import math

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import hapke as hapke_mod
from lunar_drake.render.camera import CameraConfig, TerrainCameraRenderer
from lunar_drake.render.fast_engine import rover_pixel_mask
from lunar_drake.render.hapke_lut import (
    ReflectanceLUT,
    lut_axis,
    lut_axis_f32,
    lut_reflectance_at,
    lut_reflectance_at_f32,
)
from lunar_drake.render.heightfield_trace import (
    DemPyramid,
    direction_f32,
    pixel_direction,
    trace_heightfield,
)
from lunar_drake.render.raycast import DynamicMesh, PinholeCamera, TerrainRaycaster
from lunar_drake.render.shading import RasterSampler
from lunar_drake.render.shapes import box_mesh
from lunar_drake.render.terrain_lod import TerrainLOD
from lunar_drake.terrain.heightfield import Heightfield


def _pose(p, *, yaw_deg=0.0, tilt_deg=15.0, roll_deg=0.0):
    """X_WC of a Drake camera at p looking along yaw, pitched down, rolled."""
    y, t = math.radians(yaw_deg), math.radians(tilt_deg)
    z = np.array([math.cos(t) * math.cos(y), math.cos(t) * math.sin(y), -math.sin(t)])
    x = np.array([math.sin(y), -math.cos(y), 0.0])
    yv = np.cross(z, x)
    r = math.radians(roll_deg)
    x, yv = math.cos(r) * x + math.sin(r) * yv, -math.sin(r) * x + math.cos(r) * yv
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, yv, z])
    X[:3, 3] = p
    return X


def _bumpy(n=256, res=0.1):
    yy, xx = np.mgrid[0:n, 0:n] * res
    z = 0.3 * np.sin(xx / 1.7) * np.cos(yy / 2.3) + 0.15 * np.sin(xx / 0.6 + yy / 0.9)
    c = n * res / 2
    z += 1.2 * np.exp(-((xx - c - 6) ** 2 + (yy - c) ** 2) / 4.0)  # a hill ahead
    return Heightfield.from_array(z.astype(np.float32), resolution_m=res)


def _cam(w=160, h=120, fov=50.0):
    return PinholeCamera.from_fov(width=w, height=h, fov_y_rad=math.radians(fov))


def _trace(pyr, cam, X, **kw):
    return trace_heightfield(
        pyr,
        width=cam.width,
        height=cam.height,
        fx=cam.fx,
        fy=cam.fy,
        cx=cam.cx,
        cy=cam.cy,
        X_WC=X,
        **kw,
    )


def test_tilted_plane_hits_are_exact_for_any_camera_roll():
    n, res = 128, 0.2
    yy, xx = np.mgrid[0:n, 0:n]
    a, b = 0.05, -0.08  # plane z = a x + b y in site coordinates
    hf0 = Heightfield.from_array(np.zeros((n, n), np.float32), resolution_m=res)
    left, bottom, right, top = hf0.bounds
    x = left + (xx + 0.5) * res
    y = top - (yy + 0.5) * res
    hf = Heightfield.from_array((a * x + b * y).astype(np.float32), resolution_m=res)
    pyr = DemPyramid.from_heightfield(hf)
    cam = _cam()
    for roll in (0.0, 25.0):
        X = _pose([0.5, -0.3, 2.0], yaw_deg=30.0, tilt_deg=20.0, roll_deg=roll)
        tr = _trace(pyr, cam, X, iters=2)
        d = tr.directions()
        p = X[:3, 3]
        # closed form: p_z + t d_z = a (p_x + t d_x) + b (p_y + t d_y)
        den = d[2] - a * d[0] - b * d[1]
        t_exact = np.where(den < 0, (a * p[0] + b * p[1] - p[2]) / den, np.inf)
        hit = p[:, None] + t_exact * d
        # silhouettes (here the DEM's edge) are decided per azimuth bin: up to half a
        # pixel's footprint sideways; depths by the bin's centre ray (relative error of
        # the order of the cross slope times half a pixel angle)
        m = np.where(np.isfinite(t_exact), t_exact, 0.0) / cam.fx
        inside = (hit[0] > left + m) & (hit[0] < right - m)
        inside &= (hit[1] > bottom + m) & (hit[1] < top - m)
        ok = np.isfinite(t_exact) & inside
        assert ok.mean() > 0.3
        np.testing.assert_allclose(tr.t[ok], t_exact[ok], rtol=1e-3)
        assert np.isinf(tr.t[~np.isfinite(t_exact)]).all()  # sky stays sky


def test_trace_agrees_with_embree_on_bumpy_terrain_and_sees_the_hill():
    hf = _bumpy()
    pyr = DemPyramid.from_heightfield(hf)
    cam = _cam()
    X = _pose([-4.0, 0.3, 1.4], tilt_deg=10.0)
    tr = _trace(pyr, cam, X)
    rc = TerrainRaycaster()
    rc.set_terrain(TerrainLOD.build(hf, center_xy=(-4.0, 0.3), tile_px=64, near_radius_m=40.0))
    rays, _ = cam.world_rays(X)
    te = rc.cast_rays(rays, common_origin=True).t_hit
    both = np.isfinite(te) & np.isfinite(tr.t)
    assert (np.isfinite(te) == np.isfinite(tr.t)).mean() > 0.995
    rel = np.abs(tr.t[both] - te[both]) / te[both]
    assert np.median(rel) < 1e-3 and np.quantile(rel, 0.95) < 0.02
    # the hill occludes: straight ahead the first hit is on it, well before the far edge
    mid = (cam.height // 2) * cam.width + cam.width // 2
    assert 6.0 < tr.t[mid] < 12.0


@pytest.mark.parametrize(
    ("p", "yaw"),
    [
        ([-16.0, 0.3, 3.0], 0.0),  # outside the DEM, looking in: the general march
        ([10.0, -6.0, 1.5], 60.0),  # near the east edge, rays leave it ahead and right
        ([-8.0, -7.0, 1.5], 225.0),  # facing a corner of the DEM
    ],
)
def test_trace_agrees_with_embree_from_outside_and_near_the_edges(p, yaw):
    # profile steps well inside the DEM take a branch-free path, the rest the general
    # one (entering, leaving): both must agree with Embree
    hf = _bumpy()
    pyr = DemPyramid.from_heightfield(hf)
    cam = _cam()
    X = _pose(p, yaw_deg=yaw, tilt_deg=12.0)
    tr = _trace(pyr, cam, X)
    rc = TerrainRaycaster()
    rc.set_terrain(TerrainLOD.build(hf, center_xy=(0.0, 0.0), tile_px=64, near_radius_m=40.0))
    rays, _ = cam.world_rays(X)
    te = rc.cast_rays(rays, common_origin=True).t_hit
    assert np.isfinite(te).mean() > 0.2
    assert (np.isfinite(te) == np.isfinite(tr.t)).mean() > 0.99
    both = np.isfinite(te) & np.isfinite(tr.t)
    rel = np.abs(tr.t[both] - te[both]) / te[both]
    assert np.median(rel) < 2e-3 and np.quantile(rel, 0.95) < 0.03


def _ridged(n=300, res=0.1, seed=3):
    """Rolling ground, a berm across it, a crater-like dip and scattered boulders:
    stretches hidden behind crests (odd size: the pyramid pads rows and columns)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0 : n + 7] * res
    z = 0.4 * np.sin(xx / 2.1) + 0.25 * np.cos(yy / 1.3 + xx / 3.0)
    z -= 1.5 * np.exp(-((xx - 20.0) ** 2 + (yy - 12.0) ** 2) / 18.0)
    z += 1.2 * np.exp(-((xx - 14.0) ** 2) / 0.8)  # a berm across the site
    for _ in range(60):
        cx_, cy_ = rng.uniform(0, xx.max()), rng.uniform(0, yy.max())
        z += rng.uniform(0.1, 0.6) * np.exp(-((xx - cx_) ** 2 + (yy - cy_) ** 2) / 0.05)
    return Heightfield.from_array(z.astype(np.float32), resolution_m=res)


def test_the_max_pyramid_bounds_every_level_0_sample_it_covers():
    hf = _ridged(n=75)
    pyr = DemPyramid.from_heightfield(hf)
    z0 = pyr.data[: pyr.heights[0] * pyr.widths[0]].reshape(pyr.heights[0], pyr.widths[0])
    for lev in range(pyr.levels):
        h, w = int(pyr.heights[lev]), int(pyr.widths[lev])
        o = int(pyr.offsets[lev])
        mx = pyr.max_data[o : o + h * w].reshape(h, w)
        mean = pyr.data[o : o + h * w].reshape(h, w)
        s = 2**lev
        for r in range(h):
            for c in range(w):
                block = z0[r * s : (r + 1) * s, c * s : (c + 1) * s]
                assert mx[r, c] == block.max()  # exactly the highest sample it covers
        assert (mx >= mean).all()  # and so never below the mean level's cell


def test_a_skipped_stretch_keeps_the_profile_and_hides_only_heights_no_pixel_reads(
    monkeypatch,
):
    """The profiles themselves, with and without the skip: the running maximum the same
    to the bit at every sample, the heights the same wherever read; NaN exactly at the
    skipped samples, never at a pixel's crossing sample or the one before it."""
    import lunar_drake.render.heightfield_trace as ht

    captured = []
    kernel = ht._profiles

    def capture(*a):
        kernel(*a)
        AZ, kend, skipped = a[14], a[15], a[16]
        captured.append((AZ.copy(), kend.copy(), skipped.copy()))

    monkeypatch.setattr(ht, "_profiles", capture)
    hf = _ridged()
    pyr = DemPyramid.from_heightfield(hf)
    cam = _cam(w=320, h=240)
    z = float(pyr.height(-10.0, 0.5)[0])
    X = _pose([-10.0, 0.5, z + 0.6], yaw_deg=10.0, tilt_deg=8.0)
    fast = _trace(pyr, cam, X)
    full = _trace(pyr, cam, X, skip_hidden=False)
    (az_f, kend_f, sk_f), (az_0, kend_0, sk_0) = captured
    assert (kend_f == kend_0).all() and sk_0.sum() == 0 and sk_f.sum() == fast.skipped > 0
    K = az_0.shape[0]
    live = np.arange(K)[:, None] < kend_0[None, :]  # samples each bin really has
    np.testing.assert_array_equal(az_f[..., 0][live], az_0[..., 0][live])
    hidden = live & np.isnan(az_f[..., 1])
    assert hidden.sum() == fast.skipped
    np.testing.assert_array_equal(az_f[..., 1][live & ~hidden], az_0[..., 1][live & ~hidden])
    # a skipped sample never raises the running maximum, and the sample after a skipped
    # stretch is read: its height (what a pixel crossing right after uses) is there
    a0 = az_0[..., 0]
    assert (a0[1:][hidden[1:]] == a0[:-1][hidden[1:]]).all()
    after = np.zeros_like(hidden)
    after[1:] = hidden[:-1] & ~hidden[1:] & live[1:]
    assert after.any() and not np.isnan(az_f[..., 1][after]).any()
    np.testing.assert_array_equal(fast.t, full.t)


@pytest.mark.parametrize(
    ("p", "yaw", "tilt", "roll", "hidden"),
    [
        ([-10.0, 0.5, 0.6], 10.0, 8.0, 0.0, 0.3),  # low, the berm ahead hides the ground
        ([3.0, -4.0, 1.5], 200.0, -5.0, 12.0, 0.1),  # rolled, looking up over the berm
        ([-14.0, 9.0, 6.0], -40.0, 25.0, -8.0, 0.0),  # high: it sees nearly everything
        ([-25.0, 0.0, 2.0], 0.0, 10.0, 0.0, 0.0),  # outside the DEM: the general march
    ],
)
def test_hidden_profile_stretches_are_skipped_without_changing_a_hit(p, yaw, tilt, roll, hidden):
    hf = _ridged()
    pyr = DemPyramid.from_heightfield(hf)
    cam = _cam(w=320, h=240)
    z = float(pyr.height(p[0], p[1])[0]) if abs(p[0]) < 15 else 0.0
    X = _pose([p[0], p[1], z + p[2]], yaw_deg=yaw, tilt_deg=tilt, roll_deg=roll)
    fast = _trace(pyr, cam, X)
    full = _trace(pyr, cam, X, skip_hidden=False)
    assert full.skipped == 0 and fast.samples == full.samples
    np.testing.assert_array_equal(fast.t, full.t)  # to the bit
    np.testing.assert_array_equal(fast.level, full.level)
    # the refined crossings (regula falsi on the pixel's own ray) too
    refined = _trace(pyr, cam, X, iters=2)
    np.testing.assert_array_equal(refined.t, _trace(pyr, cam, X, iters=2, skip_hidden=False).t)
    assert np.isfinite(fast.t).mean() > 0.3
    assert fast.skipped >= hidden * fast.samples  # stretches behind the berm: skipped
    # a pyramid without the max levels reads every sample, the same hits
    plain = _trace(dc.replace(pyr, max_data=None), cam, X)
    assert plain.skipped == 0
    np.testing.assert_array_equal(plain.t, full.t)
    # a max pyramid of another layout is refused, not read out of bounds
    with pytest.raises(ConfigError, match="max_data is float32"):
        _trace(dc.replace(pyr, max_data=pyr.max_data[:-5]), cam, X)


def test_camera_below_the_surface_and_bad_options_raise():
    hf = _bumpy(64)
    pyr = DemPyramid.from_heightfield(hf)
    z0 = float(pyr.height(0.0, 0.0)[0])
    with pytest.raises(OutOfRangeError, match="inside the terrain"):
        _trace(pyr, _cam(), _pose([0.0, 0.0, z0 - 0.01]))
    with pytest.raises(OutOfRangeError, match="bin_factor"):
        _trace(pyr, _cam(), _pose([0.0, 0.0, z0 + 1.0]), bin_factor=0.0)


def _highlands_reflectance():
    """The exact blended Hapke/Lunar-Lambert reflectance the tables are built from."""
    return functools.partial(
        hapke_mod.blended_reflectance,
        params=hapke_mod.HIGHLANDS_643NM,
        start_deg=84.0,
        end_deg=89.0,
        dtype=np.float64,
    )


def test_reflectance_table_matches_the_exact_hapke_function():
    f = _highlands_reflectance()
    lut = ReflectanceLUT.build(f, n_i=65, n_e=65, n_g=65)
    p99, _ = lut.max_relative_error(f, samples=4000, min_cos=0.1)
    assert p99 < 0.01
    fine = ReflectanceLUT.build(f)
    p99_fine, mx = fine.max_relative_error(f, samples=4000, min_cos=0.1)
    assert p99_fine < 0.5 * p99 and mx < 0.05  # converges with the grid
    # grid nodes are exact; the opposition surge survives tabulation
    i = 10
    ci = 1.0 - (i / 128.0) ** 2
    assert float(fine(ci, ci, 0.0)) == pytest.approx(float(f(ci, ci, 0.0)), rel=1e-6)
    assert float(fine(0.8, 0.8, 0.0)) > 1.2 * float(fine(0.8, 0.8, math.radians(20.0)))
    assert float(fine(0.0, 0.5, 0.3)) == 0.0


def test_float32_table_reads_match_the_float64_ones():
    """The shading kernel's float32 lookups agree with the float64 lookups; cos_i <= 0
    reads the zero row exactly (the kernel relies on it instead of a branch)."""
    import numba

    f = _highlands_reflectance()
    lut = ReflectanceLUT.build(f, n_i=33, n_e=33, n_g=33)

    @numba.njit
    def both(table, ci, ce, cg, out64, out32):
        m = table.shape[0] - 1
        for k in range(ci.size):
            x, y = lut_axis(ci[k], m), lut_axis(ce[k], m)
            out64[k] = lut_reflectance_at(table, x, y, cg[k])
            x32 = lut_axis_f32(np.float32(ci[k]), np.float32(m))
            y32 = np.float32(y)
            out32[k] = lut_reflectance_at_f32(table, x32, y32, np.float32(cg[k]))

    rng = np.random.default_rng(3)
    n = 20000
    ci = rng.uniform(-0.3, 1.0, n)
    ce = rng.uniform(0.05, 1.0, n)
    cg = rng.uniform(-1.0, 1.0, n)
    o64, o32 = np.empty(n), np.empty(n, np.float32)
    both(lut.table, ci, ce, cg, o64, o32)
    lit = ci > 0.05
    rel = np.abs(o32[lit] - o64[lit]) / np.maximum(o64[lit], 1e-12)
    assert np.quantile(rel, 0.99) < 1e-5 and rel.max() < 1e-3
    assert (o32[ci <= 0.0] == 0.0).all() and (o64[ci <= 0.0] == 0.0).all()


def _box(c, half):
    v, f = box_mesh(*(2.0 * np.asarray(half, float)))
    return DynamicMesh(v + np.asarray(c, float), f, albedo=0.4)


def test_rover_pixel_mask_covers_every_mesh_hit_even_across_the_near_plane():
    cam = _cam(80, 60)
    X = _pose([0.0, 0.0, 1.0], tilt_deg=20.0)
    boxes = [_box([1.5, 0.2, 0.6], [0.3, 0.3, 0.3]), _box([0.0, 0.0, 0.6], [0.4, 0.4, 0.2])]
    rc = TerrainRaycaster()
    rc.set_dynamic_meshes(boxes, [np.eye(4)] * 2)
    rays, _ = cam.world_rays(X)
    hit = np.isfinite(rc.cast_rays(rays).t_hit).reshape(cam.height, cam.width)
    mask = rover_pixel_mask(boxes, [np.eye(4)] * 2, cam, X)
    assert hit.any() and not (hit & ~mask).any()
    assert mask.mean() < 0.8  # and it is not just the whole image
    mask_boxes = mask
    # a box straddling the camera plane (the camera sits inside its bounding sphere)
    wide = [_box([0.0, 0.0, 0.8], [2.0, 2.0, 0.05])]
    rc.set_dynamic_meshes(wide, [np.eye(4)])
    hit = np.isfinite(rc.cast_rays(rays).t_hit).reshape(cam.height, cam.width)
    mask = rover_pixel_mask(wide, [np.eye(4)], cam, X)
    assert hit.any() and not (hit & ~mask).any()
    # the first list of meshes again (the stacked meshes are remembered by identity)
    assert np.array_equal(rover_pixel_mask(boxes, [np.eye(4)] * 2, cam, X), mask_boxes)
    assert not rover_pixel_mask([], [], cam, X).any()
    with pytest.raises(ConfigError, match="1 poses for 2 meshes"):
        rover_pixel_mask(boxes, [np.eye(4)], cam, X)


def _renderers(hf, meshes, w=128, h=96):
    albedo = 0.12 + 0.06 * np.sin(np.arange(hf.shape[0] * hf.shape[1]) / 97.0)
    albedo = albedo.reshape(hf.shape).astype(np.float32)
    out = {}
    for eng in ("heightfield", "raycast"):
        model = CameraConfig(width=w, height=h, fov_y_deg=50.0, engine=eng, near_radius_m=40.0)
        out[eng] = TerrainCameraRenderer(
            heightfield=hf, albedo=albedo, model=model, dynamic_meshes=meshes
        )
    return out


def _box_scene():
    """The bumpy site, a rover-sized box on it (its pose X_box) and a camera X looking at
    it from 3.5 m."""
    hf = _bumpy()
    box = _box([0.0, 0.0, 0.0], [0.5, 0.4, 0.3])
    z = float(hf.height(np.array([-2.0]), np.array([0.0]))[0])
    X_box = np.eye(4)
    X_box[:3, 3] = [-2.0, 0.0, z + 0.45]
    X = _pose([-5.5, 0.8, z + 1.6], tilt_deg=18.0, yaw_deg=-8.0)
    return hf, box, X_box, X


def test_engines_agree_on_a_bumpy_site_with_a_rover_and_its_shadow():
    hf, box, X_box, X = _box_scene()
    rs = _renderers(hf, [box])
    lm = RasterSampler.on_heightfield(
        np.linspace(0.6, 1.0, hf.shape[1], dtype=np.float32)[None, :].repeat(hf.shape[0], 0),
        hf,
        outside=1.0,
    )
    imgs = {}
    for eng, r in rs.items():
        il, up = r.illumination(
            sun_dir_W=(-0.6, 0.75, 0.28), earth_dir_W=(0.2, -0.3, 0.93), earth_phase=0.6
        )
        assert up
        imgs[eng] = r.shade(X_WC=X, illumination=il, dynamic_poses=[X_box], lightmap=lm)
    a, b = imgs["heightfield"], imgs["raycast"]
    assert (a.label == 2).sum() > 200  # the rover box is in view
    assert (a.label == b.label).mean() > 0.99
    t = (a.label == 1) & (b.label == 1)
    rel = np.abs(a.radiance[t] - b.radiance[t]) / np.maximum(b.radiance[t], 1e-4)
    assert np.median(rel) < 0.01 and np.quantile(rel, 0.9) < 0.05
    rv = (a.label == 2) & (b.label == 2)
    np.testing.assert_allclose(a.radiance[rv].mean(), b.radiance[rv].mean(), rtol=0.02)
    drel = np.abs(a.depth[t] - b.depth[t]) / b.depth[t]
    assert np.quantile(drel, 0.99) < 0.02  # all but silhouette pixels
    # the box casts a shadow on the terrain in both: compare with a render without it
    r0 = _renderers(hf, [])["heightfield"]
    il, _ = r0.illumination(
        sun_dir_W=(-0.6, 0.75, 0.28), earth_dir_W=(0.2, -0.3, 0.93), earth_phase=0.6
    )
    c = r0.shade(X_WC=X, illumination=il, lightmap=lm)
    darker = (a.label == 1) & (a.radiance < 0.5 * c.radiance)
    assert darker.sum() > 50
    ref_darker = (b.label == 1) & (b.radiance < 0.5 * c.radiance)
    assert (darker == ref_darker).mean() > 0.99
    # bit-identical on a second render
    r = rs["heightfield"]
    il, _ = r.illumination(
        sun_dir_W=(-0.6, 0.75, 0.28), earth_dir_W=(0.2, -0.3, 0.93), earth_phase=0.6
    )
    again = r.shade(X_WC=X, illumination=il, dynamic_poses=[X_box], lightmap=lm)
    assert again.radiance.tobytes() == a.radiance.tobytes()


def test_earthshine_fainter_than_the_threshold_is_left_out():
    """Earthshine is 0.3 (R_E / d)^2 x phase of sunlight (a Lambert sphere): below
    ``earthshine_min_fraction`` (1e-5) no Earth light is passed to the shading; at or
    above it, that irradiance; with the threshold 0 even the faint one; an Earth below
    the horizon never."""
    import dataclasses as dc

    hf = _bumpy(n=64)
    r = _renderers(hf, [])["heightfield"]
    r0 = TerrainCameraRenderer(
        heightfield=hf, model=dc.replace(r.model, earthshine_min_fraction=0.0)
    )
    sun, earth, d_km = (-0.6, 0.75, 0.28), (0.2, -0.3, 0.93), 384_400.0

    def earth_light(renderer, phase, direction=earth):
        il, _ = renderer.illumination(sun_dir_W=sun, earth_dir_W=direction,
                                      earth_distance_km=d_km, earth_phase=phase)  # fmt: skip
        return il.earth_direction_W, il.earth_irradiance

    fraction = 0.3 * (6371.0 / d_km) ** 2  # of sunlight at full phase: 8.2e-5
    faint, bright = 0.5e-5 / fraction, 2e-5 / fraction  # phases 0.06 and 0.24
    assert earth_light(r, faint) == (None, 0.0)
    direction, e = earth_light(r, bright)
    assert np.allclose(direction, np.array(earth) / np.linalg.norm(earth))
    assert e == pytest.approx(2e-5, rel=1e-9)
    assert earth_light(r0, faint)[1] == pytest.approx(0.5e-5, rel=1e-9)
    assert earth_light(r0, 1.0, direction=(0.2, -0.3, -0.93)) == (None, 0.0)


def test_frames_are_bit_identical_whatever_the_thread_count():
    # rows and profile groups go to the threads through a shared queue (row_queue): which
    # thread renders a row must not change a byte, rover shadow candidates included
    import numba

    hf, box, X_box, X = _box_scene()
    r = _renderers(hf, [box], w=160, h=120)["heightfield"]
    lm = RasterSampler.on_heightfield(
        np.linspace(0.6, 1.0, hf.shape[1], dtype=np.float32)[None, :].repeat(hf.shape[0], 0),
        hf,
        outside=1.0,
    )
    il, _ = r.illumination(
        sun_dir_W=(-0.6, 0.75, 0.28), earth_dir_W=(0.2, -0.3, 0.93), earth_phase=0.6
    )
    threads = numba.get_num_threads()
    out = []
    try:
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            sh = r.shade(X_WC=X, illumination=il, dynamic_poses=[X_box], lightmap=lm)
            raw = r.expose(sh, exposure_s=r.model.exposure_s, gain=1.0, key=7, frame_index=3)
            out.append((sh, raw))
    finally:
        numba.set_num_threads(threads)
    (a, ra), (b, rb) = out[0], out[-1]
    assert (a.label == 2).sum() > 200 and (a.label == 1).sum() > 5000
    assert a.radiance.tobytes() == b.radiance.tobytes()
    assert a.depth.tobytes() == b.depth.tobytes()
    assert a.label.tobytes() == b.label.tobytes()
    assert ra.tobytes() == rb.tobytes()


def test_engines_agree_under_spotlights_and_wheel_tracks():
    from lunar_drake.render.shading import SpotLight

    hf = _bumpy(128)
    z = float(hf.height(np.array([-3.0]), np.array([0.0]))[0])
    X = _pose([-3.0, 0.0, z + 1.5], tilt_deg=25.0)
    spot = SpotLight(position_W=(-2.6, 0.0, z + 0.8), direction_W=(1.0, 0.0, -0.5), intensity=0.4)
    depth = np.zeros(hf.shape, np.float32)
    depth[:, 40:44] = 0.02  # a groove across the view
    tracks = RasterSampler.on_heightfield(depth, hf, outside=0.0)
    imgs = {}
    for eng, r in _renderers(hf, []).items():
        il, up = r.illumination(sun_dir_W=(0.3, 0.2, -0.2), spotlights=(spot,))
        assert not up  # night: fill from the horizon, the spotlight does the rest
        imgs[eng] = r.shade(X_WC=X, illumination=il, track_depth=tracks)
    a, b = imgs["heightfield"], imgs["raycast"]
    t = (a.label == 1) & (b.label == 1)
    assert a.radiance[t].max() > 10 * np.median(a.radiance[t])  # the beam stands out
    rel = np.abs(a.radiance[t] - b.radiance[t]) / np.maximum(b.radiance[t], 1e-5)
    assert np.median(rel) < 0.02


def test_track_gradients_are_read_only_where_the_raster_reaches():
    """A track raster over part of the view: the shader reads its gradients only at
    pixels the raster reaches (0 elsewhere). With two rings of zeros at its edge, the
    same raster clamped at its edge (``outside=None``: every pixel reads it) gives the
    same bits."""
    hf = _bumpy(128)
    z = float(hf.height(np.array([-3.0]), np.array([0.0]))[0])
    X = _pose([-3.0, 0.0, z + 1.5], tilt_deg=25.0)
    depth = np.zeros((60, 40), np.float32)  # 3 m x 2 m at 5 cm, ahead and to one side
    depth[10:50, 8:14] = 0.02  # a groove
    depth[10:50, 20:23] = 0.01
    bounds = (-1.0, -1.5, 1.0, 1.5)
    r = _renderers(hf, [])["heightfield"]
    il, _ = r.illumination(sun_dir_W=(0.5, 0.3, 0.3))
    imgs = {}
    for outside in (0.0, None):
        tracks = RasterSampler(depth, bounds=bounds, outside=outside)
        imgs[outside] = r.shade(X_WC=X, illumination=il, track_depth=tracks)
    flat = r.shade(X_WC=X, illumination=il)
    a, b = imgs[0.0], imgs[None]
    assert a.radiance.tobytes() == b.radiance.tobytes()
    assert (a.radiance != flat.radiance).sum() > 200  # the grooves show


def test_float32_ray_directions_are_the_float64_ones_to_a_few_ulps():
    # the trace's ray slopes and bins and the shading kernel's directions and camera-z
    # depth use direction_f32; the reference is pixel_direction (float64), and the
    # camera-z component 1 / |(xc, yc, 1)| is computed here on its own
    X = _pose([1.0, -2.0, 3.0], yaw_deg=37.0, tilt_deg=21.0, roll_deg=-9.0)
    R = np.ascontiguousarray(X[:3, :3])
    fx, fy, cx, cy = 700.0, 690.0, 639.5, 479.5
    R32, ifx, cx32 = R.astype(np.float32), np.float32(1.0 / fx), np.float32(cx)
    worst = 0.0
    for r in (0, 1, 333, 959):
        yc = np.float32((r - cy) / fy)
        for c in (0, 1, 640, 1279):
            d64 = np.array(pixel_direction(R, fx, fy, cx, cy, r, c))
            *d32, zc = direction_f32.py_func(R32, ifx, cx32, yc, c)
            assert all(isinstance(v, np.float32) for v in (*d32, zc))
            worst = max(worst, float(np.abs(np.array(d32, np.float64) - d64).max()))
            zc64 = 1.0 / math.sqrt(((c - cx) / fx) ** 2 + ((r - cy) / fy) ** 2 + 1.0)
            assert abs(float(zc) - zc64) <= 4 * np.finfo(np.float32).eps
    assert 0.0 < worst <= 8 * np.finfo(np.float32).eps  # float32, and only float32 rounding


def test_a_terrain_pixel_does_not_depend_on_the_rest_of_its_row():
    # the kernel shades a row's terrain pixels as one run of columns when they are
    # contiguous and compacts them otherwise: rows that the rover splits take the second
    # path; their terrain pixels must come out as in the same frame without the rover
    hf, box, X_box, X = _box_scene()
    sun = (-0.9, 0.1, 0.4)  # the box's shadow falls behind it, out of view
    lm = RasterSampler.on_heightfield(np.full(hf.shape, 0.9, np.float32), hf, outside=1.0)
    out = []
    for meshes, poses in (([box], [X_box]), ([], [])):
        r = _renderers(hf, meshes)["heightfield"]
        il, _ = r.illumination(sun_dir_W=sun, earth_dir_W=(0.2, -0.3, 0.93), earth_phase=0.6)
        out.append(r.shade(X_WC=X, illumination=il, dynamic_poses=poses, lightmap=lm))
    a, b = out
    split = [
        i for i, row in enumerate(a.label)
        if (row == 2).any() and (row[: np.argmax(row == 2)] == 1).any() and (row[-1] == 1)
    ]  # fmt: skip
    assert len(split) > 10  # rows with terrain on both sides of the rover
    t = a.label == 1
    assert (b.label[t] == 1).all()
    assert a.depth[t].tobytes() == b.depth[t].tobytes()
    assert a.radiance[t].tobytes() == b.radiance[t].tobytes()
