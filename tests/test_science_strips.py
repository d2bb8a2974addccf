"""The world model out of core: illumination strip by strip with a decimated far field,
patches joined across blocks, and the whole stack built from a DEM read by rows."""

import dataclasses as dc
import math

import numpy as np
import pytest

from lunar_drake.errors import ConfigError
from lunar_drake.science import strips, thermal, volatiles
from lunar_drake.science.config import ThermalConfig, WorldConfig
from lunar_drake.science.sun_envelope import envelope_from_samples
from lunar_drake.science.sweep import FAR, NO_CASTER, TANGENT, Sweep
from lunar_drake.science.world import Craters, compute_world
from lunar_drake.terrain.crs import MOON_RADIUS_M as R


def _rough(n_rows: int, n_cols: int, seed: int = 2) -> np.ndarray:
    """Hills, a bowl and a random walk along rows (m), float32-representable."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n_rows, 0:n_cols].astype(float)
    r = np.hypot(x - n_cols / 2, y - n_rows / 2) / (0.3 * n_cols)
    walk = np.cumsum(rng.normal(size=(n_rows, n_cols)), axis=1) * 0.03
    bowl = -1.5 * np.clip(1 - r * r, 0, None) ** 2
    return (np.sin(x / 9.0) * 0.8 + np.cos(y / 7.0) * 0.6 + bowl + walk).astype(np.float32)


def _lunar(n_rows: int, n_cols: int, seed: int = 5) -> np.ndarray:
    """Hills, a bowl and smoothed noise (m), float32."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n_rows, 0:n_cols].astype(float)
    r = np.hypot(x - n_cols / 2, y - n_rows / 2) / (0.3 * n_cols)
    noise = ndimage.gaussian_filter(rng.normal(size=(n_rows, n_cols)), 2.0) * 0.5
    z = np.sin(x / 9.0) * 0.8 + np.cos(y / 7.0) * 0.6 - 1.5 * np.clip(1 - r * r, 0, None) ** 2
    return (z + noise).astype(np.float32)


def _envelope(az_deg=None, el_deg: float = 3.0, spread: float = 1.5):
    k = np.arange(1461)
    az = (k * 12 * 360 / 1461) % 360 if az_deg is None else np.full(k.size, float(az_deg))
    return envelope_from_samples(az, el_deg + spread * np.sin(2 * np.pi * k / 1461),
                                 np.full(k.size, 1.495978707e8), bins=16)  # fmt: skip


def _strips(z, res, env, cfg, *, az_now=120.0, el_now=3.0):
    jobs = thermal.sweep_jobs(env, sun_azimuth_deg=az_now, sun_elevation_deg=el_now,
                              sun_distance_au=1.0, config=cfg, horizon_mask=None)  # fmt: skip
    parts = list(strips.illumination_strips(lambda a, b: z[a:b], z.shape, resolution_m=res,
                                            jobs=jobs, config=cfg))  # fmt: skip
    assert [p[0] for p in parts] == list(range(0, z.shape[0], cfg.strip_px))
    names = ("ever_lit", "q_max_w_m2", "q_mean_w_m2", "q_now_w_m2", "lit_now")
    return {n: np.concatenate([getattr(p[1], n) for p in parts]) for n in names}


def _exact(z, res, env, cfg, *, az_now=120.0, el_now=3.0):
    il = thermal.illumination(z, resolution_m=res, envelope=env, sun_azimuth_deg=az_now,
                              sun_elevation_deg=el_now, config=cfg, chunk=64)  # fmt: skip
    return {n: getattr(il, n) for n in ("ever_lit", "q_max_w_m2", "q_mean_w_m2", "q_now_w_m2",
                                        "lit_now")}  # fmt: skip


