"""Tests for lunar_drake.render.lightmap and lunar_drake.render.horizon (paper section 5).

Closed-form geometry (a wall, a spherical bowl, a level outside horizon), agreement with
the 280-ray brute force (99th percentile of cells within 0.02 lit fraction), bit-identical
tiling, hourly series interpolation and the CLI.
"""

from __future__ import annotations

import argparse
import math
import sys
import types

import numpy as np
import pytest
import rasterio

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import lightmap as lm
from lunar_drake.render.horizon import (
    MOON_RADIUS_M,
    HorizonField,
    HorizonMask,
    horizon_angles,
    horizon_profile,
    sweep_orientation,
)
from lunar_drake.terrain.crs import lonlat_to_xy, moon_south_polar_stereographic
from lunar_drake.terrain.fractal import FractalParams, coarse_fractal
from lunar_drake.terrain.heightfield import Heightfield

R_SUN = math.radians(lm.SUN_ANGULAR_RADIUS_DEG)
NO_OUTSIDE = HorizonMask.none()


def _fractal(n=128, res=0.05, seed=5):
    return coarse_fractal(
        (n, n), resolution_m=res, rng=rng.generator(seed, "test/lightmap"), params=FractalParams()
    )


def _wall(nr=40, nc=120, res=0.1, col=20, height=1.0):
    """Level ground (0) with a N-S wall of ``height`` m over columns [col - 3, col]."""
    z = np.zeros((nr, nc))
    z[:, col - 3 : col + 1] = height
    return z


# ------------------------------------------------------------------------ disk fraction
def test_disk_fraction_matches_numerical_integration_for_both_limbs():
    n = 1200
    g = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(g, g)
    inside = X**2 + Y**2 < 1
    mu = np.sqrt(np.clip(1 - X**2 - Y**2, 0, 1))
    weights = {"uniform": inside * 1.0, "darkened": inside * (1 - 0.6 * (1 - mu))}
    for limb, I in weights.items():
        for v in (-0.8, -0.3, 0.0, 0.45, 0.95):
            num = (I * (Y > -v)).sum() / I.sum()
            f = lm.solar_disk_visible_fraction(-v * R_SUN, 0.0, sun_radius_rad=R_SUN, limb=limb)
            assert f == pytest.approx(num, abs=2e-3), (limb, v)
    f = lm.solar_disk_visible_fraction(np.array([-1.0, -R_SUN, 0.0, R_SUN, 1.0]), 0.0)
    np.testing.assert_allclose(f, [1.0, 1.0, 0.5, 0.0, 0.0], atol=1e-12)
    # symmetric: f(v) + f(-v) = 1
    v = np.linspace(-1, 1, 41) * R_SUN
    for limb in lm.LIMBS:
        s = lm.solar_disk_visible_fraction(v, 0.0, limb=limb) + lm.solar_disk_visible_fraction(
            -v, 0.0, limb=limb
        )
        np.testing.assert_allclose(s, 1.0, atol=1e-12)
    with pytest.raises(ConfigError, match="limb"):
        lm.solar_disk_visible_fraction(0.0, 0.0, limb="gray")


# ---------------------------------------------------------------------------- the wall
@pytest.mark.parametrize("az", [270.0, 250.0])
def test_wall_shadow_length_and_penumbra_follow_the_disk(az):
    """Ground east of a wall of height H: shadow length H / tan(e) (centre ray), fully dark
    closer than H / tan(e + r), fully lit beyond H / tan(e - r), and in between the
    segment formula for h = atan((H - d^2 / 2R) / d), d along the ray to the wall top."""
    res, H, col, el = 0.1, 1.0, 20, 8.0
    z = _wall(nr=80, res=res, col=col, height=H)
    L = lm.lightmap(
        z, sun_azimuth_deg=az, sun_elevation_deg=el, resolution_m=res, horizon_mask=NO_OUTSIDE
    )
    e = math.radians(el)
    rows = slice(2, 40)  # rays of these rows reach the wall inside the grid (drift <= 37)
    cols = np.arange(col + 1, z.shape[1])
    d = (cols - col) * res / abs(math.sin(math.radians(az)))  # along the ray
    h = np.arctan((H - d * d / (2 * MOON_RADIUS_M)) / d)
    expected = lm.solar_disk_visible_fraction(h, e)
    got = L[rows, col + 1 :]
    assert np.abs(got - expected[None, :]).max() < 0.02
    dark = d < H / math.tan(e + R_SUN)
    lit = d > H / math.tan(e - R_SUN)
    partial = ~dark & ~lit
    assert (got[:, dark] == 0).all() and (got[:, lit] == 1).all()
    assert partial.sum() >= 3 and ((got[:, partial] > 0) & (got[:, partial] < 1)).all()
    # Shadow length of the Sun's centre: the 0.5 contour.
    half = d[np.argmin(np.abs(expected - 0.5))]
    assert half == pytest.approx(H / math.tan(e), abs=res * 1.5)
    # Everything west of the wall (and the wall top) is lit.
    assert (L[:, : col - 3] == 1).all()


