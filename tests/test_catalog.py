"""Crater/rock size-frequency laws and site catalogs (lunar_drake.terrain.sfd, .catalog)."""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial import cKDTree

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.terrain import catalog as catalog_mod
from lunar_drake.terrain.catalog import (
    CatalogParams,
    CraterCatalog,
    EjectaMap,
    RockCatalog,
    synthesize_catalogs,
)
from lunar_drake.terrain.grid import GridSpec
from lunar_drake.terrain.sfd import (
    VIPER_BREAK_M,
    CraterSFD,
    RockSFD,
    cumulative_density,
    expected_count,
    remove_existing,
    sample_diameters,
)

# A ~102 m site: ~3300 Trask craters >= 0.5 m, ~200 of them ejecta craters.
SITE = GridSpec(2048, 2048, 0.05)
# A ~205 m site for the SFD checks: ~13000 Trask craters >= 0.5 m, ~16000
# Golombek-Rapp (k = 0.02) rocks >= 0.1 m (fitted slopes within ~0.025 at 1 sigma).
BIG_SITE = GridSpec(4096, 4096, 0.05)
NO_BURIAL = dict(rock_burial_probability_per_step=0.0, crater_burial=False)


# ----------------------------------------------------------------------------- helpers


def _check_bins(d, sfd, *, area, d_min, d_max, min_expected=5.0):
    """Counts per factor-of-2 bin [d_min 2^k, d_min 2^(k+1)) within 3 Poisson sigma."""
    n_bins = math.ceil(math.log2(d_max / d_min))
    checked = 0
    for k in range(n_bins):
        a, b = d_min * 2.0**k, min(d_min * 2.0 ** (k + 1), d_max)
        n_a, n_b = sfd.cumulative_density(np.array([a, b]))
        inside = (d >= a) & ((d < b) if b < d_max else (d <= b))
        expected = area * (n_a - n_b)
        if expected < min_expected:
            continue
        obs = int(np.count_nonzero(inside))
        assert abs(obs - expected) <= 3.0 * math.sqrt(expected), (k, a, b, obs, expected)
        checked += 1
    assert checked >= 2
    return checked


def _fitted_slope(d, sfd, *, area, lo, hi, d_max, min_count=20):
    """Least-squares cumulative slope of a sample on [lo, hi] and of the law itself.

    Log counts are weighted by sqrt(count) (their Poisson precision); the truncation at
    ``d_max`` is undone by adding back the expected count above it.
    """
    d = np.sort(d)
    pts = np.geomspace(lo, hi, 25)
    n_emp = len(d) - np.searchsorted(d, pts, side="left")
    tail = area * float(sfd.cumulative_density(d_max))
    use = n_emp >= min_count
    assert use.sum() >= 8, (pts, n_emp)
    x = np.log10(pts[use])
    w = np.sqrt(n_emp[use])
    emp = np.polyfit(x, np.log10(n_emp[use] + tail), 1, w=w)[0]
    law = np.polyfit(x, np.log10(area * sfd.cumulative_density(pts[use])), 1, w=w)[0]
    return emp, law


def _params(**kw):
    return CatalogParams(**kw)


# ----------------------------------------------------------------------------- sfd laws


def test_trask_and_viper_values():
    trask = CraterSFD()
    assert trask.cumulative_density(1.0) == pytest.approx(10**-1.1, rel=1e-12)
    assert trask.cumulative_density(10.0) == pytest.approx(10**-1.1 / 100, rel=1e-12)
    viper = CraterSFD(law="viper")
    # 29174 D^-1.92 per km^2 up to 80 m, 156228 D^-2.389 above (converted to per m^2).
    assert viper.cumulative_density(10.0) == pytest.approx(29174e-6 * 10**-1.92, rel=1e-12)
    assert viper.cumulative_density(80.0) == pytest.approx(29174e-6 * 80**-1.92, rel=1e-12)
    assert viper.cumulative_density(200.0) == pytest.approx(156228e-6 * 200**-2.389, rel=1e-12)
    assert cumulative_density(np.array([1.0]), sfd=trask)[0] == trask.cumulative_density(1.0)