@pytest.mark.parametrize("azimuth", [90.0, 270.0])
def test_far_mode_is_the_steepest_caster_beyond_the_near_field(azimuth):
    """Along a row (the exact case) FAR gives the steepest caster at least ``near``
    columns away, from the pixel's own height, and 1 / its distance: against a brute
    maximum over the row."""
    z = _rough(24, 40).astype(np.float64)
    res, near = 0.5, 6
    sw = Sweep(z, azimuth_deg=azimuth, resolution_m=res, near=near)
    o = sw.orient
    t = np.full(z.shape, NO_CASTER)
    b = np.zeros(z.shape)
    sw.run(FAR, np.zeros(11), [0.0], o.canon(t), o.canon(b), np.zeros((1, 1), np.uint8))
    dc_ = 1 if azimuth == 90.0 else -1  # east: columns + k
    checked = 0
    for r in range(z.shape[0]):
        for c in range(z.shape[1]):
            k = np.arange(near, z.shape[1])
            cc = c + dc_ * k
            ok = (cc >= 0) & (cc < z.shape[1])
            if not ok.any():
                assert t[r, c] <= 0.5 * NO_CASTER and b[r, c] == 0.0
                continue
            d = k[ok] * res
            tan = (z[r, cc[ok]] - z[r, c] - d * d / (2 * R)) / d
            i = int(np.argmax(tan))
            assert t[r, c] == pytest.approx(tan[i], abs=1e-9)
            assert b[r, c] == pytest.approx(1.0 / d[i], rel=1e-9)
            checked += 1
    assert checked > 500


