"""Tests for lunar_drake.terrain.craters: profile shape, plane fit, stamping, tiling."""

from __future__ import annotations

import numpy as np
import pytest

from lunar_drake.errors import OutOfRangeError
from lunar_drake.terrain import craters as cr
from lunar_drake.terrain.craters import (
    CraterShapeParams,
    crater_extent_m,
    crater_planes,
    crater_profile,
    depth_ratio,
    rim_height_ratio,
    stamp_craters,
)
from lunar_drake.terrain.grid import GridSpec

P = CraterShapeParams()


def _stamp_one(diameter, freshness, *, res, surface=lambda x, y: 0.0 * x, centre=(0.0, 0.0)):
    """Stamp one crater centred on a pixel centre; returns (x, y, z_before, z_after, plane)."""
    half = int(np.ceil(crater_extent_m(diameter, params=P) / res)) + 3
    n = 2 * half + 1
    x = centre[0] + (np.arange(n) - half) * res
    y = centre[1] + (half - np.arange(n)) * res
    z0 = np.broadcast_to(surface(x[None, :], y[:, None]), (n, n)).astype(np.float32)
    planes = crater_planes(
        surface, x_m=[centre[0]], y_m=[centre[1]], diameter_m=[diameter], params=P
    )
    z = z0.copy()
    stamp_craters(
        z,
        x=x,
        y=y,
        craters_x=[centre[0]],
        craters_y=[centre[1]],
        diameters=[diameter],
        freshness=[freshness],
        planes=planes,
        params=P,
    )
    return x, y, z0, z, planes[0]


def _measure(diameter, freshness, res=0.02):
    """(rim crest - floor) / D and rim crest above the plane / D of a stamped crater."""
    _, _, _, z, _ = _stamp_one(diameter, freshness, res=res)
    crest = float(z.max())
    floor = float(z.min())
    return (crest - floor) / diameter, crest / diameter


# ------------------------------------------------------------------------ shape / profile


def test_fresh_stamped_crater_has_configured_depth_and_rim_height():
    d_ratio, h_ratio = _measure(10.0, 1.0)
    assert d_ratio == pytest.approx(P.depth_ratio_fresh, rel=0.02)
    assert h_ratio == pytest.approx(P.rim_height_ratio_fresh, rel=0.02)
    # and the floor lies d - h below the plane (Pike's d is rim crest to floor)
    _, _, _, z, _ = _stamp_one(10.0, 1.0, res=0.02)
    assert float(z.min()) == pytest.approx(
        -(P.depth_ratio_fresh - P.rim_height_ratio_fresh) * 10.0, rel=1e-3
    )


def test_ratio_functions_endpoints_and_monotone():
    assert depth_ratio(1.0, params=P) == pytest.approx(P.depth_ratio_fresh)
    assert rim_height_ratio(1.0, params=P) == pytest.approx(P.rim_height_ratio_fresh)
    assert depth_ratio(0.0, params=P) == pytest.approx(P.depth_ratio_degraded)
    assert rim_height_ratio(0.0, params=P) == pytest.approx(P.rim_height_ratio_degraded)
    f = np.linspace(1.0, 0.0, 11)
    assert np.all(np.diff(depth_ratio(f, params=P)) < 0)
    assert np.all(np.diff(rim_height_ratio(f, params=P)) < 0)


def test_depth_and_rim_height_fall_as_freshness_falls():
    values = [1.0, 0.8, 0.6, 0.4, 0.2, 0.0]
    measured = np.array([_measure(6.0, f, res=0.03) for f in values])
    assert np.all(np.diff(measured[:, 0]) < 0), measured
    assert np.all(np.diff(measured[:, 1]) < 0), measured
    expect_d = [depth_ratio(f, params=P) for f in values]
    expect_h = [rim_height_ratio(f, params=P) for f in values]
    np.testing.assert_allclose(measured[:, 0], expect_d, rtol=0.02)
    np.testing.assert_allclose(measured[:, 1], expect_h, rtol=0.03)


@pytest.mark.parametrize("freshness", [0.0, 0.37, 1.0])
def test_profile_extrema_and_monotone_sides(freshness):
    diameter = 8.0
    radius = diameter / 2
    r = np.linspace(0.0, crater_extent_m(diameter, params=P), 20001)
    dz = crater_profile(r, diameter_m=diameter, freshness=freshness, params=P)
    d = depth_ratio(freshness, params=P) * diameter
    h = rim_height_ratio(freshness, params=P) * diameter
    assert dz[0] == pytest.approx(h - d, abs=1e-12)
    assert dz.max() == pytest.approx(h, abs=1e-12)
    assert r[np.argmax(dz)] == pytest.approx(radius, abs=r[1])
    inside = r <= radius
    assert np.all(np.diff(dz[inside]) >= -1e-12)
    assert np.all(np.diff(dz[~inside]) <= 1e-12)
    assert np.all(dz[~inside] >= 0.0)