def test_golombek_rapp_density_matches_quadrature():
    for k in (0.002, 0.02, 0.2):
        sfd = RockSFD(k=k)
        q = 1.79 + 0.152 / k
        assert sfd.q == pytest.approx(q)
        for d in (0.05, 0.1, 0.4, 1.0):
            num = integrate.quad(
                lambda s, q=q, k=k: k * q * np.exp(-q * s) / (np.pi * s * s / 4),
                d,
                np.inf,
                epsabs=0,
                epsrel=1e-11,
            )[0]
            assert sfd.cumulative_density(d) == pytest.approx(num, rel=1e-8)
        # fractional area F(D) = k exp(-qD) is the area integral of the number density
        area = integrate.quad(
            lambda s, sfd=sfd: np.pi * s * s / 4 * sfd.differential_density(s), 0.1, np.inf
        )[0]
        assert sfd.cumulative_fractional_area(0.1) == pytest.approx(area, rel=1e-8)


@pytest.mark.parametrize(
    "sfd",
    [
        CraterSFD(),
        CraterSFD(law="viper"),
        RockSFD(k=0.01),
        RockSFD(law="powerlaw", coefficient=0.1, exponent=-2.5),
    ],
)
def test_inverse_cumulative_inverts(sfd):
    d = (
        np.geomspace(0.11, 150.0, 200)
        if isinstance(sfd, CraterSFD)
        else np.geomspace(0.11, 1.9, 200)
    )
    if sfd.law == "viper":
        d = d[np.abs(d - VIPER_BREAK_M) > 1e-6]
    lo, hi = float(d[0]) * 0.9, float(d[-1]) * 1.1
    back = sfd.inverse_cumulative(sfd.cumulative_density(d), d_min_m=lo, d_max_m=hi)
    np.testing.assert_allclose(back, d, rtol=1e-9)


def test_viper_step_is_sampled_as_craters_of_80_m():
    viper = CraterSFD(law="viper")
    n_left = viper.cumulative_density(VIPER_BREAK_M)
    n_right = viper.cumulative_density(VIPER_BREAK_M * (1 + 1e-12))
    assert n_left > 1.4 * n_right  # the published pieces do not meet
    inside_step = np.linspace(n_right * 1.0001, n_left * 0.9999, 7)
    d = viper.inverse_cumulative(inside_step, d_min_m=1.0, d_max_m=1000.0)
    np.testing.assert_array_equal(d, VIPER_BREAK_M)
    area = 2e8
    s = sample_diameters(
        rng.generator(5, "t"), sfd=viper, area_m2=area, d_min_m=40.0, d_max_m=1000.0
    )
    expected = area * (n_left - n_right)
    obs = int(np.count_nonzero(s == VIPER_BREAK_M))
    assert abs(obs - expected) <= 3 * math.sqrt(expected)


# ----------------------------------------------------------------------------- crater catalogs


def test_trask_catalog_follows_sfd():
    params = _params(rock_sfd_background=None, rock_sfd_ejecta=None)
    craters, _, _ = synthesize_catalogs(grid=BIG_SITE, seed=11, params=params)
    area = BIG_SITE.area_m2
    d_max = params.crater_d_max_for(BIG_SITE)
    # automatic d_max: the crater expected once in the site, N(>=D) A = 1
    assert CraterSFD().cumulative_density(d_max) * area == pytest.approx(1.0)
    d = craters.diameter_m
    assert d.min() >= 0.5 and d.max() <= d_max
    sfd = CraterSFD()
    _check_bins(d, sfd, area=area, d_min=0.5, d_max=d_max)
    emp, law = _fitted_slope(d, sfd, area=area, lo=0.5, hi=d_max, d_max=d_max)
    assert law == pytest.approx(-2.0)
    assert abs(emp - (-2.0)) <= 0.1


def test_powerlaw_catalog_follows_sfd():
    sfd = CraterSFD(law="powerlaw", coefficient=0.05, exponent=-2.6)
    params = _params(
        crater_sfd=sfd, d_min_m=0.4, d_max_m=30.0, rock_sfd_background=None, rock_sfd_ejecta=None
    )
    craters, _, _ = synthesize_catalogs(grid=BIG_SITE, seed=3, params=params)
    d = craters.diameter_m
    area = BIG_SITE.area_m2
    _check_bins(d, sfd, area=area, d_min=0.4, d_max=30.0)
    emp, _ = _fitted_slope(d, sfd, area=area, lo=0.4, hi=30.0, d_max=30.0)
    assert abs(emp - (-2.6)) <= 0.1