def test_bowl_crater_floor_shadow_matches_the_circular_rim():
    """Spherical-cap bowl in level ground, low Sun from the west: a floor point is in the
    centre ray's shadow iff z + D tan(e) < 0, D = distance to the rim along the ray (the
    concave bowl never rises above the chord to the rim)."""
    n, res, Rc, depth = 161, 0.5, 30.0, 6.0
    Rs = (Rc**2 + depth**2) / (2 * depth)  # sphere through the rim and the floor centre
    y, x = (np.mgrid[0:n, 0:n] - (n - 1) / 2) * res
    r2 = x * x + y * y
    z = np.where(r2 < Rc**2, Rs - depth - np.sqrt(np.maximum(Rs**2 - r2, 0)), 0.0)
    for el in (8.0, 14.0):
        L = lm.lightmap(
            z,
            sun_azimuth_deg=270.0,
            sun_elevation_deg=el,
            resolution_m=res,
            horizon_mask=NO_OUTSIDE,
        )
        inside = r2 < (Rc - 2 * res) ** 2
        D = x + np.sqrt(np.maximum(Rc**2 - y * y, 0))  # to the western rim (row = -y)
        analytic = inside & (z + D * math.tan(math.radians(el)) < 0)
        shadow = inside & (L < 0.5)
        frac_a, frac_l = analytic.sum() / inside.sum(), shadow.sum() / inside.sum()
        assert 0.1 < frac_a < 0.9
        # Pixel-scale tolerance: at most one pixel along the shadow edge, which is
        # shorter than the crater diameter (2 Rc / res = 120 px).
        edge_px = 2 * Rc / res
        assert abs(frac_l - frac_a) < edge_px / inside.sum()
        assert (shadow ^ analytic).sum() < edge_px


# --------------------------------------------------------------------- vs brute force
@pytest.mark.parametrize("az, el", [(250.0, 5.0), (10.0, 3.0)])
def test_fast_method_agrees_with_the_280_ray_brute_force(az, el):
    """99th percentile of |fast - brute force| over cells (a random 8% sample) <= 0.02 on
    rough fractal terrain (pixel-scale slopes ~ the Sun's elevation)."""
    res = 0.05
    z = _fractal(res=res)
    L = lm.lightmap(
        z, sun_azimuth_deg=az, sun_elevation_deg=el, resolution_m=res, horizon_mask=NO_OUTSIDE
    )
    sel = np.random.default_rng(0).random(z.shape) < 0.08
    rows, cols = np.nonzero(sel)
    B = lm.lightmap_bruteforce(
        z,
        resolution_m=res,
        sun_azimuth_deg=az,
        sun_elevation_deg=el,
        horizon_mask=NO_OUTSIDE,
        pixels=(rows, cols),
    )
    err = np.abs(L[rows, cols] - B)
    assert ((B > 0) & (B < 1)).mean() > 0.03  # plenty of penumbra: the test has teeth
    assert 0.1 < B.mean() < 0.95
    assert np.percentile(err, 99) <= 0.02
    assert err.mean() < 0.003


def test_bruteforce_limb_darkening_matches_the_closed_form():
    z = np.zeros((3, 3))
    for h in (4.8, 5.0, 5.15):
        mask = HorizonMask.level(h)
        for limb in lm.LIMBS:
            b = lm.lightmap_bruteforce(
                z,
                resolution_m=1.0,
                sun_azimuth_deg=90.0,
                sun_elevation_deg=5.0,
                limb=limb,
                horizon_mask=mask,
            )
            f = lm.solar_disk_visible_fraction(math.radians(h), math.radians(5.0), limb=limb)
            assert b[1, 1] == pytest.approx(f, abs=0.01)
            fast = lm.lightmap(
                z,
                resolution_m=1.0,
                sun_azimuth_deg=90.0,
                sun_elevation_deg=5.0,
                limb=limb,
                horizon_mask=mask,
            )
            assert fast[1, 1] == pytest.approx(f, abs=1e-4)