def test_profile_pieces_join_c0_and_c1():
    freshness = np.array([0.0, 0.25, 0.5, 0.9, 1.0])
    diameter = np.array([0.7, 3.0, 10.0, 40.0, 90.0])
    bowl, coef = cr._profile_pieces(diameter, freshness, P)
    powers = np.arange(4)
    breaks = np.stack(
        [
            bowl,
            np.ones_like(bowl),
            np.full_like(bowl, P.rim_flank_radii),
            np.full_like(bowl, P.ejecta_extent_radii),
        ],
        axis=1,
    )
    for i in range(diameter.size):
        for j in range(4):
            s = breaks[i, j]
            left, right = coef[i, j], coef[i, j + 1]
            v_left = float(np.sum(left * s**powers))
            v_right = float(np.sum(right * s**powers))
            g_left = float(np.sum(left[1:] * powers[1:] * s ** (powers[1:] - 1)))
            g_right = float(np.sum(right[1:] * powers[1:] * s ** (powers[1:] - 1)))
            assert abs(v_left - v_right) < 1e-9, (i, j)
            assert abs(g_left - g_right) < 1e-9, (i, j)
            if j == 0:  # bowl / inner-wall join is also C2
                c_left = 2 * left[2] + 6 * left[3] * s
                c_right = 2 * right[2] + 6 * right[3] * s
                assert abs(c_left - c_right) < 1e-9 * max(1.0, abs(c_left)), i
    # public function, finite differences either side of every join (slope in m/m)
    for i in range(diameter.size):
        radius = diameter[i] / 2
        for s in breaks[i]:
            r = s * radius
            eps = 1e-7 * radius
            pts = np.array([r - 2 * eps, r - eps, r, r + eps, r + 2 * eps])
            v = crater_profile(pts, diameter_m=diameter[i], freshness=freshness[i], params=P)
            assert abs(v[1] - v[3]) < 1e-6 * diameter[i]
            slope_left = (v[2] - v[0]) / (2 * eps)
            slope_right = (v[4] - v[2]) / (2 * eps)
            assert abs(slope_left - slope_right) < 1e-4


def test_outer_flank_meets_mcgetchin_power_law():
    # At the flank / ejecta join the profile takes the value and slope of h (r/R)^-3.
    diameter, freshness = 20.0, 0.7
    radius = diameter / 2
    h = rim_height_ratio(freshness, params=P) * diameter
    c = P.rim_flank_radii
    eps = 1e-6 * radius
    r = c * radius + np.array([-eps, 0.0, eps])
    v = crater_profile(r, diameter_m=diameter, freshness=freshness, params=P)
    assert v[1] == pytest.approx(h * c**-3, rel=1e-9)
    assert (v[2] - v[0]) / (2 * eps) == pytest.approx(-3 * h * c**-4 / radius, rel=1e-5)
    # beyond it the blanket tapers below the power law, to 0 at the extent
    rr = np.linspace(c, P.ejecta_extent_radii, 50)[1:] * radius
    blanket = crater_profile(rr, diameter_m=diameter, freshness=freshness, params=P)
    assert np.all(blanket <= h * (rr / radius) ** -3 + 1e-12)


def test_profile_zero_at_and_beyond_extent():
    for diameter in (0.5, 7.0, 90.0):
        ext = crater_extent_m(diameter, params=P)
        assert ext == pytest.approx(0.5 * P.ejecta_extent_radii * diameter)
        r = ext * np.array([1.0, 1.0 + 1e-12, 1.5, 10.0])
        assert np.all(crater_profile(r, diameter_m=diameter, freshness=0.8, params=P) == 0.0)
        assert crater_profile(ext * 0.99, diameter_m=diameter, freshness=0.8, params=P) > 0.0


def test_profile_broadcasts_and_is_symmetric():
    r = np.linspace(-6, 6, 13)[:, None]
    out = crater_profile(r, diameter_m=np.array([4.0, 5.0]), freshness=[0.3, 1.0], params=P)
    assert out.shape == (13, 2)
    np.testing.assert_array_equal(out, out[::-1])
    single = crater_profile(r[:, 0], diameter_m=5.0, freshness=1.0, params=P)
    np.testing.assert_array_equal(out[:, 1], single)


# ------------------------------------------------------------------------------- planes