def test_viper_pieces_follow_sfd():
    sfd = CraterSFD(law="viper")
    g = rng.generator(7, "test/viper")
    # small-crater piece, D <= 80 m
    area = 2e7
    d = sample_diameters(g, sfd=sfd, area_m2=area, d_min_m=5.0, d_max_m=VIPER_BREAK_M)
    _check_bins(d, sfd, area=area, d_min=5.0, d_max=VIPER_BREAK_M)
    emp, _ = _fitted_slope(d, sfd, area=area, lo=5.0, hi=VIPER_BREAK_M, d_max=VIPER_BREAK_M)
    assert abs(emp - (-1.92)) <= 0.1
    # large-crater piece, D > 80 m
    area = 5e9
    d = sample_diameters(g, sfd=sfd, area_m2=area, d_min_m=81.0, d_max_m=2000.0)
    _check_bins(d, sfd, area=area, d_min=81.0, d_max=2000.0)
    emp, _ = _fitted_slope(d, sfd, area=area, lo=81.0, hi=2000.0, d_max=2000.0)
    assert abs(emp - (-2.389)) <= 0.1
    # across the break, the bins (one holds the step at 80 m) still match the law
    area = 1e8
    d = sample_diameters(g, sfd=sfd, area_m2=area, d_min_m=10.0, d_max_m=1000.0)
    _check_bins(d, sfd, area=area, d_min=10.0, d_max=1000.0)


def test_sigma_log10_varies_count_between_seeds_only():
    sfd = CraterSFD(sigma_log10=0.3)
    counts = [
        len(sample_diameters(rng.generator(s, "t"), sfd=sfd, area_m2=1e4, d_min_m=1, d_max_m=50))
        for s in range(40)
    ]
    mean = expected_count(CraterSFD(), area_m2=1e4, d_min_m=1, d_max_m=50)
    # lognormal site factor: spread far beyond Poisson (sqrt(786) ~ 28)
    assert np.std(np.log10(counts)) == pytest.approx(0.3, abs=0.1)
    assert np.std(counts) > 5 * math.sqrt(mean)


def test_existing_craters_are_subtracted():
    existing = [(0.0, 0.0, 12.0), (5.0, 5.0, 3.0), (1.0, 2.0, 3.1), (-4.0, 3.0, 0.7)]
    # too small, too large, or centred outside the site: ignored
    out_of_range = [(0.0, 0.0, 0.3), (0.0, 0.0, 5000.0), (1000.0, 0.0, 12.0)]
    base = _params(rock_sfd_background=None, rock_sfd_ejecta=None)
    with_existing = dataclasses.replace(base, existing_craters=tuple(existing + out_of_range))
    c0, _, _ = synthesize_catalogs(grid=SITE, seed=2, params=base)
    c1, _, _ = synthesize_catalogs(grid=SITE, seed=2, params=with_existing)
    assert len(c0) - len(c1) == len(existing)
    # the removed craters are the sampled ones nearest in log-diameter, bin by bin
    removed = np.setdiff1d(c0.diameter_m, c1.diameter_m)
    assert removed.size == len(existing)
    for e in (12.0, 3.0, 3.1, 0.7):
        assert np.min(np.abs(np.log(removed / e))) < math.log(2.0)

    d = sample_diameters(rng.generator(1, "t"), sfd=CraterSFD(), area_m2=1e4, d_min_m=1, d_max_m=50)
    keep = remove_existing(d, existing_diameters_m=[3.0], d_min_m=1.0, d_max_m=50.0)
    (gone,) = np.flatnonzero(~keep)
    same_bin = d[(d >= 2.0) & (d < 4.0)]
    assert d[gone] == same_bin[np.argmin(np.abs(np.log(same_bin / 3.0)))]
    # an existing crater without a sampled counterpart in its bin removes nothing
    assert remove_existing([1.5, 1.6], existing_diameters_m=[7.0], d_min_m=1.0, d_max_m=50.0).all()


