"""Tests for the rock library and stamping, the albedo map and DEM surface products."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lunar_drake import rng
from lunar_drake.errors import ConfigError, NoDataError, OutOfRangeError
from lunar_drake.terrain import albedo as al
from lunar_drake.terrain import rock_library as rl
from lunar_drake.terrain import surface as sf
from lunar_drake.terrain.grid import GridSpec

RES = 0.04


@pytest.fixture(scope="module")
def lib() -> rl.RockLibrary:
    return rl.make_rock_library(seed=0)


def _stamp_one(lib, *, d, h, k, x0=0.0, y0=0.0, n=64, base=0.0, ground=None, rid=0):
    grid = GridSpec(n, n, RES)
    x, y = grid.pixel_centers(0, 0, n, n)
    z = np.zeros((n, n), np.float32) if ground is None else ground.copy()
    mask = np.zeros((n, n), np.uint8)
    rl.stamp_rocks(
        z,
        mask,
        x=x,
        y=y,
        rocks_x=[x0],
        rocks_y=[y0],
        diameters=[d],
        heights=[h],
        shape_index=[k],
        base_z=[base],
        library=lib,
        resolution_m=RES,
        rock_ids=[rid],
    )
    return z, mask, x, y


# ----------------------------------------------------------------------------- library


def test_library_shapes_are_distinct_unit_blobs(lib):
    sh = lib.shapes
    n, s, s2 = sh.shape
    assert n >= 16 and s == s2 and sh.dtype == np.float32
    assert np.all(sh.max(axis=(1, 2)) == 1.0)
    assert sh.min() >= 0.0
    # Zero on the outer ring and outside the unit-diameter disc.
    c = (np.arange(s) + 0.5) / s - 0.5
    outside = np.hypot(c[:, None], c[None, :]) > 0.5
    assert not sh[:, outside].any()
    assert not (sh[:, 0].any() or sh[:, -1].any() or sh[:, :, 0].any() or sh[:, :, -1].any())
    # Footprints span the array: the farthest rock pixel is near the edge.
    assert np.all(lib.reach > 0.45)
    # Star-shaped about the centre: along the central row/column/diagonals the support
    # is one contiguous run containing the centre.
    m = s // 2
    for k in range(n):
        a = sh[k]
        for line in (a[m], a[:, m], np.diagonal(a), np.diagonal(a[:, ::-1])):
            nz = np.flatnonzero(line > 0)
            assert line[m] > 0 and nz.size == nz[-1] - nz[0] + 1
    # Pairwise different.
    for i in range(n):
        for j in range(i + 1, n):
            assert np.abs(sh[i] - sh[j]).max() > 0.05, (i, j)


def test_library_variety(lib):
    assert set(lib.kinds) == {"dome", "flat", "pointy", "angular"}
    top_frac, aspect = [], []
    for a in lib.shapes:
        fp = a > 0
        top_frac.append((a > 0.95).sum() / fp.sum())
        r, c = np.nonzero(fp)
        ev = np.linalg.eigvalsh(np.cov(np.stack([r, c]).astype(float)))
        aspect.append(math.sqrt(ev[1] / ev[0]))
    assert max(top_frac) > 0.3  # flat-topped
    assert min(top_frac) < 0.03  # pointy
    assert max(aspect) > 1.4  # elongated
    assert min(aspect) < 1.2  # round-ish


def test_library_deterministic_and_seeded():
    a = rl.make_rock_library(seed=3)
    b = rl.make_rock_library(seed=3)
    c = rl.make_rock_library(seed=4)
    assert np.array_equal(a.shapes, b.shapes)
    assert not np.array_equal(a.shapes, c.shapes)
    assert rl.make_rock_library(n_shapes=20, size_px=33).shapes.shape == (20, 33, 33)


@pytest.mark.parametrize("seed", [0, 1, 2, 7])
def test_library_reach_bound(seed):
    # The pipeline selects rocks per tile with reach 0.75 D + 2 px; shapes must fit.
    lib = rl.make_rock_library(seed=seed)
    assert lib.reach_per_diameter().max() <= rl.MAX_REACH_PER_DIAMETER


def test_library_bad_input():
    with pytest.raises(OutOfRangeError, match=r"n_shapes = 15"):
        rl.make_rock_library(n_shapes=15)
    with pytest.raises(OutOfRangeError, match=r"size_px = 8"):
        rl.make_rock_library(size_px=8)
    shapes = rl.make_rock_library().shapes.copy()
    shapes[2] *= 0.5
    with pytest.raises(OutOfRangeError, match=r"shapes\[2\] peaks at 0.5"):
        rl.RockLibrary(shapes=shapes)


# ----------------------------------------------------------------------------- stamping


@pytest.mark.parametrize("d", [0.2, 0.3, 0.6])
def test_stamped_rock_height_and_footprint(lib, d):
    h = 0.5 * d
    offsets = np.random.default_rng(1).uniform(-0.5, 0.5, (lib.n_shapes, 2)) * RES
    for k in range(lib.n_shapes):
        ox, oy = offsets[k]
        z, mask, _, _ = _stamp_one(lib, d=d, h=h, k=k, x0=ox, y0=oy, rid=k)
        assert abs(float(z.max()) - h) <= 0.05 * h
        d_eq = 2.0 * math.sqrt(mask.sum() / math.pi) * RES
        assert abs(d_eq - d) <= 0.15 * d, (k, d_eq)
        # The mask is exactly where the rock stands > 1 mm above the flat ground.
        assert np.array_equal(mask.astype(bool), z > np.float32(rl.MASK_THRESHOLD_M))
        assert z.min() == 0.0  # nothing dug below the ground


def test_stamped_profile_follows_library(lib):
    # A big rock centred on a pixel reproduces the library shape (up to rotation/scale).
    k, d, h = 0, 2.0, 1.0
    z, mask, _, _ = _stamp_one(lib, d=d, h=h, k=k, n=129)
    hs = h / (1.0 - rl.EMBEDMENT)
    rel = (z[mask > 0] + rl.EMBEDMENT * hs) / hs  # back to library units
    assert rel.max() == pytest.approx(1.0, abs=1e-6)
    assert np.all(rel > rl.EMBEDMENT)
    assert z[64, 64] == pytest.approx(h, abs=1e-6)


def test_rock_on_slope_is_seated_at_base_z(lib):
    n = 64
    grid = GridSpec(n, n, RES)
    x, y = grid.pixel_centers(0, 0, n, n)
    a, b = 0.3, -0.2
    ground = (a * x[None, :] + b * y[:, None]).astype(np.float32)
    xc, yc = float(x[30]), float(y[33])
    seat = a * xc + b * yc
    d, h = 0.5, 0.2
    for shift in (0.0, 0.07):
        z, mask, _, _ = _stamp_one(
            lib, d=d, h=h, k=5, x0=xc, y0=yc, base=seat + shift, ground=ground
        )
        assert z[33, 30] == pytest.approx(seat + shift + h, abs=1e-5)
        changed = z != ground
        assert z[changed].max() <= seat + shift + h + 1e-5
        assert z[changed].min() >= seat + shift - rl.EMBEDMENT * h / (1 - rl.EMBEDMENT) - 1e-5
        # Uphill of the rock the original terrain may bury it; never lowered anywhere.
        assert np.all(z >= ground)
        assert mask.any()
    # The seat comes from base_z, not from the ground under the tile.
    z1, _, _, _ = _stamp_one(lib, d=d, h=h, k=5, x0=xc, y0=yc, base=seat, ground=ground)
    z2, _, _, _ = _stamp_one(
        lib, d=d, h=h, k=5, x0=xc, y0=yc, base=seat, ground=ground - np.float32(0.01)
    )
    assert z1[33, 30] == z2[33, 30]


def test_subpixel_rock_raises_nearest_pixel(lib):
    n = 16
    grid = GridSpec(n, n, RES)
    x, y = grid.pixel_centers(0, 0, n, n)
    xc, yc = float(x[7]) + 0.3 * RES, float(y[9]) - 0.2 * RES
    z, mask, _, _ = _stamp_one(lib, d=0.3 * RES, h=0.01, k=2, x0=xc, y0=yc, n=n, base=0.0)
    assert z[9, 7] == np.float32(0.01)
    assert mask[9, 7] == 1
    assert mask.sum() == 1


def _rock_scene(n_rows=80, n_cols=96, n_rocks=70, seed=5):
    grid = GridSpec(n_rows, n_cols, RES)
    x, y = grid.pixel_centers(0, 0, n_rows, n_cols)
    r = np.arange(n_rows)[:, None]
    c = np.arange(n_cols)[None, :]
    ground = (0.01 * rng.hash_normal(11, r, c) + 0.05 * x[None, :]).astype(np.float32)
    g = rng.generator(seed, "test_rocks")
    rx = g.uniform(x[0] - 0.4, x[-1] + 0.4, n_rocks)
    ry = g.uniform(y[-1] - 0.4, y[0] + 0.4, n_rocks)
    d = np.exp(g.uniform(math.log(0.01), math.log(0.9), n_rocks))
    h = d * g.uniform(0.3, 0.7, n_rocks)
    k = g.integers(0, 16, n_rocks)
    rr, cc = grid.to_pixel(rx, ry)
    rr = np.clip(np.rint(rr).astype(int), 0, n_rows - 1)
    cc = np.clip(np.rint(cc).astype(int), 0, n_cols - 1)
    base = ground[rr, cc]
    return (
        grid,
        ground,
        dict(rocks_x=rx, rocks_y=ry, diameters=d, heights=h, shape_index=k, base_z=base),
    )


@pytest.mark.parametrize("use_ids", [True, False])
def test_stamp_rocks_tile_invariant(lib, use_ids):
    grid, ground, cat = _rock_scene()
    nr, nc = grid.nrows, grid.ncols
    x, y = grid.pixel_centers(0, 0, nr, nc)
    ids = np.arange(cat["diameters"].size)
    z = ground.copy()
    mask = np.zeros(z.shape, np.uint8)
    rl.stamp_rocks(
        z, mask, x=x, y=y, library=lib, resolution_m=RES, rock_ids=ids if use_ids else None, **cat
    )
    assert mask.sum() > 200 and np.any(z > ground)
    zt = np.full_like(z, np.nan)
    mt = np.full(z.shape, 7, np.uint8)
    reach = 0.75 * cat["diameters"] + 2 * RES
    for r0, r1 in ((0, 37), (37, 38), (38, 80)):
        for c0, c1 in ((0, 50), (50, 61), (61, 96)):
            xs, ys = grid.pixel_centers(r0, c0, r1 - r0, c1 - c0)
            sel = np.flatnonzero(
                (cat["rocks_x"] + reach >= xs[0])
                & (cat["rocks_x"] - reach <= xs[-1])
                & (cat["rocks_y"] + reach >= ys[-1])
                & (cat["rocks_y"] - reach <= ys[0])
            )
            tz = ground[r0:r1, c0:c1].copy()
            tm = np.zeros(tz.shape, np.uint8)
            rl.stamp_rocks(
                tz,
                tm,
                x=xs,
                y=ys,
                library=lib,
                resolution_m=RES,
                rock_ids=ids[sel] if use_ids else None,
                **{key: v[sel] for key, v in cat.items()},
            )
            zt[r0:r1, c0:c1] = tz
            mt[r0:r1, c0:c1] = tm
    assert np.array_equal(z, zt)
    assert np.array_equal(mask, mt)


def test_stamp_rocks_bad_input(lib):
    z = np.zeros((8, 8), np.float32)
    m = np.zeros((8, 8), np.uint8)
    x, y = GridSpec(8, 8, RES).pixel_centers(0, 0, 8, 8)
    kw = dict(
        x=x,
        y=y,
        rocks_x=[0.0, 0.1],
        rocks_y=[0.0, 0.0],
        heights=[0.1, 0.1],
        shape_index=[0, 1],
        base_z=[0.0, 0.0],
        library=lib,
        resolution_m=RES,
    )
    with pytest.raises(OutOfRangeError, match=r"diameters\[1\] = -0.2"):
        rl.stamp_rocks(z, m, diameters=[0.2, -0.2], **kw)
    with pytest.raises(OutOfRangeError, match=r"shape_index\[1\] = 99"):
        rl.stamp_rocks(z, m, diameters=[0.2, 0.2], **{**kw, "shape_index": [0, 99]})
    with pytest.raises(ConfigError, match="base_z"):
        rl.stamp_rocks(z, m, diameters=[0.2, 0.2], **{**kw, "base_z": [0.0]})
    with pytest.raises(ConfigError, match="float32"):
        rl.stamp_rocks(z.astype(np.float64), m, diameters=[0.2, 0.2], **kw)


# ----------------------------------------------------------------------------- albedo


def _albedo(n, *, craters=(), fresh=(), d=(), mask=None, params=None, win=None):
    grid = GridSpec(n, n, RES)
    r0, c0, h, w = win or (0, 0, n, n)
    x, y = grid.pixel_centers(r0, c0, h, w)
    cx = [c[0] for c in craters]
    cy = [c[1] for c in craters]
    return al.albedo_tile(
        x=x,
        y=y,
        row0=r0,
        col0=c0,
        key=rng.stream_key(0, "test_albedo"),
        craters_x=cx,
        craters_y=cy,
        diameters=d,
        freshness=fresh,
        rock_mask=mask,
        params=params or al.AlbedoParams(),
    )


def test_albedo_fresh_brighter_than_old_and_background_far_away():
    n, d = 200, 1.0
    rad_px = 0.5 * d / RES
    p = al.AlbedoParams()
    bg = _albedo(n)
    fresh = _albedo(n, craters=[(0.0, 0.0)], fresh=[1.0], d=[d])
    old = _albedo(n, craters=[(0.0, 0.0)], fresh=[0.6], d=[d])
    ancient = _albedo(n, craters=[(0.0, 0.0)], fresh=[0.0], d=[d])
    assert bg.dtype == np.float32 and bg.shape == (n, n)
    yy, xx = np.mgrid[0:n, 0:n] + 0.5 - n / 2
    rho = np.hypot(xx, yy) / rad_px
    inner = rho < 0.9
    annulus = (rho > 1.1) & (rho < 1.5)
    far = rho > p.splash_extent_radii + 0.5
    # Inside the rim of a pristine crater: exactly (1 + contrast) x background.
    np.testing.assert_allclose(fresh[inner] / bg[inner], 1.0 + p.splash_contrast, rtol=1e-5)
    # Same crater half-faded: F = exp(-5 * 0.4) = 0.135 of the brightening inside.
    fade = math.exp(-p.fade_rate * 0.4)
    np.testing.assert_allclose(old[inner] / bg[inner], 1.0 + p.splash_contrast * fade, rtol=1e-5)
    assert fresh[annulus].mean() > 1.1 * old[annulus].mean()
    assert old[annulus].mean() > bg[annulus].mean()  # faded, not gone
    assert np.array_equal(ancient, bg)  # fully weathered: blended into the background
    # Far away the splash is exactly absent: background (noise only).
    assert np.array_equal(fresh[far], bg[far])
    assert abs(bg.mean() / p.base_albedo - 1.0) < 0.01
    assert 0.01 < bg.std() / bg.mean() < 0.05
    # Rays: the brightening at 3 R varies with azimuth.
    ring = (rho > 2.9) & (rho < 3.1)
    ratio = fresh[ring] / bg[ring]
    assert ratio.max() - ratio.min() > 0.05


def test_albedo_rocks_brighter_and_clipped():
    n = 32
    mask = np.zeros((n, n), np.uint8)
    mask[5:9, 10:20] = 1
    p = al.AlbedoParams()
    a0 = _albedo(n)
    a1 = _albedo(n, mask=mask)
    np.testing.assert_allclose(a1[mask > 0], a0[mask > 0] * p.rock_albedo_factor, rtol=1e-6)
    assert np.array_equal(a1[mask == 0], a0[mask == 0])
    bright = al.AlbedoParams(base_albedo=0.9, splash_contrast=2.0)
    a2 = _albedo(n, craters=[(0.0, 0.0)], fresh=[1.0], d=[0.5], mask=mask, params=bright)
    assert a2.max() == 1.0 and a2.min() >= 0.0


def test_albedo_tile_invariant():
    n = 120
    g = rng.generator(2, "test_albedo_scene")
    m = 60
    half = n * RES / 2
    craters = list(
        zip(g.uniform(-half - 1, half + 1, m), g.uniform(-half - 1, half + 1, m), strict=True)
    )
    d = np.exp(g.uniform(math.log(0.3), math.log(4.0), m))
    f = g.uniform(0, 1, m)
    f[:5] = 1.0
    mask = rng.hash_uniform(9, np.arange(n)[:, None], np.arange(n)[None, :]) < 0.05
    whole = _albedo(n, craters=craters, fresh=f, d=d, mask=mask.astype(np.uint8))
    assert whole.std() > 0.01
    grid = GridSpec(n, n, RES)
    cx, cy = np.array(craters).T
    reach = al.splash_extent_m(d, params=al.AlbedoParams()) + RES
    for subset in (False, True):
        tiled = np.full_like(whole, np.nan)
        for r0, r1 in ((0, 45), (45, 46), (46, 120)):
            for c0, c1 in ((0, 1), (1, 77), (77, 120)):
                sel = np.arange(m)
                if subset:  # only the craters reaching the tile, as the pipeline passes
                    xs, ys = grid.pixel_centers(r0, c0, r1 - r0, c1 - c0)
                    sel = np.flatnonzero(
                        (cx + reach >= xs[0])
                        & (cx - reach <= xs[-1])
                        & (cy + reach >= ys[-1])
                        & (cy - reach <= ys[0])
                    )
                tiled[r0:r1, c0:c1] = _albedo(
                    n,
                    craters=[craters[i] for i in sel],
                    fresh=f[sel],
                    d=d[sel],
                    mask=mask[r0:r1, c0:c1].astype(np.uint8),
                    win=(r0, c0, r1 - r0, c1 - c0),
                )
        assert np.array_equal(whole, tiled)


def test_splash_extent_covers_splash():
    p = al.AlbedoParams()
    d = np.array([1.0, 2.0])
    ext = al.splash_extent_m(d, params=p)
    assert np.allclose(ext, p.splash_extent_radii * d / 2)
    fe = al.splash_extent_m(d, params=p, freshness=[1.0, 0.0])
    assert fe[0] == pytest.approx(ext[0]) and fe[1] == 0.0  # fully faded: skipped
    n = 200
    a = _albedo(n, craters=[(0.0, 0.0)], fresh=[0.6], d=[1.0])
    b = _albedo(n)
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5 - n / 2) * RES
    reach = al.splash_extent_m([1.0], params=p, freshness=[0.6])[0]
    changed = a != b
    assert changed.any()
    assert np.hypot(xx, yy)[changed].max() <= reach


def test_albedo_bad_input():
    with pytest.raises(OutOfRangeError, match=r"freshness\[0\] = 1.5"):
        _albedo(8, craters=[(0.0, 0.0)], fresh=[1.5], d=[1.0])
    with pytest.raises(OutOfRangeError, match=r"diameters\[0\] = -1.0"):
        _albedo(8, craters=[(0.0, 0.0)], fresh=[0.5], d=[-1.0])
    with pytest.raises(OutOfRangeError, match=r"base_albedo = 0"):
        al.AlbedoParams(base_albedo=0)
    with pytest.raises(OutOfRangeError, match=r"splash_extent_radii = 0.5"):
        al.AlbedoParams(splash_extent_radii=0.5)
    with pytest.raises(ConfigError, match=r"ray_sharpness = 2.5"):
        al.AlbedoParams(ray_sharpness=2.5)


# ----------------------------------------------------------------------------- surface


def test_normals_of_plane_exact():
    n = 12
    grid = GridSpec(n + 2, n + 2, RES)
    x, y = grid.pixel_centers(0, 0, n + 2, n + 2)
    for a, b in ((0.3, -0.7), (0.0, 0.5), (-1.2, 0.0), (2.0, 3.0)):
        z = a * x[None, :] + b * y[:, None] + 4.0
        nrm = sf.normals_from_dem(z, resolution_m=RES)
        assert nrm.shape == (3, n, n) and nrm.dtype == np.float32
        want = np.array([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1.0)
        np.testing.assert_allclose(nrm, np.broadcast_to(want[:, None, None], nrm.shape), atol=1e-6)
        np.testing.assert_allclose(
            sf.slope_deg(z, resolution_m=RES), math.degrees(math.atan(math.hypot(a, b))), atol=1e-4
        )


def test_normal_directions_by_row_and_column():
    # z grows with the row index (southward): the ground falls towards the north, so
    # the slope faces north and the normal leans north (+y).
    z = np.repeat(np.arange(6, dtype=np.float32)[:, None], 6, axis=1) * 0.01
    nrm = sf.normals_from_dem(z, resolution_m=RES)
    assert np.all(nrm[1] > 0.2) and np.all(nrm[0] == 0)
    # z grows eastward (with the column): the slope faces west, normal x < 0.
    nrm = sf.normals_from_dem(z.T.copy(), resolution_m=RES)
    assert np.all(nrm[0] < -0.2) and np.all(nrm[1] == 0)


def test_normals_tile_invariant():
    n = 50
    z = (0.05 * rng.hash_normal(3, np.arange(n)[:, None], np.arange(n)[None, :])).astype(np.float32)
    zh = np.pad(z, 1, mode="edge")
    whole = sf.normals_from_dem(zh, resolution_m=RES)
    tiled = np.empty_like(whole)
    for r0, r1 in ((0, 17), (17, 50)):
        for c0, c1 in ((0, 1), (1, 50)):
            tiled[:, r0:r1, c0:c1] = sf.normals_from_dem(
                zh[r0 : r1 + 2, c0 : c1 + 2], resolution_m=RES
            )
    assert np.array_equal(whole, tiled)
    np.testing.assert_allclose(np.sum(whole.astype(np.float64) ** 2, axis=0), 1.0, atol=1e-6)


def test_hillshade():
    flat = np.zeros((5, 7))
    hs = sf.hillshade(flat, resolution_m=RES, altitude_deg=30.0)
    np.testing.assert_allclose(hs, 0.5, atol=1e-6)  # sin 30 deg
    grid = GridSpec(20, 20, RES)
    x, y = grid.pixel_centers(0, 0, 20, 20)
    facing_nw = -(-x[None, :] + y[:, None])  # falls towards the north-west
    facing_se = -facing_nw
    a = sf.hillshade(facing_nw, resolution_m=RES)
    b = sf.hillshade(facing_se, resolution_m=RES)
    assert a.dtype == np.float32 and a.shape == (20, 20)
    assert a.min() >= 0 and a.max() <= 1 and b.min() >= 0
    assert a.mean() > 0.9 and b.mean() < 0.05
    rough = rng.hash_normal(1, np.arange(30)[:, None], np.arange(30)[None, :])
    r = sf.hillshade(rough, resolution_m=RES)
    assert r.min() >= 0.0 and r.max() <= 1.0


def test_surface_bad_input():
    z = np.zeros((5, 5))
    z[2, 3] = np.nan
    with pytest.raises(NoDataError, match=r"nan at row 2, col 3"):
        sf.normals_from_dem(z, resolution_m=RES)
    with pytest.raises(NoDataError, match="z_halo"):
        sf.slope_deg(z, resolution_m=RES)
    with pytest.raises(OutOfRangeError, match=r"resolution_m = -1"):
        sf.normals_from_dem(np.zeros((4, 4)), resolution_m=-1)
    with pytest.raises(ConfigError, match=r"z_halo has shape \(2, 5\)"):
        sf.normals_from_dem(np.zeros((2, 5)), resolution_m=RES)