def test_plane_fit_recovers_known_plane_in_one_call():
    rng = np.random.default_rng(3)
    n = 50
    xc = rng.uniform(-100, 100, n)
    yc = rng.uniform(-100, 100, n)
    dia = rng.uniform(0.5, 90, n)
    calls = []

    def surface(x, y):
        calls.append(x.size)
        return 12.5 - 0.3 * x + 0.07 * y

    planes = crater_planes(surface, x_m=xc, y_m=yc, diameter_m=dia, params=P)
    assert planes.shape == (n, 3) and planes.dtype == np.float64
    assert len(calls) == 1
    np.testing.assert_allclose(planes[:, 0], 12.5 - 0.3 * xc + 0.07 * yc, rtol=0, atol=1e-9)
    np.testing.assert_allclose(planes[:, 1], -0.3, rtol=0, atol=1e-12)
    np.testing.assert_allclose(planes[:, 2], 0.07, rtol=0, atol=1e-12)


def test_plane_fit_ignores_symmetric_curvature():
    # A paraboloid centred on the crater: the best plane is level, at the pattern mean.
    def bowl(x, y):
        return (x - 3.0) ** 2 + (y + 2.0) ** 2

    pl = crater_planes(bowl, x_m=[3.0], y_m=[-2.0], diameter_m=[4.0], params=P)[0]
    assert abs(pl[1]) < 1e-9 and abs(pl[2]) < 1e-9
    assert pl[0] > 0.0


# ----------------------------------------------------------------------------- stamping


def test_crater_on_slope_follows_fitted_plane():
    def slope(x, y):
        return 0.2 * x + 0.1 * y

    diameter, res, centre = 8.0, 0.02, (3.0, -5.0)
    x, y, z0, z, pl = _stamp_one(diameter, 1.0, res=res, surface=slope, centre=centre)
    np.testing.assert_allclose(pl, [slope(*centre), 0.2, 0.1], atol=1e-9)
    xx, yy = np.meshgrid(x - centre[0], y - centre[1])
    r = np.hypot(xx, yy)
    plane = slope(xx + centre[0], yy + centre[1])
    far = r >= crater_extent_m(diameter, params=P)
    assert np.array_equal(z[far], z0[far])
    rel = z.astype(np.float64) - plane
    h = rim_height_ratio(1.0, params=P) * diameter
    d = depth_ratio(1.0, params=P) * diameter
    # rim crest around the rim, in 16 azimuth sectors, sits at plane + h
    az = np.arctan2(yy, xx)
    ring = np.abs(r - diameter / 2) < 0.1 * diameter / 2
    for k in range(16):
        lo = -np.pi + k * np.pi / 8
        sector = ring & (az >= lo) & (az < lo + np.pi / 8)
        assert rel[sector].max() == pytest.approx(h, abs=0.01 * h + 1e-4)
    # absolute crest heights differ around the rim by the plane's relief
    assert z[ring].max() - z[ring].min() > 0.2 * diameter / 2
    # floor at plane - (d - h)
    centre_px = np.unravel_index(np.argmin(r), r.shape)
    assert rel[centre_px] == pytest.approx(-(d - h), abs=2e-4)


def test_ejecta_is_added_on_top_of_surroundings():
    rng = np.random.default_rng(5)
    res, diameter = 0.04, 6.0
    n = 201
    x = (np.arange(n) - 100) * res
    y = (100 - np.arange(n)) * res
    z0 = rng.normal(0.0, 0.05, (n, n)).astype(np.float32)
    z = z0.copy()
    stamp_craters(
        z,
        x=x,
        y=y,
        craters_x=[0.0],
        craters_y=[0.0],
        diameters=[diameter],
        freshness=[0.9],
        planes=[[0.0, 0.0, 0.0]],
        params=P,
    )
    r = np.hypot(x[None, :], y[:, None])
    radius = diameter / 2
    outer = (r >= P.blend_outer_radii * radius) & (r < P.ejecta_extent_radii * radius)
    dz = crater_profile(r[outer], diameter_m=diameter, freshness=0.9, params=P)
    assert np.all(dz > 0)
    np.testing.assert_allclose(z[outer] - z0[outer], dz, atol=2e-6)
    # inside the rim the rough surface is gone: z = plane + profile
    inner = r <= radius
    dzi = crater_profile(r[inner], diameter_m=diameter, freshness=0.9, params=P)
    np.testing.assert_allclose(z[inner], dzi, atol=2e-6)