def test_crater_ages_order_and_freshness():
    params = _params(rock_sfd_background=None, rock_sfd_ejecta=None)
    craters, _, _ = synthesize_catalogs(grid=SITE, seed=4, params=params)
    assert np.all(np.diff(craters.age_yr) <= 0)  # oldest first
    life = params.crater_lifetime_yr(craters.diameter_m)
    assert np.all(craters.age_yr <= np.minimum(life, params.surface_age_yr))
    assert np.all((craters.freshness > 0) & (craters.freshness <= 1))
    # small craters: ages uniform over their lifetime, so age/lifetime is U(0, 1)
    small = craters.diameter_m < 2.0
    frac = craters.age_yr[small] / life[small]
    assert np.mean(frac) == pytest.approx(0.5, abs=0.03)
    assert np.mean(frac < 0.25) == pytest.approx(0.25, abs=0.03)
    # older craters are degraded (monotone in age / lifetime)
    order = np.argsort(frac)
    assert np.all(np.diff(craters.freshness[small][order]) <= 1e-12)
    # big craters live longer, so are older on average
    big = craters.diameter_m >= 8.0
    assert np.median(craters.age_yr[big]) > 3 * np.median(craters.age_yr[small])
    assert np.array_equal(craters.ejecta, craters.diameter_m >= params.ejecta_min_diameter_m)
    # centres lie in the site
    assert np.all(np.abs(craters.x_m) <= SITE.width_m / 2)
    assert np.all(np.abs(craters.y_m) <= SITE.height_m / 2)


# ----------------------------------------------------------------------------- rock catalogs


@pytest.mark.parametrize(
    "sfd",
    [RockSFD(k=0.02), RockSFD(law="powerlaw", coefficient=0.01, exponent=-2.2)],
    ids=["golombek_rapp", "powerlaw"],
)
def test_background_rocks_follow_sfd_without_burial(sfd):
    params = _params(rock_sfd_background=sfd, rock_sfd_ejecta=None, **NO_BURIAL)
    _, rocks, _ = synthesize_catalogs(grid=BIG_SITE, seed=9, params=params)
    assert np.all(rocks.population == 0)
    d = rocks.diameter_m
    assert d.min() >= 0.1 and d.max() <= 2.0
    area = BIG_SITE.area_m2
    _check_bins(d, sfd, area=area, d_min=0.1, d_max=2.0)
    emp, law = _fitted_slope(d, sfd, area=area, lo=0.1, hi=2.0, d_max=2.0)
    assert abs(emp - law) <= 0.1
    if sfd.law == "powerlaw":
        assert law == pytest.approx(-2.2)


def test_background_burial_is_compensated():
    sfd = RockSFD(k=0.02)
    params = _params(rock_sfd_background=sfd, rock_sfd_ejecta=None)  # burial on, compensated
    counts = [len(synthesize_catalogs(grid=SITE, seed=s, params=params)[1]) for s in range(4)]
    expected = expected_count(sfd, area_m2=SITE.area_m2, d_min_m=0.1, d_max_m=2.0)
    assert np.mean(counts) == pytest.approx(expected, rel=0.05)
    raw = dataclasses.replace(params, compensate_background_burial=False)
    raw_count = len(synthesize_catalogs(grid=SITE, seed=0, params=raw)[1])
    assert raw_count < 0.2 * expected  # regolith burial over 3.5 Gyr removes most rocks


def _density_2r(craters, rocks):
    tree = cKDTree(np.column_stack((rocks.x_m, rocks.y_m)))

    def density(i):
        r2 = craters.diameter_m[i]  # 2 crater radii
        return len(tree.query_ball_point([craters.x_m[i], craters.y_m[i]], r2)) / (np.pi * r2**2)

    return density


def _disk_inside(craters, grid):
    half = grid.width_m / 2
    return (np.abs(craters.x_m) + craters.diameter_m < half) & (
        np.abs(craters.y_m) + craters.diameter_m < half
    )