# ------------------------------------------------------------------------- tiling
def test_lightmap_is_bit_identical_for_any_tiling_and_workers():
    z = _fractal(n=72, res=0.05, seed=2)[:, :60].copy()
    z[30:33, 40:44] = np.nan  # nodata hole
    mask = HorizonMask(
        (0.0, 90.0, 180.0, 270.0),
        np.stack([np.full((2, 3), v) for v in (1.0, 2.0, 1.5, 3.5)]) + np.arange(3) * 0.7,
        bounds=(-1.5, -1.8, 1.5, 1.8),
    )
    for az, el in [(250.0, 4.0), (90.0, 6.0), (0.0, 3.5), (45.0, 5.0), (163.0, 4.5)]:
        ref = lm.lightmap(
            z,
            sun_azimuth_deg=az,
            sun_elevation_deg=el,
            resolution_m=0.05,
            horizon_mask=mask,
            workers=1,
        )
        assert np.isnan(ref[30:33, 40:44]).all() and not np.isnan(ref[:30]).any()
        assert ((ref > 0) & (ref < 1)).any()
        for tile, workers in [(16, 1), (24, 3), (40, 2)]:
            got = lm.lightmap(
                z,
                sun_azimuth_deg=az,
                sun_elevation_deg=el,
                resolution_m=0.05,
                horizon_mask=mask,
                tile_px=tile,
                workers=workers,
            )
            np.testing.assert_array_equal(got, ref)  # NaN == NaN here, bits otherwise


def test_halo_cap_bounds_the_shadow_reach_consistently():
    """A capped reach ignores far casters -- the same way in every tiling."""
    z = _wall(nr=24, nc=100, res=0.1, col=10, height=1.0)
    full = lm.lightmap(
        z, sun_azimuth_deg=270.0, sun_elevation_deg=2.0, resolution_m=0.1, horizon_mask=NO_OUTSIDE
    )
    capped = lm.lightmap(
        z,
        sun_azimuth_deg=270.0,
        sun_elevation_deg=2.0,
        resolution_m=0.1,
        horizon_mask=NO_OUTSIDE,
        max_shadow_length_m=3.0,
    )
    tiled = lm.lightmap(
        z,
        sun_azimuth_deg=270.0,
        sun_elevation_deg=2.0,
        resolution_m=0.1,
        horizon_mask=NO_OUTSIDE,
        max_shadow_length_m=3.0,
        tile_px=16,
    )
    assert (full[:, 11:] == 0).all()  # a 28.6 m shadow, longer than the grid
    assert (capped[:, 11:40] == 0).all()  # casters within 3 m
    assert (capped[:, 42:] == 1).all()  # the wall is out of reach

    np.testing.assert_array_equal(tiled, capped)


# -------------------------------------------------------------- outside horizon, Sun below
def test_outside_horizon_mask_darkens_cells_when_above_the_sun():
    z = np.zeros((20, 30))
    kw = dict(resolution_m=1.0, sun_azimuth_deg=200.0, sun_elevation_deg=5.0)
    assert (lm.lightmap(z, horizon_mask=HorizonMask.level(4.0), **kw) == 1).all()
    assert (lm.lightmap(z, horizon_mask=HorizonMask.level(5.5), **kw) == 0).all()
    np.testing.assert_allclose(
        lm.lightmap(z, horizon_mask=HorizonMask.level(5.0), **kw), 0.5, atol=1e-4
    )
    # Azimuth-dependent profile: high only towards the south-west.
    prof = HorizonMask((0.0, 90.0, 180.0, 200.0, 220.0, 270.0), [0, 0, 0, 7, 0, 0])
    assert (lm.lightmap(z, horizon_mask=prof, **kw) == 0).all()
    assert (lm.lightmap(z, horizon_mask=prof, **{**kw, "sun_azimuth_deg": 100.0}) == 1).all()
    # Gridded: the eastern half of the site sees a high horizon.
    grid = HorizonMask((0.0,), np.array([[[0.0, 9.0]]]), bounds=(-15.0, -10.0, 15.0, 10.0))
    L = lm.lightmap(z, horizon_mask=grid, **kw)
    assert (L[:, :15] == 1).all() and (L[:, 15:] == 0).all()
    # The outside horizon adds to the DEM's own shadows.
    wall = _wall()
    own = lm.lightmap(
        wall, resolution_m=0.1, sun_azimuth_deg=270, sun_elevation_deg=8.0, horizon_mask=NO_OUTSIDE
    )
    both = lm.lightmap(
        wall,
        resolution_m=0.1,
        sun_azimuth_deg=270,
        sun_elevation_deg=8.0,
        horizon_mask=HorizonMask.level(8.0),
    )
    np.testing.assert_allclose(both, np.minimum(own, 0.5), atol=1e-5)