def test_young_crater_obliterates_older_crater_inside_it():
    res = 0.04
    grid = GridSpec(400, 400, res)
    x, y = grid.pixel_centers(0, 0, 400, 400)
    base = np.full((400, 400), 1.0, np.float32)
    old = dict(cx=1.2, cy=-0.8, d=1.5, f=1.0)
    young = dict(cx=0.0, cy=0.0, d=10.0, f=0.9)
    planes = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])

    def run(order):
        z = base.copy()
        cs = [old, young] if order == "old-first" else [young, old]
        stamp_craters(
            z,
            x=x,
            y=y,
            craters_x=[c["cx"] for c in cs],
            craters_y=[c["cy"] for c in cs],
            diameters=[c["d"] for c in cs],
            freshness=[c["f"] for c in cs],
            planes=planes,
            params=P,
        )
        return z

    z_young_only = base.copy()
    stamp_craters(
        z_young_only,
        x=x,
        y=y,
        craters_x=[0.0],
        craters_y=[0.0],
        diameters=[10.0],
        freshness=[0.9],
        planes=planes[:1],
        params=P,
    )
    old_first, young_first = run("old-first"), run("young-first")
    near_old = np.hypot(x[None, :] - old["cx"], y[:, None] - old["cy"]) < old["d"] / 2
    # the old crater lies wholly inside the young one's rim: no trace of it remains
    np.testing.assert_allclose(old_first, z_young_only, atol=1e-5)
    # stamped the other way round, the small crater is clearly there
    assert np.max(np.abs(young_first - z_young_only)[near_old]) > 0.1 * old["d"]


def _random_scene(n_craters=200, size=256, res=0.04, seed=11):
    rng = np.random.default_rng(seed)
    grid = GridSpec(size, size, res)
    u = rng.random(n_craters)
    dmin, dmax = 0.3, 8.0
    dia = dmin * (1 - u * (1 - (dmin / dmax) ** 2)) ** -0.5  # cumulative power law -2
    half = 0.5 * grid.width_m
    cx = rng.uniform(-half - 1, half + 1, n_craters)
    cy = rng.uniform(-half - 1, half + 1, n_craters)
    fr = rng.random(n_craters)

    def low(xq, yq):
        return 0.3 * np.sin(0.4 * xq) + 0.05 * yq + 0.02 * xq * yq

    planes = crater_planes(low, x_m=cx, y_m=cy, diameter_m=dia, params=P)
    xa, ya = grid.pixel_centers(0, 0, size, size)
    base = (low(xa[None, :], ya[:, None]) + rng.normal(0, 0.01, (size, size))).astype(np.float32)
    return (
        grid,
        base,
        dict(craters_x=cx, craters_y=cy, diameters=dia, freshness=fr, planes=planes, params=P),
    )


def _stamp_window(grid, base, cat, r0, c0, h, w, *, embed=False):
    x, y = grid.pixel_centers(r0, c0, h, w)
    if embed:  # a non-contiguous view into a bigger array
        big = np.zeros((h + 6, w + 9), np.float32)
        z = big[3 : 3 + h, 4 : 4 + w]
        z[...] = base[r0 : r0 + h, c0 : c0 + w]
    else:
        z = base[r0 : r0 + h, c0 : c0 + w].copy()
    reach = crater_extent_m(cat["diameters"], params=P) + grid.resolution_m
    cx, cy = cat["craters_x"], cat["craters_y"]
    sel = np.flatnonzero(
        (cx + reach >= x[0]) & (cx - reach <= x[-1]) & (cy + reach >= y[-1]) & (cy - reach <= y[0])
    )
    sub = {k: (v[sel] if isinstance(v, np.ndarray) else v) for k, v in cat.items()}
    stamp_craters(z, x=x, y=y, **sub)
    return z


def test_tiling_is_bit_identical():
    grid, base, cat = _random_scene()
    whole = _stamp_window(grid, base, cat, 0, 0, 256, 256)
    assert not np.array_equal(whole, base)
    quads = np.empty_like(whole)
    for r0 in (0, 128):
        for c0 in (0, 128):
            quads[r0 : r0 + 128, c0 : c0 + 128] = _stamp_window(grid, base, cat, r0, c0, 128, 128)
    assert np.array_equal(whole.view(np.uint32), quads.view(np.uint32))
    odd = np.empty_like(whole)
    rows = [0, 37, 38, 101, 190, 256]
    cols = [0, 5, 77, 200, 201, 256]
    for i in range(len(rows) - 1):
        for j in range(len(cols) - 1):
            r0, r1, c0, c1 = rows[i], rows[i + 1], cols[j], cols[j + 1]
            odd[r0:r1, c0:c1] = _stamp_window(
                grid, base, cat, r0, c0, r1 - r0, c1 - c0, embed=(i + j) % 2 == 0
            )
    assert np.array_equal(whole.view(np.uint32), odd.view(np.uint32))