def test_ejecta_rocks_concentrate_around_fresh_large_craters():
    # A crater field 8x sparser than Trask (ejecta craters from 1 m), so that ejecta
    # blankets seldom overlap and each crater's own rocks can be seen.
    params = CatalogParams(
        crater_sfd=CraterSFD(law="powerlaw", coefficient=0.01, exponent=-2.0),
        d_min_m=1.0,
        ejecta_min_diameter_m=1.0,
    )
    craters, rocks, emap = synthesize_catalogs(grid=BIG_SITE, seed=1, params=params)
    density = _density_2r(craters, rocks)
    inside = _disk_inside(craters, BIG_SITE)
    fresh_big = np.flatnonzero(craters.ejecta & inside & (craters.freshness > 0.8))
    biggest = fresh_big[np.argmax(craters.diameter_m[fresh_big])]
    assert craters.diameter_m[biggest] > 4.0
    site_mean = len(rocks) / BIG_SITE.area_m2
    assert density(biggest) > 5 * site_mean
    # craters of the same sizes: fresh ones are surrounded by more rocks than old ones
    sized = craters.ejecta & inside & (craters.diameter_m >= 2.0) & (craters.diameter_m < 12.0)
    fresh = [density(i) for i in np.flatnonzero(sized & (craters.freshness > 0.7))]
    old = [density(i) for i in np.flatnonzero(sized & (craters.freshness < 0.3))]
    assert len(fresh) >= 10 and len(old) >= 10
    assert np.mean(fresh) > 2 * np.mean(old)
    # the ejecta map is high at the crater and zero off the site and beyond every stencil
    assert emap.value_at(craters.x_m[biggest], craters.y_m[biggest]) > 0.3
    half = BIG_SITE.width_m / 2
    assert emap.value_at(half + 1.0, 0.0) == 0.0
    assert emap.values.dtype == np.float32
    xs, ys = (
        a.ravel() for a in np.meshgrid(np.linspace(-half, half, 64), np.linspace(-half, half, 64))
    )
    vals = emap.value_at(xs, ys)
    for i in np.flatnonzero(craters.ejecta):
        reach = params.ejecta_blanket_extent * craters.diameter_m[i] / 2 + emap.cell_m * 1.5
        vals = np.where(np.hypot(xs - craters.x_m[i], ys - craters.y_m[i]) < reach, 0.0, vals)
    assert np.all(vals == 0.0)


def test_default_site_ejecta_rocks_cluster_at_fresh_craters():
    craters, rocks, _ = synthesize_catalogs(grid=BIG_SITE, seed=2, params=CatalogParams())
    # the paper: polar background far sparser than ejecta
    assert np.count_nonzero(rocks.population == 1) > 2 * np.count_nonzero(rocks.population == 0)
    density = _density_2r(craters, rocks)
    inside = _disk_inside(craters, BIG_SITE)
    fresh = np.flatnonzero(craters.ejecta & inside & (craters.freshness > 0.9))
    biggest = fresh[np.argmax(craters.diameter_m[fresh])]
    assert density(biggest) > 2 * len(rocks) / BIG_SITE.area_m2


def test_ejecta_rock_count_matches_ejecta_map():
    # without burial and block cap, ejecta rocks in the site = N_ej(range) * integral of map
    params = CatalogParams(rock_sfd_background=None, ejecta_max_rock_coefficient=None, **NO_BURIAL)
    total, expected = 0, 0.0
    for seed in range(3):
        _, rocks, emap = synthesize_catalogs(grid=SITE, seed=seed, params=params)
        n_range = np.diff(params.rock_sfd_ejecta.cumulative_density([2.0, 0.1]))[0]
        expected += n_range * float(emap.values.sum(dtype=np.float64)) * emap.cell_m**2
        total += len(rocks)
    assert emap.values.shape == (512, 512)
    assert abs(total - expected) <= 3 * math.sqrt(expected) + 0.01 * expected


def test_ejecta_map_integral_matches_stencil():
    p = CatalogParams()
    m = catalog_mod._stencil(p).masses.sum()
    rho = np.linspace(0.0, p.ejecta_blanket_extent, 200001)
    w = catalog_mod.ejecta_weight(rho, params=p)
    assert np.trapezoid(w * 2 * np.pi * rho, rho) == pytest.approx(m, rel=1e-3)
    assert catalog_mod.ejecta_weight(1.0, params=p) == p.ejecta_rim_density
    assert catalog_mod.ejecta_weight(0.0, params=p) == p.ejecta_interior_density
    assert catalog_mod.ejecta_weight(2.4, params=p) == pytest.approx((2.4 / 1.2) ** -3)
    assert catalog_mod.ejecta_weight(3.01, params=p) == 0.0
    # a lone fresh crater: the cell-averaged map integrates to f * masses * R^2
    grid = GridSpec(400, 400, 0.1)
    emap = catalog_mod._ejecta_map(
        grid,
        p,
        catalog_mod._stencil(p),
        np.array([0.3]),
        np.array([-0.2]),
        np.array([6.0]),
        np.array([0.5]),
    )
    assert emap.values.sum() * emap.cell_m**2 == pytest.approx(0.5 * m * 9.0, rel=0.02)


