"""Tests for the Hapke / Lunar-Lambert photometry core (lunar_drake.render.hapke).

The reference values come from independent scalar implementations written here with the
``math`` module straight from the published equations (Hapke 1984 roughness with its two
explicit branches and the azimuth psi given directly, not recovered from g), and the exact
Chandrasekhar H-function obtained by iterating its integral equation.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render import hapke as hk

D = math.radians

# ----------------------------------------------------------------------------- references


def _H(x, w):
    """Hapke (2002) eq. 13 H-function, scalar."""
    gam = math.sqrt(1.0 - w)
    r0 = (1.0 - gam) / (1.0 + gam)
    return 1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) / 2.0 * math.log((1.0 + x) / x)))


def _p(g, b, c):
    return (1 + c) / 2 * (1 - b * b) / (1 - 2 * b * math.cos(g) + b * b) ** 1.5 + (1 - c) / 2 * (
        1 - b * b
    ) / (1 + 2 * b * math.cos(g) + b * b) ** 1.5


def _K(phi):
    if phi == 0:
        return 1.0
    x = 1.209 * phi ** (2 / 3)
    return -math.log(1 - x) / x


def _phase(i, e, psi):
    return math.acos(
        max(-1.0, min(1.0, math.cos(i) * math.cos(e) + math.sin(i) * math.sin(e) * math.cos(psi)))
    )


def _roughness_1984(i, e, psi, tb):
    """Hapke (1984) mu0e, mue, S written branch by branch (angles in rad, 0 < i, e)."""
    chi = 1 / math.sqrt(1 + math.pi * math.tan(tb) ** 2)

    def E1(x):
        return math.exp(-2 / math.pi / math.tan(tb) / math.tan(x))

    def E2(x):
        return math.exp(-1 / math.pi / math.tan(tb) ** 2 / math.tan(x) ** 2)

    def eta(x):
        return chi * (math.cos(x) + math.sin(x) * math.tan(tb) * E2(x) / (2 - E1(x)))

    f = math.exp(-2 * math.tan(psi / 2)) if psi < math.pi else 0.0
    s2 = math.sin(psi / 2) ** 2
    if i <= e:
        den = 2 - E1(e) - psi / math.pi * E1(i)
        mu0e = chi * (
            math.cos(i) + math.sin(i) * math.tan(tb) * (math.cos(psi) * E2(e) + s2 * E2(i)) / den
        )
        mue = chi * (math.cos(e) + math.sin(e) * math.tan(tb) * (E2(e) - s2 * E2(i)) / den)
        S = mue / eta(e) * math.cos(i) / eta(i) * chi / (1 - f + f * chi * math.cos(i) / eta(i))
    else:
        den = 2 - E1(i) - psi / math.pi * E1(e)
        mu0e = chi * (math.cos(i) + math.sin(i) * math.tan(tb) * (E2(i) - s2 * E2(e)) / den)
        mue = chi * (
            math.cos(e) + math.sin(e) * math.tan(tb) * (math.cos(psi) * E2(i) + s2 * E2(e)) / den
        )
        S = mue / eta(e) * math.cos(i) / eta(i) * chi / (1 - f + f * chi * math.cos(e) / eta(e))
    return mu0e, mue, S


def _hapke_scalar(i, e, psi, p: hk.HapkeParams):
    g = _phase(i, e, psi)
    if p.theta_bar > 0:
        mu0e, mue, S = _roughness_1984(i, e, psi, p.theta_bar)
    else:
        mu0e, mue, S = math.cos(i), math.cos(e), 1.0
    K = _K(p.phi)
    bsh = p.bs0 / (1 + math.tan(g / 2) / p.hs)
    z = math.tan(g / 2) / p.hc
    bcb = p.bc0 * (1 + (1 - math.exp(-z)) / z) / (2 * (1 + z) ** 2) if z > 0 else p.bc0
    M = _H(mu0e / K, p.w) * _H(mue / K, p.w) - 1
    return (
        K
        * p.w
        / (4 * math.pi)
        * mu0e
        / (mu0e + mue)
        * (_p(g, p.b, p.c) * (1 + bsh) + M)
        * (1 + bcb)
        * S
    )


def _vec(i, e, psi):
    return math.cos(i), math.cos(e), _phase(i, e, psi)


def _h_exact(w, mu, n=96):
    """Isotropic H-function from 1/H(mu) = sqrt(1-w) + w/2 int_0^1 mu' H(mu')/(mu+mu') dmu'."""
    x, wt = np.polynomial.legendre.leggauss(n)
    x, wt = 0.5 * (x + 1), 0.5 * wt
    gam = math.sqrt(1 - w)
    H = np.ones(n)
    for _ in range(20000):
        Hn = 1 / (gam + 0.5 * w * np.sum(wt * x * H / (x[:, None] + x), axis=1))
        done = np.max(np.abs(Hn - H)) < 1e-14
        H = Hn
        if done:
            break
    alpha0 = float(np.sum(wt * H))
    mu = np.asarray(mu, dtype=float)
    return 1 / (gam + 0.5 * w * np.sum(wt * x * H / (mu[:, None] + x), axis=1)), alpha0


# (i, e, psi) in degrees: i < e, i > e, i = e, psi = 0 and 180, near-normal, grazing
GEOMS = [
    (30, 0.5, 0),
    (30, 10, 0),
    (60, 10, 45),
    (10, 60, 45),
    (45, 45, 0),
    (45, 45, 90),
    (45, 45, 180),
    (70, 20, 180),
    (20, 70, 120),
    (80, 5, 30),
    (5, 80, 150),
    (85, 85, 10),
    (1, 50, 60),
    (50, 1, 60),
]

# ----------------------------------------------------------------------------- Hapke


@pytest.mark.parametrize("phi", [0.0, 0.41])
def test_smooth_surface_matches_closed_form(phi):
    p = hk.HapkeParams(w=0.36, b=0.3, c=0.5, bs0=1.5, hs=0.06, bc0=0.0, theta_bar=0.0, phi=phi)
    for i, e, psi in GEOMS:
        ci, ce, g = _vec(D(i), D(e), D(psi))
        mu0, mu = ci, ce
        K = _K(phi)
        bsh = p.bs0 / (1 + math.tan(g / 2) / p.hs)
        want = (
            K
            * p.w
            / (4 * math.pi)
            * mu0
            / (mu0 + mu)
            * (_p(g, p.b, p.c) * (1 + bsh) + _H(mu0 / K, p.w) * _H(mu / K, p.w) - 1)
        )
        got32 = float(hk.hapke_reflectance(ci, ce, g, params=p))
        got64 = float(hk.hapke_reflectance(ci, ce, g, params=p, dtype=np.float64))
        assert got32 == pytest.approx(want, rel=1e-4), (i, e, psi)
        assert got64 == pytest.approx(want, rel=1e-10), (i, e, psi)


@pytest.mark.parametrize(
    "params",
    [
        hk.HIGHLANDS_643NM,
        hk.HapkeParams(
            w=0.6, b=0.2, c=-0.3, bs0=1.0, hs=0.1, bc0=0.8, hc=0.05, theta_bar=D(35), phi=0.3
        ),
    ],
    ids=["highlands", "rough_cboe"],
)
def test_rough_surface_matches_scalar_hapke1984(params):
    for i, e, psi in GEOMS:
        want = _hapke_scalar(D(i), D(e), D(psi), params)
        ci, ce, g = _vec(D(i), D(e), D(psi))
        got32 = float(hk.hapke_reflectance(ci, ce, g, params=params))
        got64 = float(hk.hapke_reflectance(ci, ce, g, params=params, dtype=np.float64))
        assert got64 == pytest.approx(want, rel=1e-6), (i, e, psi)
        assert got32 == pytest.approx(want, rel=1e-4), (i, e, psi)


def test_roughness_changes_the_answer():
    # guards the test above: roughness must matter at these geometries
    smooth = dataclasses.replace(hk.HIGHLANDS_643NM, theta_bar=0.0)
    ci, ce, g = _vec(D(70), D(20), D(180))
    r_rough = float(hk.hapke_reflectance(ci, ce, g, dtype=np.float64))
    r_smooth = float(hk.hapke_reflectance(ci, ce, g, params=smooth, dtype=np.float64))
    assert abs(r_rough / r_smooth - 1) > 0.05


def test_opposition_surge_ratio():
    # i = e = 30 deg held fixed; only psi (hence g) changes, so with theta_bar = 0, b = 0
    # (p = 1) and bc0 = 0 the ratio is exactly (1 + B(0) + M) / (1 + B(5 deg) + M).
    p = hk.HapkeParams(w=0.1, b=0.0, c=0.0, bs0=2.3, hs=0.065, bc0=0.0, theta_bar=0.0)
    mu = math.cos(D(30))
    cos_psi = (math.cos(D(5)) - mu * mu) / (1 - mu * mu)
    psi5 = math.acos(cos_psi)
    r0 = float(hk.hapke_reflectance(*_vec(D(30), D(30), 0.0), params=p, dtype=np.float64))
    r5 = float(hk.hapke_reflectance(*_vec(D(30), D(30), psi5), params=p, dtype=np.float64))
    M = _H(mu, p.w) ** 2 - 1
    b5 = p.bs0 / (1 + math.tan(D(2.5)) / p.hs)
    assert r0 / r5 == pytest.approx((1 + p.bs0 + M) / (1 + b5 + M), rel=1e-9)
    # the highland preset brightens by ~40 % over the last 5 degrees of phase
    r0 = float(hk.hapke_reflectance(*_vec(D(30), D(30), 0.0), dtype=np.float64))
    r5 = float(hk.hapke_reflectance(*_vec(D(30), D(30), psi5), dtype=np.float64))
    assert 1.25 < r0 / r5 < 1.6


def _facet_normals(axis, max_tilt_deg, n=200, seed=3):
    rng = np.random.default_rng(seed)
    tilt = np.radians(max_tilt_deg) * np.sqrt(rng.random(n))
    az = 2 * np.pi * rng.random(n)
    a = axis / np.linalg.norm(axis)
    u = np.cross(a, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    return (
        np.cos(tilt)[:, None] * a
        + (np.sin(tilt) * np.cos(az))[:, None] * u
        + (np.sin(tilt) * np.sin(az))[:, None] * v
    )


def _spread(l_dir, v_dir, normals):
    ci, ce = normals @ l_dir, normals @ v_dir
    g = np.arccos(np.clip(l_dir @ v_dir, -1, 1))
    r = hk.hapke_reflectance(ci, ce, np.full_like(ci, g), dtype=np.float64)
    assert np.all(r > 0)
    return np.std(r) / np.mean(r)


def test_opposition_flattens_facet_contrast():
    # the same tilted facets lit and viewed from one direction (g = 0, the paper's Fig. 4-5)
    # show far less contrast than at g = 60 deg (facets tilted about the bisector)
    v = np.array([0.0, 0.0, 1.0])
    l60 = np.array([math.sin(D(60)), 0.0, math.cos(D(60))])
    cv0 = _spread(v, v, _facet_normals(v, 30))
    cv60 = _spread(l60, v, _facet_normals(l60 + v, 30))
    assert cv0 < 0.2 * cv60, (cv0, cv60)


def test_finite_nonnegative_random_geometry():
    rng = np.random.default_rng(7)
    n = 50_000
    ci = rng.uniform(-0.2, 1.0, n)
    ce = rng.uniform(-0.2, 1.0, n)
    g = rng.uniform(0, math.pi, n)
    ci[:50], ce[50:100], g[100:150] = np.nan, np.nan, np.nan
    ci[150:200], ce[200:250], g[250:300] = 1.0, 1.0, 0.0
    ci[300:350], ce[350:400], g[400:450] = 1e-9, 1e-9, math.pi
    for dtype in (np.float32, np.float64):
        for p in (hk.HIGHLANDS_643NM, hk.HapkeParams(bc0=1.0, hc=0.02, theta_bar=D(45), phi=0.6)):
            r = hk.hapke_reflectance(ci, ce, g, params=p, dtype=dtype)
            assert r.dtype == dtype and r.shape == (n,)
            assert np.all(np.isfinite(r)) and np.all(r >= 0)
            bad = ~((ci > 0) & (ce > 0)) | np.isnan(g)
            assert np.all(r[bad] == 0) and np.all(r[~bad] > 0)


@pytest.mark.parametrize(
    "i,e,psi",
    [
        (0, 0, 0),
        (0, 40, 0),
        (40, 0, 0),
        (40, 40, 0),
        (40, 40, 180),
        (88, 88, 0),
        (30, 60, 180),
    ],
)
def test_singular_geometries_are_finite_and_continuous(i, e, psi):
    ci, ce, g = _vec(D(i), D(e), D(psi))
    r = float(hk.hapke_reflectance(ci, ce, g, dtype=np.float64))
    assert math.isfinite(r) and r > 0
    # a nudge of 1e-4 rad into the valid domain gives nearly the same value (no spike)
    di = 1e-4 if i < 45 else -1e-4
    de = 2e-4 if e < 45 else -2e-4
    dpsi = 1e-4 if psi < 90 else -1e-4
    near = float(hk.hapke_reflectance(*_vec(D(i) + di, D(e) + de, D(psi) + dpsi), dtype=np.float64))
    assert near == pytest.approx(r, rel=2e-2)


def test_normal_incidence_roughness_factor_is_one():
    # at i = e = 0 the shadowing function S is 1 and mu0e = mue = chi for any theta_bar
    p = dataclasses.replace(hk.HIGHLANDS_643NM, bs0=0.0)
    r = float(hk.hapke_reflectance(1.0, 1.0, 0.0, params=p, dtype=np.float64))
    chi = 1 / math.sqrt(1 + math.pi * math.tan(p.theta_bar) ** 2)
    want = p.w / (8 * math.pi) * (_p(0.0, p.b, p.c) + _H(chi, p.w) ** 2 - 1)
    assert r == pytest.approx(want, rel=1e-10)


def test_h_function_within_one_percent_of_exact():
    mu = np.linspace(0.01, 1.0, 60)
    for w in (0.05, 0.2, 0.36, 0.5, 0.8, 0.95):
        exact, alpha0 = _h_exact(w, mu)
        # the solver itself: Chandrasekhar's zeroth moment identity
        assert alpha0 == pytest.approx(2 / w * (1 - math.sqrt(1 - w)), rel=1e-10)
        approx = hk.h_function(mu, w=w)
        assert np.max(np.abs(approx / exact - 1)) < 0.01, w
    # and the approximation is not trivially 1
    assert hk.h_function(1.0, w=0.95) > 2.0


def test_phase_function_normalised_and_backscattering():
    x, wt = np.polynomial.legendre.leggauss(400)  # cos g
    for b, c in ((0.26, 0.45), (0.6, -0.4), (0.0, 0.0)):
        p = hk.phase_function(np.arccos(x), b=b, c=c)
        assert 0.5 * np.sum(wt * p) == pytest.approx(1.0, rel=1e-9)
    assert hk.phase_function(0.0, b=0.3, c=0.5) > 2 * hk.phase_function(math.pi, b=0.3, c=0.5)
    assert hk.phase_function(0.0, b=0.3, c=-0.5) < hk.phase_function(math.pi, b=0.3, c=-0.5)


def test_coherent_backscatter_peak_and_limit():
    assert float(hk.coherent_backscatter(0.0, bc0=0.7, hc=0.05)) == pytest.approx(0.7)
    assert float(hk.coherent_backscatter(1e-7, bc0=0.7, hc=0.05)) == pytest.approx(0.7, rel=1e-5)
    assert float(hk.coherent_backscatter(D(30), bc0=0.7, hc=0.05)) < 0.05
    with_cb = hk.HapkeParams(bc0=0.5, hc=0.05)
    r_on = float(hk.hapke_reflectance(*_vec(D(30), D(30), 0.0), params=with_cb, dtype=np.float64))
    r_off = float(hk.hapke_reflectance(*_vec(D(30), D(30), 0.0), dtype=np.float64))
    assert r_on / r_off == pytest.approx(1.5, rel=1e-9)


def test_per_pixel_w_and_determinism():
    rng = np.random.default_rng(1)
    ci, ce = rng.uniform(0.05, 1, (2, 300, 200))
    g = rng.uniform(0, 2.5, (300, 200))
    w = rng.uniform(0.1, 0.6, (300, 200))
    r = hk.hapke_reflectance(ci, ce, g, w=w, dtype=np.float64)
    k = (17, 123)
    one = hk.hapke_reflectance(
        ci[k],
        ce[k],
        g[k],
        params=dataclasses.replace(hk.HIGHLANDS_643NM, w=float(w[k])),
        dtype=np.float64,
    )
    assert float(r[k]) == float(one)
    assert np.array_equal(r, hk.hapke_reflectance(ci, ce, g, w=w, dtype=np.float64, workers=2))
    r32 = hk.hapke_reflectance(ci, ce, g)
    assert np.array_equal(r32, hk.hapke_reflectance(ci, ce, g, workers=3))
    with pytest.raises(OutOfRangeError, match=r"1\.2"):
        hk.hapke_reflectance(ci, ce, g, w=np.full_like(ci, 1.2))


def test_normal_albedo_inversion():
    target = np.array([0.05, 0.15, 0.28])
    w = hk.w_from_normal_albedo(target)
    back = np.pi * hk.hapke_reflectance(1.0, 1.0, 0.0, w=w, dtype=np.float64)
    np.testing.assert_allclose(back, target, rtol=1e-4)
    with pytest.raises(OutOfRangeError, match="normal albedo"):
        hk.w_from_normal_albedo(5.0)


def test_params_validation_and_porosity():
    with pytest.raises(OutOfRangeError, match=r"w=1\.5"):
        hk.HapkeParams(w=1.5)
    with pytest.raises(OutOfRangeError, match="hs=0"):
        hk.HapkeParams(hs=0.0)
    with pytest.raises(OutOfRangeError, match=r"phi=0\.8"):
        hk.HapkeParams(phi=0.8)
    with pytest.raises(OutOfRangeError, match="theta_bar"):
        hk.HapkeParams(theta_bar=70.0)
    assert hk.HapkeParams(phi=0.0).K == 1.0
    with pytest.raises(ConfigError, match="int64"):
        hk.hapke_reflectance(0.5, 0.5, 0.1, dtype=np.int64)
    assert hk.porosity_k(0.41) == pytest.approx(_K(0.41), rel=1e-12)
    assert 1.6 < hk.porosity_k(0.41) < 1.7
    assert hk.porosity_k(1e-6) == pytest.approx(1.0, abs=1e-3)


def test_preset_radiance_factor_plausible():
    # I/F of the highland preset: bright at opposition, ~0.1 at the (30, 0, 30) standard
    iof0 = float(hk.radiance_factor(hk.hapke_reflectance(1.0, 1.0, 0.0, dtype=np.float64)))
    iof30 = float(
        hk.radiance_factor(hk.hapke_reflectance(*_vec(D(30), 0.0, 0.0), dtype=np.float64))
    )
    assert 0.2 < iof0 < 0.35
    assert 0.07 < iof30 < 0.15


# ----------------------------------------------------------------------------- Lunar-Lambert


def test_lunar_lambert_limits():
    ci = np.array([1.0, 0.8, 0.5, 0.2])
    ce = np.array([1.0, 0.3, 0.9, 0.6])
    lam = hk.lunar_lambert(ci, ce, 0.7, albedo=0.2, L=0.0)
    np.testing.assert_allclose(lam, 0.2 * ci / np.pi, rtol=1e-14)  # L = 0: Lambert
    ls = hk.lunar_lambert(ci, ce, 0.7, albedo=0.2, L=1.0)
    np.testing.assert_allclose(ls, 0.2 * 2 * ci / (ci + ce) / np.pi, rtol=1e-14)  # Lommel-Seeliger
    # normal albedo: I/F = albedo at i = e = g = 0 for any L
    for L in (0.0, 0.4, 1.0, None):
        assert float(np.pi * hk.lunar_lambert(1.0, 1.0, 0.0, albedo=0.17, L=L)) == pytest.approx(
            0.17
        )
    assert float(hk.lunar_lambert(-0.1, 0.5, 0.3, albedo=0.2)) == 0.0
    assert float(hk.lunar_lambert(0.5, 0.0, 0.3, albedo=0.2)) == 0.0


def test_mcewen_L():
    assert float(hk.lunar_lambert_L(0.0)) == 1.0
    a = 60.0
    assert float(hk.lunar_lambert_L(D(a))) == pytest.approx(
        1 - 0.019 * a + 2.42e-4 * a**2 - 1.46e-6 * a**3
    )
    L = hk.lunar_lambert_L(np.radians(np.arange(0, 101, 5.0)))
    assert np.all(np.diff(L) < 0) and 0.0 <= L.min()
    assert float(hk.lunar_lambert_L(D(170))) == 0.0  # clipped


def test_blend_is_hapke_away_from_limb_and_lunar_lambert_at_limb():
    rng = np.random.default_rng(5)
    n = 2000
    ci = rng.uniform(0.05, 1, n)
    e = np.radians(rng.uniform(0, 89.9, n))
    ce = np.cos(e)
    g = rng.uniform(0, 2.0, n)
    r_h = hk.hapke_reflectance(ci, ce, g)
    r_b = hk.blended_reflectance(ci, ce, g, start_deg=70, end_deg=85)
    inner = e < D(70)
    assert np.array_equal(r_b[inner], r_h[inner])
    outer = e > D(85)
    r_ll = hk.matched_lunar_lambert(ci[outer], ce[outer], g[outer], anchor_deg=70)
    np.testing.assert_allclose(r_b[outer], r_ll, rtol=1e-5)
    assert np.all(np.isfinite(r_b)) and np.all(r_b >= 0)
    # custom weight function
    r_all = hk.blended_reflectance(ci, ce, g, lambert_weight_fn=lambda a, b, c: np.ones_like(b))
    r_ll_all = hk.matched_lunar_lambert(ci, ce, g)
    np.testing.assert_allclose(r_all, r_ll_all, rtol=1e-5)
    with pytest.raises(OutOfRangeError, match="weights"):
        hk.blended_reflectance(ci, ce, g, lambert_weight_fn=lambda a, b, c: 2 * np.ones_like(b))


def test_matched_lunar_lambert_continues_hapke():
    rng = np.random.default_rng(9)
    i = np.radians(rng.uniform(0, 89, 500))
    e = np.radians(rng.uniform(0, 89.9, 500))
    psi = np.radians(rng.uniform(0, 180, 500))
    ci, ce = np.cos(i), np.cos(e)
    g = np.arccos(np.clip(ci * ce + np.sin(i) * np.sin(e) * np.cos(psi), -1, 1))
    r_ll = hk.matched_lunar_lambert(ci, ce, g, anchor_deg=75)
    r_h = hk.hapke_reflectance(ci, ce, g, dtype=np.float64)
    below = e <= np.radians(75)
    np.testing.assert_allclose(r_ll[below], r_h[below], rtol=1e-9)  # equal up to the anchor
    assert np.all(r_ll[~below] > 0) and np.all(np.isfinite(r_ll))
    # beyond it: the same order as Hapke, and the opposition surge survives at the limb
    assert np.all(np.abs(np.log(r_ll[~below] / r_h[~below])) < np.log(3.0))
    i85, e85 = D(84), D(85)
    r_opp = hk.matched_lunar_lambert(math.cos(i85), math.cos(e85), D(1.0))
    r_off = hk.matched_lunar_lambert(math.cos(i85), math.cos(e85), D(15.0))
    assert float(r_opp / r_off) > 1.3
    # near opposition beyond the anchor the phase curve is the pixel's own, not the
    # anchor's (i = 83, e = 80, psi = 0: g = 3 deg here but 8 deg at the anchor)
    geo = _vec(D(83), D(80), 0.0)
    ratio = float(hk.matched_lunar_lambert(*geo) / hk.hapke_reflectance(*geo, dtype=np.float64))
    assert 0.85 < ratio < 1.15


def test_blend_shades_backfacing_shading_normals():
    # cos_e <= 0 from a bump-mapped normal on a surface the ray caster saw: Hapke gives 0
    # (a black speckle), the blend gives the grazing-emission Lunar-Lambert value
    ci = np.array([0.3, 0.3, 0.3, -0.1])
    ce = np.array([0.01, 0.0, -0.05, 0.5])
    g = np.radians([80.0, 80.0, 80.0, 80.0])
    r_h = hk.hapke_reflectance(ci, ce, g)
    r_b = hk.blended_reflectance(ci, ce, g)
    assert r_h[1] == 0 and r_h[2] == 0
    assert np.all(r_b[:3] > 0) and r_b[3] == 0
    assert r_b[1] == pytest.approx(r_b[2], rel=1e-6)
    assert r_b[0] == pytest.approx(r_b[1], rel=0.05)
    # also with a custom weight that would otherwise keep pure Hapke
    r_c = hk.blended_reflectance(ci, ce, g, lambert_weight_fn=lambda a, b, c: np.zeros_like(b))
    assert r_c[0] == r_h[0] and r_c[2] == pytest.approx(r_b[2], rel=1e-6)


def test_blend_has_no_seam():
    # emission swept through the blend band at fixed incidence/azimuth: no jumps
    e = np.radians(np.linspace(60, 89.5, 3000))
    i, psi = D(40), D(150)
    ci = np.full_like(e, math.cos(i))
    cg = np.cos(i) * np.cos(e) + np.sin(i) * np.sin(e) * np.cos(psi)
    g = np.arccos(cg)
    r = hk.blended_reflectance(ci, np.cos(e), g, dtype=np.float64)
    steps = np.abs(np.diff(r)) / r[:-1]
    assert steps.max() < 2e-3
    assert np.any(r != hk.hapke_reflectance(ci, np.cos(e), g, dtype=np.float64))  # blend active
    with pytest.raises(OutOfRangeError, match="start_deg=80"):
        hk.limb_weight(np.array([0.5]), start_deg=80, end_deg=70)