@pytest.mark.parametrize("azimuth", [10.0, 60.0, 100.0, 150.0, 190.0, 240.0, 280.0, 330.0])
def test_the_far_field_reaches_each_pixel_at_its_grid_position(azimuth):
    """On a plain (its own casters lie at about -1e-7) a sweep's tangent is its far
    field's: ``a - (z - z_ref) b`` interpolated bilinearly at the pixel's place in the
    whole grid (cell centres at ``(i + 0.5) k - 0.5`` px, edge cells held), for a window
    that starts 10 rows down the grid, whatever the sweep's orientation. The reference
    is numpy's ``interp`` along both axes."""
    rng = np.random.default_rng(4)
    k, grid_rows, row0, rows, cols = 4, 64, 10, 30, 44
    na, ma = -(-grid_rows // k), -(-cols // k)
    a = rng.uniform(0.05, 0.5, size=(na, ma)).astype(np.float32)
    b = rng.uniform(0.0, 0.2, size=(na, ma)).astype(np.float32)
    z = np.zeros((rows, cols))
    z_ref = -0.3
    sw = Sweep(z, azimuth_deg=azimuth, resolution_m=0.1)
    o = sw.orient
    t = np.full(z.shape, NO_CASTER, np.float32)
    far = strips.far_field(a, b, k=k, z_ref=z_ref, row0=row0, shape=z.shape)
    sw.run(TANGENT, np.zeros(11), [0.0], o.canon(t), o.canon(t), np.zeros((1, 1), np.uint8),
           far=far)  # fmt: skip

    def centre(i, n):  # pixel index -> coarse index, clamped to the cell centres
        return np.clip((np.asarray(i, float) + 0.5) / k - 0.5, 0, n - 1)

    ref_cells = a.astype(np.float64) - (0.0 - z_ref) * b.astype(np.float64)
    u = centre(np.arange(cols), ma)
    along = np.array([np.interp(u, np.arange(ma), row) for row in ref_cells])
    v = centre(np.arange(row0, row0 + rows), na)
    ref = np.array([np.interp(v, np.arange(na), along[:, c]) for c in range(cols)]).T
    np.testing.assert_allclose(t, ref, rtol=0, atol=2e-6)


@pytest.mark.parametrize("azimuth", [30.0, 120.0, 210.0, 300.0])
def test_the_far_field_shades_sector_and_epoch_sweeps(azimuth):
    """The same plain and far field under a Sun at 10 deg: the epoch's lit fraction is
    the visible part of the disk above the far horizon (the closed form, against the
    TANGENT sweep's horizon), and a sector flags a pixel lit exactly where the disk's
    top clears it."""
    from lunar_drake.render.lightmap import SUN_ANGULAR_RADIUS_DEG as R_SUN
    from lunar_drake.science.sweep import EPOCH, SECTOR

    rng = np.random.default_rng(9)
    k, rows, cols, row0 = 4, 30, 44, 6
    na, ma = -(-(row0 + rows + 8) // k), -(-cols // k)
    e = math.radians(10.0)
    a = np.tan(e + rng.uniform(-0.012, 0.012, size=(na, ma))).astype(np.float32)
    b = np.zeros((na, ma), np.float32)
    z = np.zeros((rows, cols))
    sw = Sweep(z, azimuth_deg=azimuth, resolution_m=0.1)
    o = sw.orient
    far = strips.far_field(a, b, k=k, z_ref=0.0, row0=row0, shape=z.shape)
    t = np.full(z.shape, NO_CASTER, np.float32)
    sw.run(TANGENT, np.zeros(11), [0.0], o.canon(t), o.canon(t), np.zeros((1, 1), np.uint8),
           far=far)  # fmt: skip
    par = sw.sun_par(flux_w_m2=1000.0, mask_deg=-90.0, radius_deg=R_SUN, w_mean=0.1)
    f, q = np.zeros(z.shape, np.float32), np.zeros(z.shape, np.float32)
    lit = np.zeros(z.shape, np.uint8)
    sw.run(EPOCH, par, [10.0], o.canon(f), o.canon(q), o.canon(lit), far=far)
    r = math.radians(R_SUN)
    v = np.clip((e - np.arctan(t.astype(np.float64))) / r, -1.0, 1.0)
    disk = 1.0 - (np.arccos(v) - v * np.sqrt(1.0 - v * v)) / np.pi
    assert 0.05 < (disk > 0.0).mean() < 0.95 and ((disk > 0.01) & (disk < 0.99)).any()
    # (The Sun stands up to ~2e-6 rad higher across the 4 m grid, the Moon's curvature,
    # which the reference leaves out: 5e-4 of the disk at most.)
    np.testing.assert_allclose(f, disk, atol=5e-4)
    assert np.array_equal(lit == 1, f > 0)  # lit at the epoch: lit once in the year
    q_max, q_mean, ever = (np.zeros(z.shape, np.float32), np.zeros(z.shape, np.float32),
                           np.zeros(z.shape, np.uint8))  # fmt: skip
    sw.run(SECTOR, par, [10.0, 10.0], o.canon(q_max), o.canon(q_mean), o.canon(ever), far=far)
    clear = np.abs(np.arctan(t.astype(np.float64)) - (e + r)) > 1e-5
    assert np.array_equal((ever == 1)[clear], (np.arctan(t) < e + r)[clear])
    np.testing.assert_allclose(q_max, 1000.0 * f * math.sin(e), rtol=1e-4, atol=1e-3)


def test_one_strip_over_the_grid_is_the_whole_grid_sweep_byte_for_byte():
    z = _rough(72, 56)
    cfg = ThermalConfig()
    env = _envelope()
    got = _strips(z, 0.25, env, dc.replace(cfg, strip_px=72))
    ref = _exact(z, 0.25, env, cfg)
    for name in ref:
        assert np.array_equal(got[name], ref[name]), name


def test_a_ridge_beyond_the_window_still_casts_its_shadow():
    """A 2 m ridge along the north edge of a 50 m plain, the Sun from the north at
    5 +- 0.5 deg: its shadow reaches 21-25 m, far beyond the 2 m windows of the strips
    south of it; the far field casts it as the whole-grid sweep does, the windows alone
    (far field removed) do not."""
    res, rows, cols = 0.25, 200, 48
    z = np.zeros((rows, cols), np.float32)
    z[:4] = 2.0
    env = _envelope(az_deg=0.0, el_deg=5.0, spread=0.5)
    cfg = ThermalConfig(strip_px=32, near_field_m=2.0, far_cell_m=0.5)
    ref = _exact(z, res, env, cfg, az_now=0.0, el_now=5.0)
    got = _strips(z, res, env, cfg, az_now=0.0, el_now=5.0)
    # The sector's azimuth is 11.25 deg: rays from column 4 stay on the grid.
    dark_ref = ref["ever_lit"][:, 4] == 0
    assert dark_ref[10:75].all() and not dark_ref[100:].any()  # 2 / tan(5.77 deg) = 20 m
    assert np.mean(got["ever_lit"] != ref["ever_lit"]) < 0.01
    assert np.abs(got["lit_now"] - ref["lit_now"]).mean() < 0.01

    def no_far(zk, jobs, **kw):
        return [(np.full(zk.shape, NO_CASTER, np.float32), np.zeros(zk.shape, np.float32))
                for _ in jobs]  # fmt: skip

    orig = strips.far_fields
    strips.far_fields = no_far
    try:
        blind = _strips(z, res, env, cfg, az_now=0.0, el_now=5.0)
    finally:
        strips.far_fields = orig
    assert (blind["ever_lit"][40:75, 4] == 1).all()  # the windows alone see the Sun


def test_strips_are_close_to_the_whole_grid_on_rough_terrain():
    """A near field 15 far cells deep, as the defaults at 4 cm (10 m, 0.64 m): permanent
    shadow differs on 0.3 % of the pixels (of 30 % in shadow), the fluxes by 0.5 %."""
    z = _lunar(192, 160)
    res = 0.1
    env = _envelope()
    cfg = ThermalConfig(strip_px=48, near_field_m=3.0, far_cell_m=0.2)
    ref = _exact(z, res, env, cfg)
    got = _strips(z, res, env, cfg)
    psr_ref = ref["ever_lit"] == 0
    assert 0.1 < psr_ref.mean() < 0.5
    assert np.mean((got["ever_lit"] == 0) != psr_ref) < 0.006
    for name in ("q_max_w_m2", "q_mean_w_m2", "q_now_w_m2"):
        assert np.abs(got[name] - ref[name]).mean() < 0.01 * ref[name].mean(), name


def test_patches_joined_across_blocks_have_their_whole_area():
    rng = np.random.default_rng(0)
    for _ in range(15):
        shape = (int(rng.integers(5, 60)), int(rng.integers(1, 50)))
        m = rng.random(shape) < rng.uniform(0.2, 0.6)
        labels, areas = volatiles.label_patches(m)
        for step in (1, 2, 5, 1000):
            sl = volatiles.StripLabels()
            got = np.concatenate([sl.add(m[r : r + step]) for r in range(0, m.shape[0], step)])
            assert np.array_equal(sl.areas()[got], areas[labels])
            assert np.array_equal(got > 0, m)


def _world(z, **thermal_kw):
    env = _envelope()
    craters = Craters(x_m=np.array([0.0]), y_m=np.array([0.0]), diameter_m=np.array([8.0]),
                      age_yr=np.array([1e8]))  # fmt: skip
    tile = thermal_kw.pop("tile_px", 4096)
    thermal_kw.setdefault("whole_max_mpx", 0.0)
    cfg = WorldConfig(tile_px=tile, thermal=ThermalConfig(**thermal_kw))
    return compute_world(z, resolution_m=0.25, craters=craters, seed=3, envelope=env,
                         sun_azimuth_deg=120.0, sun_elevation_deg=3.0, config=cfg)  # fmt: skip


def test_the_out_of_core_stack_is_the_whole_one_with_one_strip_and_tile_invariant():
    """The strip pipeline (fluxes and temperatures on disk between passes, windowed view
    factors, coarse sources streamed, patches joined across blocks) gives the in-memory
    stack byte for byte when one strip covers the grid; with several strips, the tile
    size still never changes a byte."""
    z = _lunar(96, 72)
    whole = _world(z, whole_max_mpx=1.0)
    one = _world(z, strip_px=96, tile_px=64)
    for name in whole:
        assert np.array_equal(whole[name], one[name]), name
    a = _world(z, strip_px=32, near_field_m=2.0, tile_px=64)
    b = _world(z, strip_px=32, near_field_m=2.0, tile_px=4096)
    for name in a:
        assert np.array_equal(a[name], b[name]), name
    assert np.mean(a["psr"] != whole["psr"]) < 0.02


@pytest.mark.parametrize(
    "field, value",
    [("strip_px", 8), ("near_field_m", 0.0), ("far_cell_m", 500.0), ("whole_max_mpx", -1.0),
     ("near_field_m", 1.0)],  # less than twice the 0.64 m far cell: a gap between them
)
def test_bad_strip_settings_are_refused(field, value):
    with pytest.raises(ConfigError, match=field):
        ThermalConfig(**{field: value}).validate()


def test_the_far_grid_is_bounded():
    cfg = ThermalConfig()
    assert strips.far_factor((30720, 30720), 0.04, cfg) == 16  # 0.64 m cells, 3.7 Mpx
    assert strips.far_factor((2048, 2048), 0.04, cfg) == 16
    k = strips.far_factor((20000, 20000), 1.0, cfg)  # 1 m pixels: not 1 px cells
    assert k == 10 and (20000 / k) ** 2 <= strips.MAX_FAR_CELLS


def test_the_height_datum_does_not_matter():
    """Heights 3 km above the datum (a polar DEM's) give the same light: the far field
    is stored relative to the mean height, so float32 loses nothing to the datum."""
    z = _lunar(96, 80)
    cfg = ThermalConfig(strip_px=32, near_field_m=2.0, far_cell_m=0.5)
    env = _envelope()
    lo = _strips(z, 0.1, env, cfg)
    hi = _strips(z.astype(np.float64) + 3000.0, 0.1, env, cfg)
    assert np.mean(lo["ever_lit"] != hi["ever_lit"]) < 1e-3
    for name in ("q_max_w_m2", "q_mean_w_m2"):
        assert np.abs(lo[name] - hi[name]).mean() < 1e-3 * lo[name].mean(), name


def test_only_big_dems_are_built_out_of_core():
    cfg = ThermalConfig()
    assert not cfg.out_of_core((8192, 8192)) and cfg.out_of_core((30720, 30720))
    assert ThermalConfig(whole_max_mpx=0).out_of_core((1, 1))


def test_world_build_out_of_core_from_the_cli(small_site, tmp_path):
    """``world build`` of a site forced out of core, compressed: every layer written,
    close to the in-memory build of the same site; GDAL's cache limit restored."""
    import rasterio
    from rasterio.env import get_gdal_config

    from lunar_drake.cli import main

    site_dir = str(small_site[1].site.directory)
    cfg = tmp_path / "strips.yaml"
    cfg.write_text("thermal: {whole_max_mpx: 0, strip_px: 64}\ncompress: zstd\n")
    cache = get_gdal_config("GDAL_CACHEMAX")
    a, b = tmp_path / "whole", tmp_path / "strips"
    assert main(["world", "build", site_dir, "--out", str(a), "--no-progress"]) == 0
    assert main(["world", "build", site_dir, "--out", str(b), "--config", str(cfg),
                 "--no-progress"]) == 0  # fmt: skip
    assert get_gdal_config("GDAL_CACHEMAX") == cache
    for name in ("psr", "t_max_K", "minerals", "ice_wt_pct"):
        with rasterio.open(a / f"{name}.tif") as da, rasterio.open(b / f"{name}.tif") as db:
            assert db.compression is not None and da.compression is None
            va, vb = da.read(), db.read()
        if name == "minerals":
            assert np.array_equal(va, vb)
        elif name == "psr":
            assert np.mean(va != vb) < 0.01
        else:
            assert np.abs(va - vb).mean() < 0.01 * np.abs(va).mean() + 1e-6, name