def test_crater_burial_removes_rocks_inside_younger_rims():
    grid = GridSpec(600, 600, 0.05)
    base = _params(
        rock_sfd_background=RockSFD(k=0.05),
        rock_burial_probability_per_step=0.0,
        compensate_background_burial=False,
    )
    craters, kept, _ = synthesize_catalogs(grid=grid, seed=6, params=base)
    _, allr, _ = synthesize_catalogs(
        grid=grid, seed=6, params=dataclasses.replace(base, crater_burial=False)
    )
    assert len(kept) < len(allr)

    def covered(r):
        dx = r.x_m[:, None] - craters.x_m[None, :]
        dy = r.y_m[:, None] - craters.y_m[None, :]
        inside = np.hypot(dx, dy) <= craters.diameter_m[None, :] / 2
        younger = craters.age_yr[None, :] < r.age_yr[:, None]
        return np.any(inside & younger, axis=1)

    assert not covered(kept).any()
    cov = covered(allr)
    assert cov.sum() == len(allr) - len(kept)
    # the survivors are exactly the uncovered rocks, in the same (birth) order
    survivors = allr.subset(~cov)
    for name in ("x_m", "y_m", "diameter_m", "height_m", "population", "shape_index", "age_yr"):
        assert np.array_equal(getattr(survivors, name), getattr(kept, name)), name


def test_rock_attributes_and_order():
    params = CatalogParams(n_rock_shapes=16)
    _, rocks, _ = synthesize_catalogs(grid=SITE, seed=8, params=params)
    assert rocks.population.dtype == np.uint8 and rocks.shape_index.dtype == np.int16
    assert set(np.unique(rocks.population)) == {0, 1}
    assert rocks.shape_index.min() >= 0 and rocks.shape_index.max() <= 15
    assert len(np.unique(rocks.shape_index)) == 16
    ratio = rocks.height_m / rocks.diameter_m
    assert ratio.min() >= 0.3 and ratio.max() <= 0.7
    assert np.all(np.diff(rocks.age_yr) <= 0)  # birth order, oldest first
    assert np.all(np.abs(rocks.x_m) <= SITE.width_m / 2)
    assert np.all(np.abs(rocks.y_m) <= SITE.height_m / 2)
    # ejecta rocks are never larger than the block cap of a crater of the site
    ej = rocks.population == 1
    assert rocks.diameter_m[ej].max() <= params.rock_d_max_m


# ----------------------------------------------------------------------------- determinism


def _all_arrays(craters, rocks, emap):
    out = [getattr(craters, f.name) for f in dataclasses.fields(craters)]
    out += [getattr(rocks, f.name) for f in dataclasses.fields(rocks)]
    return [*out, emap.values]


def test_same_seed_same_catalogs_different_seed_differs():
    params = CatalogParams()
    a = _all_arrays(*synthesize_catalogs(grid=SITE, seed=21, params=params))
    b = _all_arrays(*synthesize_catalogs(grid=SITE, seed=21, params=params))
    c = _all_arrays(*synthesize_catalogs(grid=SITE, seed=22, params=params))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    n_crater_fields = len(dataclasses.fields(CraterCatalog))
    assert not np.array_equal(a[0], c[0])  # crater x
    assert not np.array_equal(a[2], c[2])  # crater diameters
    assert not np.array_equal(a[n_crater_fields], c[n_crater_fields])  # rock x


def test_progress_callback_reports_stages():
    seen = []
    synthesize_catalogs(
        grid=GridSpec(200, 200, 0.05),
        seed=0,
        params=CatalogParams(),
        progress=lambda s, f: seen.append((s, f)),
    )
    assert seen[0] == ("craters", 0.0) and seen[-1] == ("done", 1.0)


