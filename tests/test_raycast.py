"""Tests for render/terrain_lod.py, render/raycast.py and render/shading.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import shading as sh
from lunar_drake.render.raycast import (
    INVALID_ID,
    LABEL_ROVER,
    LABEL_SKY,
    LABEL_TERRAIN,
    DynamicMesh,
    PinholeCamera,
    TerrainRaycaster,
    pinhole_rays,
)
from lunar_drake.render.terrain_lod import TerrainLOD, TileCache, select_tile_levels
from lunar_drake.rng import hash_normal, stream_key
from lunar_drake.terrain.heightfield import Heightfield

DOWN = np.array([0.0, 0.0, -1.0])


def _look(p, forward, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """X_WC for a Drake camera at p looking along forward (+x right, +y down)."""
    z = np.asarray(forward, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    X = np.eye(4)
    X[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    X[:3, 3] = p
    return X


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Closed axis-aligned box mesh (12 triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], float)
    f = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x0, x1
            [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y0, y1
            [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # z0, z1
        ]
    )  # fmt: skip
    return v, f


def _flat(z0=0.0, n=128, res=0.1) -> Heightfield:
    return Heightfield.from_array(np.full((n, n), z0, np.float32), resolution_m=res)


def _raycaster(hf, **kw) -> tuple[TerrainRaycaster, TerrainLOD]:
    lod = TerrainLOD.build(hf, cache=TileCache(), **kw)
    rc = TerrainRaycaster()
    rc.set_terrain(lod)
    return rc, lod


def _rough(shape=(200, 300), res=0.1) -> Heightfield:
    """Rough terrain: long waves plus +-5 cm hash noise (non-tile-aligned shape)."""
    r, c = np.mgrid[0 : shape[0], 0 : shape[1]]
    z = 1.5 * np.sin(c * res / 3.0) * np.cos(r * res / 2.0) + 0.05 * hash_normal(
        stream_key(1, "test"), r, c, dtype=np.float64
    )
    return Heightfield.from_array(z.astype(np.float32), resolution_m=res)


# ----------------------------------------------------------------------------------------
# Ray casting geometry
# ----------------------------------------------------------------------------------------
def test_flat_plane_hit_at_analytic_distance():
    hf = _flat(2.0, n=64, res=0.5)
    rc, lod = _raycaster(hf, tile_px=16, near_radius_m=3.0)
    assert len(lod.stats.tiles_per_level) > 1  # several levels, still an exact plane
    rng = np.random.default_rng(0)
    o = np.column_stack([rng.uniform(-10, 10, 200), rng.uniform(-10, 10, 200), np.full(200, 7.0)])
    d = np.column_stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.5, 0.5, 200), -np.ones(200)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    h = rc.cast(o, d)
    assert h.hit.all() and not h.is_dynamic.any()
    np.testing.assert_allclose(h.t_hit, 5.0 / -d[:, 2], rtol=1e-5)
    np.testing.assert_allclose(np.abs(h.normals[:, 2]), 1.0, atol=1e-6)
    assert (rc.labels(h) == LABEL_TERRAIN).all()
    up = rc.cast(o, -d)
    assert not up.hit.any() and (up.geometry_id == INVALID_ID).all()
    assert np.isinf(up.t_hit).all() and (rc.labels(up) == LABEL_SKY).all()


def test_sloped_plane_exact_at_every_level():
    n, res = 96, 0.25
    r, c = np.mgrid[0:n, 0:n]
    hf = Heightfield.from_array((0.1 * c - 0.05 * r + 3.0).astype(np.float32), resolution_m=res)
    rc, lod = _raycaster(hf, tile_px=16, near_radius_m=2.0)
    assert set(lod.stats.tiles_per_level) == {0, 1, 2}
    # interior, away from the edge band where the tent filter clamps
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-9, 9, 500), rng.uniform(-9, 9, 500)
    h = rc.cast(np.column_stack([x, y, np.full(500, 50.0)]), np.tile(DOWN, (500, 1)))
    np.testing.assert_allclose(50.0 - h.t_hit, hf.height(x, y), atol=2e-4)


def test_pinhole_directions_match_intrinsics():
    cam = PinholeCamera(width=9, height=7, fx=10.0, fy=12.0, cx=4.0, cy=3.0)
    X = _look((1.0, 2.0, 3.0), (1.0, 1.0, -0.5))
    o, d = cam.rays(X)
    assert o.shape == d.shape == (63, 3)
    np.testing.assert_allclose(o, np.broadcast_to(X[:3, 3], o.shape))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # principal point (u=4, v=3) -> optical axis (C's +z)
    np.testing.assert_allclose(d[3 * 9 + 4], X[:3, 2], atol=1e-12)
    # back-project every ray into C: u = fx x/z + cx, v = fy y/z + cy
    dc = d @ X[:3, :3]
    u, v = np.meshgrid(np.arange(9), np.arange(7))
    np.testing.assert_allclose(10.0 * dc[:, 0] / dc[:, 2] + 4.0, u.ravel(), atol=1e-9)
    np.testing.assert_allclose(12.0 * dc[:, 1] / dc[:, 2] + 3.0, v.ravel(), atol=1e-9)
    # +x right and +y down: pixel to the right of centre tilts toward C's +x
    assert dc[3 * 9 + 5, 0] > 0 and dc[4 * 9 + 4, 1] > 0
    # the float32 fast path agrees; Drake's centred principal point
    np.testing.assert_allclose(cam.open3d_rays(X)[:, 3:], d, atol=1e-6)
    drake = PinholeCamera.from_fov(width=640, height=480, fov_y_rad=1.0)
    assert (drake.cx, drake.cy) == (319.5, 239.5)
    _, d2 = pinhole_rays(width=9, height=7, fx=10.0, fy=12.0, cx=4.0, cy=3.0, X_WC=X)
    np.testing.assert_array_equal(d2, d)
    with pytest.raises(OutOfRangeError):
        PinholeCamera(width=0, height=7, fx=10.0, fy=12.0, cx=4.0, cy=3.0)
    with pytest.raises(ConfigError):
        pinhole_rays(width=9, height=7, fx=10.0, fy=12.0, cx=4.0, cy=3.0, X_WC=np.eye(3))


def test_depth_is_along_optical_axis():
    hf = _flat(0.0, n=64, res=0.5)
    rc, _ = _raycaster(hf, tile_px=16)
    cam = PinholeCamera.from_fov(width=32, height=24, fov_y_rad=1.2)
    g = sh.trace(rc, cam, _look((0.5, -0.3, 4.0), DOWN, up=(0.0, 1.0, 0.0)))
    assert (g.label == LABEL_TERRAIN).all()
    np.testing.assert_allclose(g.depth, 4.0, rtol=1e-5)  # image plane parallel to ground
    g2 = sh.trace(rc, cam, _look((0.0, 0.0, 1.0), (1.0, 0.0, 0.3)))
    assert (g2.label[0] == LABEL_SKY).all() and np.isinf(g2.depth[0]).all()


# ----------------------------------------------------------------------------------------
# LOD
# ----------------------------------------------------------------------------------------
def test_lod_levels_counts_and_cache():
    hf = _rough()
    cache = TileCache()
    lod = TerrainLOD.build(hf, center_xy=(-10.0, 5.0), tile_px=32, near_radius_m=2.0, cache=cache)
    lv = lod.level_grid()
    assert lv.shape == (7, 10)  # ceil(199 / 32), ceil(299 / 32)
    assert lv.min() == 0 and lv.max() == 3  # levels default: log2(32) - 1 = 4 -> 0..3
    expect = select_tile_levels(
        hf.shape, 0.1, center_xy=(-10.0, 5.0), tile_px=32, levels=4, near_radius_m=2.0
    )
    np.testing.assert_array_equal(lv, expect)
    # the tile holding the centre is full resolution, the far corner the coarsest
    col, row = int((-10.0 + 15.0) / 0.1) // 32, int((10.0 - 5.0) / 0.1) // 32
    assert lv[row, col] == 0 and lv[-1, -1] == 3
    s = lod.stats
    assert s.triangles == sum(t.triangle_count for t in lod.tiles) == lod.triangle_count
    assert s.surface_triangles < 2 * 199 * 299  # decimated
    assert s.cache_misses == len(lod.tiles) and s.cache_hits == 0
    for t in lod.tiles:
        assert t.vertices.dtype == np.float32 and t.faces.dtype == np.int32
    # same centre: all from cache; a small move: most from cache
    assert TerrainLOD.build(
        hf, center_xy=(-10.0, 5.0), tile_px=32, near_radius_m=2.0, cache=cache
    ).stats.cache_hits == len(lod.tiles)
    assert not lod.changes_at((-10.01, 5.0)) and lod.changes_at((-7.0, 5.0))
    moved = lod.recenter((-7.0, 5.0))
    assert 0 < moved.stats.cache_misses < len(lod.tiles) // 2
    assert moved.stats.cache_hits + moved.stats.cache_misses == len(lod.tiles)
    with pytest.raises(OutOfRangeError):
        TerrainLOD.build(hf, tile_px=48)
    with pytest.raises(OutOfRangeError):
        TerrainLOD.build(hf, tile_px=32, levels=7)


def test_lod_heights_within_decimation_error_and_covering_whole_extent():
    hf = _rough()
    z = hf.read_window(0, 0, *hf.shape).astype(np.float64)
    rc, lod = _raycaster(hf, center_xy=(-10.0, 5.0), tile_px=32, near_radius_m=2.0)
    lv = lod.level_grid()
    # straight-down rays on a grid 4x denser than the pixels over the whole extent,
    # including the outermost half-pixel band and every tile boundary
    b = hf.bounds
    eps = 1e-4
    xs = np.linspace(b.left + eps, b.right - eps, 4 * hf.shape[1])
    ys = np.linspace(b.bottom + eps, b.top - eps, 4 * hf.shape[0])
    X, Y = np.meshgrid(xs, ys)
    o = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, 20.0)])
    h = rc.cast(o, np.tile(DOWN, (X.size, 1)))
    assert h.hit.all()
    # heights at pixel centres vs. the local relief within 2 s pixels (tent filter bound)
    r, c = np.mgrid[0 : hf.shape[0], 0 : hf.shape[1]]
    xc, yc = hf.grid.pixel_centers(0, 0, *hf.shape)
    o = np.column_stack(
        [np.broadcast_to(xc, r.shape).ravel(), np.repeat(yc, r.shape[1]), np.full(r.size, 20.0)]
    )
    zm = 20.0 - rc.cast(o, np.tile(DOWN, (r.size, 1))).t_hit.astype(np.float64)
    err = np.abs(zm - z.ravel())
    level = lv[np.minimum(r // 32, lv.shape[0] - 1), np.minimum(c // 32, lv.shape[1] - 1)].ravel()
    on_edge = ((r % 32 == 0) | (c % 32 == 0)).ravel()  # shared with a neighbour tile
    for L in range(4):
        k = 4 * (1 << L) + 1
        relief = (ndimage.maximum_filter(z, size=k) - ndimage.minimum_filter(z, size=k)).ravel()
        m = level == L
        assert m.any()
        assert (err[m] <= relief[m] + 1e-4).all()
        if L == 0:
            assert err[m & ~on_edge].max() < 1e-5  # exact DEM postings
        else:
            assert err[m].max() > 1e-3  # really decimated


def test_lod_skirts_close_cracks_between_levels():
    """Horizontal rays aimed into the vertical gap between two tiles' edges must hit at
    the edge (a skirt); without skirts they pass under the surface."""
    hf = _rough()
    lod_kw = dict(center_xy=(-10.0, 5.0), tile_px=32, near_radius_m=2.0)
    rc, lod = _raycaster(hf, **lod_kw)
    rc0, _ = _raycaster(hf, skirts=False, **lod_kw)
    lv = lod.level_grid()
    res = hf.resolution_m
    origins, dirs, dist = [], [], []
    for tr in range(lv.shape[0]):
        for tc in range(lv.shape[1] - 1):
            if lv[tr, tc] == lv[tr, tc + 1]:
                continue
            xe = ((tc + 1) * 32 + 0.5 - 0.5 * hf.shape[1]) * res  # shared edge x
            ys = (0.5 * hf.shape[0] - 0.5 - (tr * 32 + np.arange(1, 32, 0.37))) * res
            down = np.tile(DOWN, (ys.size, 1))
            zl = (
                50.0
                - rc0.cast(
                    np.column_stack([np.full_like(ys, xe - 1e-4), ys, 50 + 0 * ys]), down
                ).t_hit
            )
            zr = (
                50.0
                - rc0.cast(
                    np.column_stack([np.full_like(ys, xe + 1e-4), ys, 50 + 0 * ys]), down
                ).t_hit
            )
            gap = np.abs(zl - zr) > 0.01
            zmid = 0.5 * (zl + zr)
            # start 1 mm before the edge on the lower side, aim across it
            side = np.where(zl < zr, -1.0, 1.0)
            for y, zz, sd in zip(ys[gap], zmid[gap], side[gap], strict=True):
                origins.append((xe + sd * 1e-3, y, zz))
                dirs.append((-sd, 0.0, 0.0))
                dist.append(1e-3)
    assert len(origins) > 20
    o, d = np.array(origins), np.array(dirs)
    h = rc.cast(o, d)
    assert h.hit.all()
    np.testing.assert_allclose(h.t_hit, dist, atol=2e-4)
    assert rc.skirt_mask(h).mean() > 0.9
    h0 = rc0.cast(o, d)
    assert (np.abs(h0.t_hit - np.array(dist)) > 1e-2).mean() > 0.9  # the gaps are real


# ----------------------------------------------------------------------------------------
# Dynamic geometry and shadows
# ----------------------------------------------------------------------------------------
def _box_scene():
    hf = _flat(0.0, n=128, res=0.1)
    rc, _ = _raycaster(hf, tile_px=32)
    v, f = _box((-0.5, -0.5, 0.5), (0.5, 0.5, 1.0))
    rc.set_dynamic_meshes([DynamicMesh(v, f)])
    return rc


def test_dynamic_box_occludes_terrain_and_moves():
    rc = _box_scene()
    o = np.array([[-4.0, 0.0, 1.5], [-4.0, 3.0, 1.5]])
    aim = np.array([[6.0, 0.0, -1.5], [6.0, 0.0, -1.5]])  # toward (2, y, 0) on the ground
    d = aim / np.linalg.norm(aim, axis=1, keepdims=True)
    h = rc.cast(o, d)
    assert h.is_dynamic.tolist() == [True, False]
    assert rc.labels(h).tolist() == [LABEL_ROVER, LABEL_TERRAIN]
    t_ground = np.linalg.norm(aim[0])
    assert h.t_hit[0] < t_ground - 1.0  # the box is in front of the ground point
    np.testing.assert_allclose(h.t_hit[1], t_ground, rtol=1e-5)
    # the box's west face (x = -0.5) is hit at z = 0.625
    np.testing.assert_allclose(h.t_hit[0], 3.5 / 6.0 * t_ground, rtol=1e-5)
    # move the box 2 m north: the first ray now reaches the ground
    X = np.eye(4)
    X[1, 3] = 2.0
    rc.set_dynamic_poses([X])
    h2 = rc.cast(o, d)
    assert not h2.is_dynamic[0]
    np.testing.assert_allclose(h2.t_hit[0], t_ground, rtol=1e-5)
    # occlusion: up from under the box (and from 2 m north, now under the moved box)
    pts = np.array([[0.0, 0.0, 0.01], [0.0, 2.0, 0.01]])  # just above the ground
    up = np.tile([0.0, 0.0, 1.0], (2, 1))
    assert rc.occlusion(pts, up).tolist() == [False, True]
    assert rc.occlusion(pts, up, max_t=np.array([1.0, 0.4])).tolist() == [False, False]
    with pytest.raises(ConfigError):
        rc.set_dynamic_poses([])
    # the same pose again keeps the dynamic BVH; a changed one rebuilds it
    n = rc.dynamic_rebuilds
    rc.set_dynamic_poses([X.copy()])
    assert rc.occlusion(pts, up).tolist() == [False, True]
    assert rc.dynamic_rebuilds == n
    X3 = X.copy()
    X3[1, 3] = 0.0
    rc.set_dynamic_poses([X3])
    assert rc.occlusion(pts, up).tolist() == [True, False]
    assert rc.dynamic_rebuilds == n + 1


def test_rover_shadow_soft_with_sun_overhead():
    rc = _box_scene()
    pts = np.array([[0.0, 0.0, 0.0], [3.0, 3.0, 0.0], [0.5005, 0.0, 0.0], [0.4995, 0.0, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (4, 1))
    f = sh.rover_shadow_factor(rc, pts, nrm, (0.0, 0.0, 1.0), samples=16)
    assert f[0] == 0.0 and f[1] == 1.0
    # the penumbra at the edge is ~2 x 0.5 m x tan(0.27 deg) = 4.7 mm wide
    assert 0.0 < f[2] < 1.0 and 0.0 < f[3] < 1.0 and f[2] > f[3]
    hard = sh.rover_shadow_factor(rc, pts, nrm, (0.0, 0.0, 1.0), samples=1)
    assert hard.tolist() == [0.0, 1.0, 1.0, 0.0]
    # the soft shadow in an image: only the penumbra pixels get fractional values, and
    # the adaptive (hard pass + penumbra) path equals casting every sample everywhere
    cam = PinholeCamera.from_fov(width=160, height=120, fov_y_rad=0.25)
    sun = (0.3, 0.0, 1.0)  # the box's west top edge shadows x = -0.8 with a ~9 mm penumbra
    g = sh.trace(rc, cam, _look((-0.8, -1.5, 1.5), (0.0, 1.5, -1.5)))
    kw = dict(samples=8, bias_m=1e-3)
    brute = sh.rover_shadow_factor(rc, g.position, g.normal, sun, **kw)
    fast = sh.rover_shadow_factor(
        rc,
        g.position,
        g.normal,
        sun,
        image_shape=(g.height, g.width),
        pixel_index=g.index,
        pixel_footprint_m=g.hits.t_hit[g.index] * g.pixel_angle_rad,
        **kw,
    )
    partial = (brute > 0) & (brute < 1)
    assert partial.sum() > 50 and (brute == 0).sum() > 500 and (brute == 1).sum() > 500
    np.testing.assert_array_equal(fast, brute)


# ----------------------------------------------------------------------------------------
# Shading
# ----------------------------------------------------------------------------------------
def _top_view(rc, size=64, height=6.0, fov=1.2):
    cam = PinholeCamera.from_fov(width=size, height=size, fov_y_rad=fov)
    return sh.trace(rc, cam, _look((0.0, 0.0, height), DOWN, up=(0.0, 1.0, 0.0)))


def test_direct_sun_on_flat_ground_is_lommel_seeliger_i_over_f():
    rc, _ = _raycaster(_flat(0.0, n=128, res=0.1), tile_px=32)
    g = _top_view(rc)
    el = math.radians(30.0)
    il = sh.Illumination(sun_direction_W=(math.cos(el), 0.0, math.sin(el)), fill_fraction=0.0)
    img = sh.shade(g, rc, il)
    p = g.position
    v = g.view
    mu0, mu = math.sin(el), v[2]
    expect = math.pi * (2 * 0.15 / math.pi) / (mu0 + mu) * mu0
    np.testing.assert_allclose(img.radiance.ravel()[g.index], expect, rtol=1e-5)
    # the albedo map scales it: A / A_ref
    alb = sh.RasterSampler(np.array([[0.3, 0.3], [0.3, 0.3]]), bounds=(-10, -10, 10, 10))
    img2 = sh.shade(g, rc, il, albedo=alb)
    np.testing.assert_allclose(img2.radiance, 2.0 * img.radiance, rtol=1e-5)
    assert p.shape == (3, 64 * 64)


def test_indirect_fill_lights_lightmap_shadows():
    rc, _ = _raycaster(_flat(0.0, n=128, res=0.1), tile_px=32)
    g = _top_view(rc)
    el = math.radians(20.0)
    il = sh.Illumination(sun_direction_W=(0.0, math.cos(el), math.sin(el)))

    def lightmap(x, y):
        return (np.asarray(x) < 0).astype(np.float32)  # east half in terrain shadow

    img = sh.shade(g, rc, il, lightmap=lightmap).radiance.ravel()[g.index]
    shadow = g.position[0] > 0.05
    lit = g.position[0] < -0.05
    assert (img[shadow] > 0).all()
    # same cos_i for the Sun and the opposing fill on level ground, and Lommel-Seeliger
    # has no phase dependence: shadow = 3% of the direct level exactly
    direct = sh.shade(g, rc, sh.Illumination(sun_direction_W=il.sun_direction_W, fill_fraction=0))
    d = direct.radiance.ravel()[g.index]
    np.testing.assert_allclose(img[shadow], 0.03 * d[shadow], rtol=1e-5)
    np.testing.assert_allclose(img[lit], 1.03 * d[lit], rtol=1e-5)
    np.testing.assert_allclose(
        sh.fill_direction(il.sun_direction_W), (0.0, -math.cos(el), math.sin(el)), atol=1e-12
    )


def test_spotlight_cone_falloff_and_pattern():
    rc, _ = _raycaster(_flat(0.0, n=128, res=0.1), tile_px=32)
    g = _top_view(rc, size=96, height=6.0, fov=1.0)
    spot = sh.SpotLight(
        position_W=(0.0, 0.0, 2.0),
        direction_W=(0.0, 0.0, -1.0),
        intensity=4.0,
        outer_half_angle_rad=math.radians(30.0),
        inner_half_angle_rad=math.radians(20.0),
        up_W=(0.0, 1.0, 0.0),
    )
    il = sh.Illumination(sun_irradiance=0.0, spotlights=(spot,))
    img = sh.shade(g, rc, il).radiance.ravel()[g.index]
    x, y = g.position[0], g.position[1]
    r = np.hypot(x, y)
    ang = np.arctan2(r, 2.0)
    inside = ang < math.radians(19.0)
    outside = ang > math.radians(31.0)
    edge = (ang > math.radians(21.0)) & (ang < math.radians(29.0))
    assert inside.sum() > 100 and outside.sum() > 100 and edge.sum() > 100
    assert (img[outside] == 0).all()
    mu0 = np.cos(ang)
    mu = g.view[2]
    f = 2 * 0.15 / math.pi / (mu0 + mu)
    full = math.pi * 4.0 / (4.0 + r * r) * f * mu0
    np.testing.assert_allclose(img[inside], full[inside], rtol=1e-4)
    frac = img[edge] / full[edge]
    assert (frac > 0).all() and (frac < 1).all()
    # a narrow view, all inside the beam (the shader's full-array path), agrees
    gn = _top_view(rc, size=32, height=6.0, fov=0.1)
    rn = np.hypot(gn.position[0], gn.position[1])
    an = np.arctan2(rn, 2.0)
    assert (an < math.radians(19.0)).all()
    fn = 2 * 0.15 / math.pi / (np.cos(an) + gn.view[2])
    np.testing.assert_allclose(
        sh.shade(gn, rc, il).radiance.ravel()[gn.index],
        math.pi * 4.0 / (4.0 + rn * rn) * fn * np.cos(an),
        rtol=1e-4,
    )
    # a pattern dark in its right (east) half darkens the ground east of the light
    pattern = np.ones((8, 8))
    pattern[:, 4:] = 0.0
    sp2 = sh.SpotLight(**{**spot.__dict__, "pattern": pattern})
    img2 = sh.shade(g, rc, sh.Illumination(sun_irradiance=0.0, spotlights=(sp2,)))
    img2 = img2.radiance.ravel()[g.index]
    np.testing.assert_allclose(img2[inside & (x < -0.2)], full[inside & (x < -0.2)], rtol=1e-4)
    assert (img2[inside & (x > 0.2)] == 0).all()
    with pytest.raises(ConfigError):
        sh.Illumination(spotlights=(spot,) * 5)


def test_spotlight_shadow_and_rover_is_lambertian():
    rc = _box_scene()
    g = _top_view(rc, size=64, height=6.0, fov=1.0)
    spot = sh.SpotLight(
        position_W=(0.0, 0.0, 3.0),
        direction_W=(0.0, 0.0, -1.0),
        intensity=9.0,
        outer_half_angle_rad=math.radians(40.0),
        inner_half_angle_rad=math.radians(39.0),
        up_W=(0.0, 1.0, 0.0),
        cast_shadows=True,
    )
    il = sh.Illumination(sun_irradiance=0.0, spotlights=(spot,))
    img = sh.shade(g, rc, il)
    lab = img.label.ravel()[g.index]
    rad = img.radiance.ravel()[g.index]
    top = lab == LABEL_ROVER
    assert top.sum() > 50
    # the box top (z = 1, 2 m below the light, albedo 0.5): pi * I / d^2 * (0.5 / pi) * cos
    p = g.position[:, top]
    d2 = p[0] ** 2 + p[1] ** 2 + 4.0
    np.testing.assert_allclose(rad[top], 9.0 / d2 * 0.5 * (2.0 / np.sqrt(d2)), rtol=1e-4)
    # ground just outside the box footprint but inside its spot shadow is dark
    x, y = g.position[0], g.position[1]
    ground = lab == LABEL_TERRAIN
    cheb = np.maximum(np.abs(x), np.abs(y))
    in_shadow = ground & (cheb < 0.72)  # the shadow square reaches 0.75 m, the box 0.5 m
    assert in_shadow.sum() > 10 and (rad[in_shadow] == 0).all()
    assert (rad[ground & (cheb > 0.78) & (np.hypot(x, y) < 2.0)] > 0).all()


def test_track_bump_normals():
    rc, _ = _raycaster(_flat(0.0, n=128, res=0.1), tile_px=32)
    g = _top_view(rc)
    el = math.radians(20.0)
    il = sh.Illumination(sun_direction_W=(math.cos(el), 0.0, math.sin(el)), fill_fraction=0.0)
    k = 0.2  # groove deepening eastward: the surface tilts toward the Sun

    def depth(x, y):
        return k * np.asarray(x, np.float32)

    img = sh.shade(g, rc, il, track_depth=depth).radiance.ravel()[g.index]
    n = np.array([k, 0.0, 1.0]) / math.hypot(k, 1.0)
    mu0 = float(n @ il.sun_direction_W)
    mu = n @ g.view.astype(np.float64)
    expect = math.pi * (2 * 0.15 / math.pi) / (mu0 + mu) * mu0
    np.testing.assert_allclose(img, expect, rtol=1e-4)
    # the same from a raster: gradient of a ramp
    xs = np.linspace(-6.35, 6.35, 128)
    ramp = sh.RasterSampler(np.tile(k * xs, (128, 1)), bounds=(-6.4, -6.4, 6.4, 6.4))
    img_r = sh.shade(g, rc, il, track_depth=ramp).radiance.ravel()[g.index]
    np.testing.assert_allclose(img_r, expect, rtol=1e-3)
    flat = sh.shade(g, rc, il).radiance.ravel()[g.index]
    assert (img > flat).all()


def test_raster_sampler_and_brdf_helpers():
    vals = np.arange(12, dtype=np.float32).reshape(3, 4)  # 4 x 3 px over 4 x 3 m
    s = sh.RasterSampler(vals, bounds=(0.0, 0.0, 4.0, 3.0), outside=-1.0)
    # pixel centres and a midpoint
    np.testing.assert_allclose(
        s(np.array([0.5, 3.5, 1.0]), np.array([2.5, 0.5, 1.5])), [0, 11, 4.5]
    )
    np.testing.assert_allclose(s(np.array([5.0]), np.array([1.0])), [-1.0])
    gx, gy = s.gradient(np.array([2.0]), np.array([1.5]))
    np.testing.assert_allclose([gx[0], gy[0]], [1.0, -4.0])  # rows grow southwards
    clamp = sh.RasterSampler(vals, bounds=(0.0, 0.0, 4.0, 3.0))
    np.testing.assert_allclose(clamp(np.array([-3.0]), np.array([2.9])), [0.0])

    def r(ci, ce, g):
        return 0.1 * np.asarray(ci) * (1 + np.asarray(g))

    f = sh.brdf_from_reflectance(r)
    np.testing.assert_allclose(f(np.array([0.5]), np.array([0.7]), np.array([0.2])), [0.12])
    with pytest.raises(OutOfRangeError):
        sh.ShadingConfig(shadow_samples=0)
    with pytest.raises(OutOfRangeError):
        sh.SpotLight(position_W=(0, 0, 1), direction_W=(0, 0, -1), intensity=1.0,
                     inner_half_angle_rad=0.6, outer_half_angle_rad=0.5)  # fmt: skip


def test_render_is_bit_identical_across_runs():
    hf = _rough()

    def frame():
        rc, _ = _raycaster(hf, center_xy=(0.0, 0.0), tile_px=32, near_radius_m=3.0)
        v, f = _box((-0.4, -0.3, 0.0), (0.4, 0.3, 0.5))
        X = np.eye(4)
        X[:3, 3] = (2.0, 0.5, float(hf.height(2.0, 0.5)) + 0.2)
        rc.set_dynamic_meshes([DynamicMesh(v, f)], [X])
        cam = PinholeCamera.from_fov(width=120, height=90, fov_y_rad=1.0)
        el = math.radians(10.0)
        il = sh.Illumination(
            sun_direction_W=(-math.cos(el), 0.3, math.sin(el)),
            earth_direction_W=(0.0, 1.0, 0.2),
            earth_irradiance=0.01,
            spotlights=(
                sh.SpotLight(
                    position_W=(0.0, 0.0, 2.0), direction_W=(1.0, 0.0, -0.5), intensity=1.0
                ),
            ),
        )
        X_WC = _look((0.0, 0.0, float(hf.height(0.0, 0.0)) + 1.5), (1.0, 0.1, -0.3))
        return sh.render(rc, cam, X_WC, il, albedo="vertex")

    a, b = frame(), frame()
    assert (a.label == LABEL_ROVER).any() and (a.label == LABEL_TERRAIN).any()
    assert a.radiance.max() > 0
    for name in ("radiance", "depth", "label"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes()