def test_batched_and_single_paths_agree(monkeypatch):
    grid, base, cat = _random_scene(seed=4)
    batched = _stamp_window(grid, base, cat, 0, 0, 256, 256)
    monkeypatch.setattr(cr, "_BATCH_MAX_SIDE", 0)
    single = _stamp_window(grid, base, cat, 0, 0, 256, 256)
    assert np.array_equal(batched.view(np.uint32), single.view(np.uint32))


def test_float64_tile_and_flipped_axes():
    grid, base, cat = _random_scene(n_craters=40, size=96, seed=2)
    x, y = grid.pixel_centers(0, 0, 96, 96)
    z32 = base.copy()
    stamp_craters(z32, x=x, y=y, **cat)
    z64 = base.astype(np.float64)
    stamp_craters(z64, x=x, y=y, **cat)
    np.testing.assert_allclose(z64, z32, atol=1e-5)
    zflip = base[::-1, ::-1].copy()
    stamp_craters(zflip, x=x[::-1], y=y[::-1], **cat)
    np.testing.assert_array_equal(zflip[::-1, ::-1], z32)


def test_craters_outside_tile_are_skipped_and_empty_catalog_is_noop():
    grid = GridSpec(64, 64, 0.05)
    x, y = grid.pixel_centers(0, 0, 64, 64)
    z = np.ones((64, 64), np.float32)
    stamp_craters(
        z,
        x=x,
        y=y,
        craters_x=[50.0],
        craters_y=[0.0],
        diameters=[2.0],
        freshness=[1.0],
        planes=[[1.0, 0.0, 0.0]],
        params=P,
    )
    stamp_craters(
        z,
        x=x,
        y=y,
        craters_x=[],
        craters_y=[],
        diameters=[],
        freshness=[],
        planes=np.zeros((0, 3)),
        params=P,
    )
    assert np.all(z == 1.0)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("depth_ratio_fresh", 0.0),
        ("depth_ratio_fresh", -0.1),
        ("depth_ratio_degraded", 0.0),
        ("depth_ratio_degraded", 0.2),
        ("rim_height_ratio_fresh", 0.2),
        ("rim_height_ratio_degraded", -0.01),
        ("bowl_fraction_fresh", 1.0),
        ("rim_flank_radii", 1.0),
        ("ejecta_extent_radii", 2.6),
        ("blend_outer_radii", 3.0),
        ("depth_ratio_fresh", float("nan")),
    ],
)
def test_bad_shape_params_raise_naming_field_and_value(field, value):
    with pytest.raises(OutOfRangeError) as info:
        CraterShapeParams(**{field: value})
    assert field in str(info.value)
    assert repr(value) in str(info.value)


def test_bad_call_values_raise_naming_value():
    with pytest.raises(OutOfRangeError, match=r"diameter_m.*-2\.0"):
        crater_profile(1.0, diameter_m=-2.0, freshness=0.5, params=P)
    with pytest.raises(OutOfRangeError, match=r"diameter_m.*0\.0"):
        crater_extent_m([1.0, 0.0], params=P)
    with pytest.raises(OutOfRangeError, match=r"freshness.*1\.5"):
        depth_ratio(1.5, params=P)
    with pytest.raises(OutOfRangeError, match=r"freshness.*-0\.1"):
        rim_height_ratio([0.5, -0.1], params=P)
    x = np.arange(8) * 0.1
    y = x[::-1].copy()
    z = np.zeros((8, 8), np.float32)
    with pytest.raises(OutOfRangeError, match=r"diameter_m\[1\].*-1\.0"):
        stamp_craters(
            z,
            x=x,
            y=y,
            craters_x=[0, 0],
            craters_y=[0, 0],
            diameters=[1.0, -1.0],
            freshness=[0.5, 0.5],
            planes=np.zeros((2, 3)),
            params=P,
        )
    with pytest.raises(OutOfRangeError, match=r"freshness\[0\].*2\.0"):
        stamp_craters(
            z,
            x=x,
            y=y,
            craters_x=[0],
            craters_y=[0],
            diameters=[1.0],
            freshness=[2.0],
            planes=np.zeros((1, 3)),
            params=P,
        )
    with pytest.raises(ValueError, match="planes"):
        stamp_craters(
            z,
            x=x,
            y=y,
            craters_x=[0],
            craters_y=[0],
            diameters=[1.0],
            freshness=[0.5],
            planes=np.zeros((1, 2)),
            params=P,
        )