# ----------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("make", "exc", "text"),
    [
        (lambda: CraterSFD(law="lunar"), ConfigError, "'lunar'"),
        (lambda: RockSFD(law="boulders"), ConfigError, "'boulders'"),
        (lambda: RockSFD(k=1.5), OutOfRangeError, "1.5"),
        (lambda: RockSFD(k=0.0), OutOfRangeError, "0.0"),
        (lambda: RockSFD(k=-0.1), OutOfRangeError, "-0.1"),
        (lambda: CraterSFD(law="powerlaw", coefficient=0.1, exponent=2.0), OutOfRangeError, "2.0"),
        (lambda: RockSFD(law="powerlaw", coefficient=0.1, exponent=0.5), OutOfRangeError, "0.5"),
        (
            lambda: CraterSFD(law="powerlaw", coefficient=-3.0, exponent=-2.0),
            OutOfRangeError,
            "-3.0",
        ),
        (lambda: CraterSFD(law="powerlaw"), ConfigError, "None"),
        (lambda: CraterSFD(law="trask", coefficient=0.1), ConfigError, "0.1"),
        (lambda: CraterSFD(sigma_log10=-0.2), OutOfRangeError, "-0.2"),
        (lambda: CatalogParams(d_min_m=-0.5), OutOfRangeError, "-0.5"),
        (lambda: CatalogParams(d_min_m=5.0, d_max_m=2.0), OutOfRangeError, "2.0"),
        (lambda: CatalogParams(d_min_m=2.0, d_max_m=2.0), OutOfRangeError, "2.0"),
        (lambda: CatalogParams(rock_d_min_m=-0.1), OutOfRangeError, "-0.1"),
        (lambda: CatalogParams(rock_d_min_m=3.0), OutOfRangeError, "2.0"),
        (lambda: CatalogParams(rock_burial_probability_per_step=1.5), OutOfRangeError, "1.5"),
        (lambda: CatalogParams(n_time_steps=0), OutOfRangeError, "0"),
        (lambda: CatalogParams(ejecta_blanket_extent=1.1), OutOfRangeError, "1.1"),
        (lambda: CatalogParams(min_freshness=0.0), OutOfRangeError, "0.0"),
        (lambda: CatalogParams(existing_craters=((0.0, 0.0, -4.0),)), OutOfRangeError, "-4.0"),
        (lambda: CatalogParams(crater_sfd="trask"), ConfigError, "'trask'"),
        (
            lambda: CatalogParams(rock_height_ratio_min=0.8, rock_height_ratio_max=0.4),
            OutOfRangeError,
            "0.4",
        ),
        (
            lambda: sample_diameters(
                rng.generator(0, "t"), sfd=CraterSFD(), area_m2=1.0, d_min_m=-1.0, d_max_m=2.0
            ),
            OutOfRangeError,
            "-1.0",
        ),
        (
            lambda: sample_diameters(
                rng.generator(0, "t"), sfd=CraterSFD(), area_m2=1.0, d_min_m=3.0, d_max_m=2.0
            ),
            OutOfRangeError,
            "2.0",
        ),
        (
            lambda: expected_count(CraterSFD(), area_m2=1.0, d_min_m=2.0, d_max_m=2.0),
            OutOfRangeError,
            "2.0",
        ),
        (
            lambda: expected_count(CraterSFD(), area_m2=-5.0, d_min_m=1.0, d_max_m=2.0),
            OutOfRangeError,
            "-5.0",
        ),
    ],
)
def test_bad_values_raise_with_value(make, exc, text):
    with pytest.raises(exc) as info:
        make()
    assert text in str(info.value)


def test_errors_are_value_errors():
    with pytest.raises(ValueError):
        RockSFD(k=2.0)


# ----------------------------------------------------------------------------- containers, CSV


def _small_catalogs():
    params = CatalogParams(rock_sfd_background=RockSFD(k=0.05))
    return synthesize_catalogs(grid=GridSpec(400, 400, 0.05), seed=5, params=params)