def test_sun_elevation_follows_the_curvature_across_a_large_grid():
    """Level ground 20 km wide, Sun on the horizon in the east at the grid centre: a cell
    u metres towards the Sun sees it u / R higher (R = lunar radius)."""
    res, n = 100.0, 201
    z = np.zeros((3, n))
    L = lm.lightmap(
        z, resolution_m=res, sun_azimuth_deg=90.0, sun_elevation_deg=0.0, horizon_mask=NO_OUTSIDE
    )
    u = (np.arange(n) + 0.5 - n / 2) * res
    expected = lm.solar_disk_visible_fraction(0.0, u / MOON_RADIUS_M)
    np.testing.assert_allclose(L[1], expected, atol=1e-3)
    assert L[1, 0] == 0 and L[1, -1] == 1 and 0 < L[1, n // 2 + 5] < 1
    B = lm.lightmap_bruteforce(
        z,
        resolution_m=res,
        sun_azimuth_deg=90.0,
        sun_elevation_deg=0.0,
        horizon_mask=NO_OUTSIDE,
        pixels=([1] * 9, range(80, 125, 5)),
    )
    np.testing.assert_allclose(B, expected[80:125:5], atol=0.01)


def test_sun_below_the_horizon_gives_zeros():
    z = _fractal(n=32)
    z[3, 4] = np.nan
    L = lm.lightmap(z, resolution_m=0.05, sun_azimuth_deg=120.0, sun_elevation_deg=-1.0)
    assert np.isnan(L[3, 4]) and np.nansum(L) == 0 and np.isnan(L).sum() == 1
    B = lm.lightmap_bruteforce(
        z,
        resolution_m=0.05,
        sun_azimuth_deg=120.0,
        sun_elevation_deg=-1.0,
        pixels=([0, 10], [0, 20]),
    )
    assert (B == 0).all()


def test_horizon_mask_from_a_regional_dem():
    """A ridge 400 m east of the site, 20 m high, on a coarse regional DEM."""
    res = 10.0
    z = np.zeros((101, 101))
    z[:, 90] = 20.0  # ridge column, 40 px = 400 m east of the centre column 50
    az = np.arange(0.0, 360.0, 10.0)
    mask = HorizonMask.from_dem(
        z, resolution_m=res, points_xy=(5.0, 5.0), azimuths_deg=az, min_distance_m=100.0
    )
    d = 400.0 - 5.0
    expected = math.degrees(math.atan((20.0 - d * d / (2 * MOON_RADIUS_M)) / d))
    assert float(mask.elevation_deg(90.0)) == pytest.approx(expected, abs=0.02)
    # Level ground curving away: highest at the nearest sample, 100 m, -d / (2 R).
    assert float(mask.elevation_deg(270.0)) == pytest.approx(
        math.degrees(-100.0 / (2 * MOON_RADIUS_M)), rel=1e-3
    )
    # Over an azimuth range the ridge is farther away: lower.
    assert float(mask.elevation_deg(60.0)) < float(mask.elevation_deg(80.0)) < expected
    # Gridded: profiles per coarse cell of a local site (its origin 5 m east of the
    # regional centre); the eastern cells are closer to the ridge, so see it higher.
    grid = HorizonMask.from_dem_grid(
        z,
        resolution_m=res,
        bounds=(-100.0, -50.0, 100.0, 50.0),
        cells=(1, 2),
        azimuths_deg=az,
        origin_xy=(5.0, 0.0),
    )
    west, east = grid.elevation_deg(90.0)[0]
    d_w, d_e = 400.0 - (5.0 - 50.0), 400.0 - (5.0 + 50.0)
    assert west == pytest.approx(math.degrees(math.atan(20.0 / d_w)), abs=0.05)
    assert east == pytest.approx(math.degrees(math.atan(20.0 / d_e)), abs=0.05)
    el = horizon_profile(
        z, resolution_m=res, points_xy=[(5.0, 5.0)], azimuths_deg=[90.0], min_distance_m=500.0
    )
    assert el[0, 0] == -90.0  # nothing beyond the ridge inside the DEM
    with pytest.raises(ConfigError):
        HorizonMask((10.0, 5.0), [1.0, 2.0])


# ------------------------------------------------------------------- horizon angles
def test_horizon_angles_of_a_wall_include_curvature_and_interpolate_in_azimuth():
    res, H = 20.0, 40.0
    z = np.zeros((12, 140))
    z[:, 5] = H
    h = horizon_angles(
        z, azimuth_deg=270.0, resolution_m=res, elevation_range_deg=(-1, 30), resolution_deg=0.1
    )
    d = (np.arange(6, 140) - 5) * res
    expected = np.arctan((H - d * d / (2 * MOON_RADIUS_M)) / d)
    np.testing.assert_allclose(
        h[6, 6:], np.clip(expected, math.radians(-1), math.radians(30)), atol=math.radians(0.002)
    )
    flat = np.arctan(H / d)
    # Curvature lowers the horizon by d / 2R: 0.044 deg at 2.7 km (20x the tolerance).
    assert math.degrees(flat[-1] - h[6, -1]) > 0.04
    assert np.all(h[:, 0] == np.float32(math.radians(-1)))  # no caster: the band's floor
    assert np.all(h[:, 1:5] == 0)  # level ground: the surface leaves the cell level
    # A field at two azimuths interpolates; its lightmap equals the direct one.
    f = HorizonField.compute(
        z,
        azimuths_deg=[265.0, 275.0],
        resolution_m=res,
        elevation_range_deg=(0.0, 6.0),
        resolution_deg=0.05,
    )
    mid = 0.5 * (f.elevations_rad[0] + f.elevations_rad[1])
    np.testing.assert_allclose(f.at(270.0), mid, atol=1e-7)
    assert not np.allclose(f.elevations_rad[0], f.elevations_rad[1])
    with pytest.raises(OutOfRangeError):
        f.at(280.0)
    zf = _fractal(n=64, res=0.05)
    h = horizon_angles(zf, azimuth_deg=250.0, resolution_m=0.05, elevation_range_deg=(2, 8))
    direct = lm.lightmap(
        zf, resolution_m=0.05, sun_azimuth_deg=250.0, sun_elevation_deg=5.0, horizon_mask=NO_OUTSIDE
    )
    via = lm.lightmap_from_horizon(
        h, sun_azimuth_deg=250.0, sun_elevation_deg=5.0, horizon_mask=NO_OUTSIDE
    )
    assert np.abs(via - direct).max() < 0.01
    with pytest.raises(OutOfRangeError, match="elevation range"):
        lm.lightmap_from_horizon(f, sun_azimuth_deg=270.0, sun_elevation_deg=5.9)


def test_sweep_orientation_covers_all_octants():
    for az in np.arange(0.0, 360.0, 22.5):
        o = sweep_orientation(az, (30, 50))
        assert abs(o.sigma) <= 1.0 and o.step_px == pytest.approx(math.hypot(1, o.sigma))
        a = np.arange(1500).reshape(30, 50)
        np.testing.assert_array_equal(o.uncanon(o.canon(a)), a)
        r = o.rect_to_canon(3, 9, 10, 25)
        assert o.rect_from_canon(*r) == (3, 9, 10, 25)


# ----------------------------------------------------------------- series, interpolation
def test_hourly_series_and_linear_interpolation():
    z = _wall(nr=20, nc=60)
    sun = {0.0: (270.0, 6.0), 3600.0: (270.5, 6.5), 7200.0: (271.0, 7.0)}
    s = lm.lightmap_series(
        z,
        times=[0.0, 3600.0, 7200.0],
        sun_az_el_at=lambda t: sun[t],
        resolution_m=0.1,
        horizon_mask=NO_OUTSIDE,
    )
    assert s.maps.shape == (3, 20, 60) and s.maps.dtype == np.float32
    assert s.sun_elevation_deg == (6.0, 6.5, 7.0)
    assert not np.array_equal(s.maps[0], s.maps[2])  # the shadow shortens
    np.testing.assert_array_equal(lm.interpolate_lightmap(s, 0.0), s.maps[0])
    np.testing.assert_array_equal(s.at(7200.0), s.maps[2])
    mid = lm.interpolate_lightmap(s, 5400.0)
    np.testing.assert_allclose(mid, 0.5 * (s.maps[1] + s.maps[2]), atol=1e-7)
    q = lm.interpolate_lightmap(s, 900.0)
    np.testing.assert_allclose(q, 0.75 * s.maps[0] + 0.25 * s.maps[1], atol=1e-7)
    with pytest.raises(OutOfRangeError, match="outside"):
        lm.interpolate_lightmap(s, 7300.0)
    with pytest.raises(ConfigError):
        lm.LightmapSeries((0.0, 0.0), np.zeros((2, 2, 2)))


def test_bad_values_are_reported():
    z = np.zeros((8, 8))
    with pytest.raises(ConfigError, match="resolution_m"):
        lm.lightmap(z, sun_azimuth_deg=0.0, sun_elevation_deg=5.0)
    with pytest.raises(OutOfRangeError, match="sun_elevation_deg"):
        lm.lightmap(z, resolution_m=1.0, sun_azimuth_deg=0.0, sun_elevation_deg=95.0)
    with pytest.raises(ConfigError, match="limb"):
        lm.lightmap(z, resolution_m=1.0, sun_azimuth_deg=0.0, sun_elevation_deg=5.0, limb="x")
    with pytest.raises(OutOfRangeError, match="tile_px"):
        lm.lightmap(z, resolution_m=1.0, sun_azimuth_deg=0.0, sun_elevation_deg=5.0, tile_px=4)


# ------------------------------------------------------------------------------- CLI
def _dem_file(tmp_path):
    x, y = lonlat_to_xy(30.0, -89.5, crs=moon_south_polar_stereographic())
    z = _wall(nr=30, nc=40).astype(np.float32)
    hf = Heightfield.from_array(z, resolution_m=0.1, origin_xy=(float(x), float(y)))
    path = tmp_path / "dem.tif"
    hf.to_geotiff(path)
    return path, hf


def _parse(argv):
    p = argparse.ArgumentParser()
    lm.add_arguments(p)
    return p.parse_args(argv)


def test_cli_writes_a_georeferenced_lightmap(tmp_path, capsys):
    path, hf = _dem_file(tmp_path)
    out = tmp_path / "lm.tif"
    argv = [str(path), "--out", str(out), "--sun-az", "270", "--sun-el", "8", "--no-progress"]
    assert lm.run_cli(_parse(argv)) == 0
    with rasterio.open(out) as ds, rasterio.open(path) as src:
        assert ds.dtypes == ("float32",) and ds.crs == src.crs
        assert ds.transform == src.transform == hf.transform
        a = ds.read(1)
    ref = lm.lightmap(hf, sun_azimuth_deg=270.0, sun_elevation_deg=8.0)
    np.testing.assert_array_equal(a, ref)
    assert "Sun azimuth 270.000" in capsys.readouterr().out
    out2 = tmp_path / "tiled.tif"  # tiled path (dask store into a GeoTiffWriter)
    assert lm.run_cli(_parse([*argv[:2], str(out2), *argv[3:], "--tile", "16"])) == 0
    with rasterio.open(out2) as ds:
        np.testing.assert_array_equal(ds.read(1), ref)
    with pytest.raises(ConfigError, match="--utc"):
        lm.run_cli(_parse([str(path), "--out", str(out)]))


def test_cli_utc_turns_the_ephemeris_azimuth_into_grid_azimuth(tmp_path, monkeypatch):
    from lunar_drake.ephemeris import sun_earth

    path, hf = _dem_file(tmp_path)
    fake = types.SimpleNamespace(sun_azimuth_deg=248.0, sun_elevation_deg=6.0)
    monkeypatch.setattr(sun_earth, "sun_earth_enu", lambda **kw: fake)
    az, el = lm.sun_in_grid_frame(hf, "2027-11-20T12:00:00")
    # Site at lon 30 E on the south-polar grid: grid north is at true azimuth -30 deg.
    gamma = sun_earth.meridian_convergence_deg(sun_earth.SiteLocation(-89.5, 30.0))
    assert gamma == pytest.approx(-30.0)
    assert az == pytest.approx(248.0 - gamma, abs=1e-6) and el == 6.0
    out = tmp_path / "lm.tif"
    assert lm.run_cli(_parse([str(path), "--out", str(out), "--utc", "x", "--no-progress"])) == 0
    # Without the ephemeris module: a ConfigError naming the way out.
    monkeypatch.setitem(sys.modules, "lunar_drake.ephemeris.sun_earth", None)
    with pytest.raises(ConfigError, match="--sun-az"):
        lm.sun_in_grid_frame(hf, "2027-11-20T12:00:00")