def test_subset_and_in_box_preserve_order():
    craters, rocks, _ = _small_catalogs()
    assert len(craters) > 100 and len(rocks) > 100
    sub = craters.in_box(-2.0, 3.0, -1.0, 4.0, margin_fn=lambda d: 0.75 * d)
    m = 0.75 * craters.diameter_m
    expect = (
        (craters.x_m + m >= -2.0)
        & (craters.x_m - m <= 3.0)
        & (craters.y_m + m >= -1.0)
        & (craters.y_m - m <= 4.0)
    )
    assert 0 < len(sub) < len(craters)
    assert np.array_equal(sub.x_m, craters.x_m[expect])
    assert np.all(np.diff(sub.age_yr) <= 0)
    # default margin: half the diameter
    rsub = rocks.in_box(0.0, 5.0, 0.0, 5.0)
    rm = rocks.diameter_m / 2
    rexp = (
        (rocks.x_m + rm >= 0)
        & (rocks.x_m - rm <= 5)
        & (rocks.y_m + rm >= 0)
        & (rocks.y_m - rm <= 5)
    )
    assert np.array_equal(rsub.shape_index, rocks.shape_index[rexp])
    assert isinstance(rsub, RockCatalog) and isinstance(sub, CraterCatalog)
    idx = np.flatnonzero(expect)[::-1]  # integer indices are taken in catalog order too
    assert np.array_equal(craters.subset(idx).x_m, craters.x_m[expect])
    with pytest.raises(ConfigError):
        CraterCatalog(
            x_m=[0.0], y_m=[0.0, 1.0], diameter_m=[1.0], age_yr=[1.0], freshness=[1.0], ejecta=[0]
        )


def test_csv_columns_and_atomic_write(tmp_path, monkeypatch):
    craters, rocks, _ = _small_catalogs()
    depth = 0.1 * craters.diameter_m
    replaced = []
    real_replace = os.replace

    def spy(src, dst):
        assert os.path.dirname(os.fspath(src)) == os.path.dirname(os.fspath(dst))
        assert not os.path.exists(dst)  # the target appears only by the rename
        assert os.path.getsize(src) > 0
        replaced.append(os.fspath(dst))
        real_replace(src, dst)

    monkeypatch.setattr(catalog_mod.os, "replace", spy)
    craters.to_csv(tmp_path / "craters.csv", depth_m=depth)
    rocks.to_csv(tmp_path / "rocks.csv")
    assert replaced == [str(tmp_path / "craters.csv"), str(tmp_path / "rocks.csv")]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["craters.csv", "rocks.csv"]

    lines = (tmp_path / "craters.csv").read_text().splitlines()
    assert lines[0] == "x_m,y_m,diameter_m,depth_m,age_yr,freshness"
    assert len(lines) == len(craters) + 1
    table = np.loadtxt(tmp_path / "craters.csv", delimiter=",", skiprows=1, ndmin=2)
    np.testing.assert_allclose(table[:, 2], craters.diameter_m, rtol=1e-8)
    np.testing.assert_allclose(table[:, 3], depth, rtol=1e-8)
    np.testing.assert_allclose(table[:, 5], craters.freshness, rtol=1e-8)

    lines = (tmp_path / "rocks.csv").read_text().splitlines()
    assert lines[0] == "x_m,y_m,diameter_m,height_m,population"
    assert len(lines) == len(rocks) + 1
    words = [ln.rsplit(",", 1)[1] for ln in lines[1:]]
    assert set(words) <= {"background", "ejecta"}
    assert words.count("ejecta") == int(np.sum(rocks.population == 1))

    # a failed write leaves neither the target nor a temporary file
    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(catalog_mod.os, "replace", boom)
    with pytest.raises(OSError):
        rocks.to_csv(tmp_path / "rocks2.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["craters.csv", "rocks.csv"]
    with pytest.raises(ConfigError):
        craters.to_csv(tmp_path / "c.csv", depth_m=depth[:-1])


def test_ejecta_map_value_at_cells():
    emap = EjectaMap(
        values=np.arange(6, dtype=np.float32).reshape(2, 3), cell_m=2.0, x_min=-3.0, y_max=2.0
    )
    # row 0 is north: (x, y) = (-2, 1) is cell (0, 0); (2.9, -1.9) is cell (1, 2)
    np.testing.assert_array_equal(emap.value_at([-2.0, 2.9, 0.0], [1.0, -1.9, 1.0]), [0, 5, 1])
    np.testing.assert_array_equal(emap.value_at([-3.1, 3.1, 0.0], [0.0, 0.0, 2.1]), [0, 0, 0])
