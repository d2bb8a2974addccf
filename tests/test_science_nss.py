"""NSS core: depth and footprint weighting against quadrature, count rates, Poisson
counts and the ground's inversion."""

import math

import numpy as np
import pytest
from scipy import integrate, stats

from lunar_drake.errors import OutOfBoundsError, OutOfRangeError
from lunar_drake.science import nss


def _map(dry, ice, h, res):
    return nss.HydrogenMap.centred(
        dry_layer_m=dry, ice_wt_pct=ice, h_minerals_ppm=h, resolution_m=res
    )


def test_depth_weight_matches_quadrature():
    cfg = nss.NSSConfig(depth_scale_m=0.25, max_depth_m=1.0)
    for d in (0.0, 0.1, 0.4, 0.99, 1.0, 1.3):
        num, _ = integrate.quad(lambda z: math.exp(-z / 0.25), min(d, 1.0), 1.0)
        den, _ = integrate.quad(lambda z: math.exp(-z / 0.25), 0.0, 1.0)
        assert nss.ice_depth_weight(d, config=cfg) == pytest.approx(num / den, abs=1e-12)


def test_footprint_weight_matches_the_solid_angle_integral():
    # Ice only within rho of the detector: its share of the footprint is
    # (1 - h / sqrt(h^2 + rho^2)) / (1 - h / sqrt(h^2 + R^2)) in the continuum.
    cfg = nss.NSSConfig(height_m=0.5, footprint_radius_m=2.0)
    res, n = 0.01, 500
    y, x = (np.mgrid[0:n, 0:n] + 0.5 - n / 2) * res
    rho = 0.8
    ice = np.where(np.hypot(x, y) <= rho, 3.0, 0.0)
    hmap = _map(np.zeros((n, n)), ice, np.zeros((n, n)), res)
    got = nss.footprint_weh(hmap, 0.0, 0.0, config=cfg)
    h, R = 0.5, 2.0
    share = (1 - h / math.hypot(h, rho)) / (1 - h / math.hypot(h, R))
    assert got == pytest.approx(3.0 * share, rel=5e-3)
    uniform = _map(np.full((n, n), 0.3), np.full((n, n), 2.0), np.full((n, n), 100.0), res)
    expected = 100.0 * nss.WEH_PER_H_PPM + 2.0 * nss.ice_depth_weight(0.3, config=cfg)
    assert nss.footprint_weh(uniform, 0.4, -0.7, config=cfg) == pytest.approx(expected)
    with pytest.raises(OutOfBoundsError, match="outside the world model"):
        nss.footprint_weh(uniform, 40.0, 0.0, config=cfg)


def test_count_rates_fall_as_hydrogen_rises():
    cfg = nss.NSSConfig()
    w = np.linspace(0.0, 10.0, 41)
    epi, th = nss.count_rates(w, config=cfg)
    assert np.all(np.diff(epi) < 0)
    assert epi[0] == cfg.epithermal_dry_cps
    assert np.all(np.diff(th) > 0) and th[-1] < 2.0 * cfg.thermal_dry_cps  # saturates
    back = nss.weh_from_epithermal(epi * 2.0, 2.0, config=cfg)
    assert np.allclose(back, w)


def test_counts_are_poisson():
    cfg = nss.NSSConfig(rate_hz=2.0)
    mu_epi, mu_th = (r * 0.5 for r in nss.count_rates(2.0, config=cfg))
    g = np.random.default_rng(7)
    draws = np.array([nss.draw_counts(2.0, g, config=cfg) for _ in range(4000)])
    for k, mu in enumerate((mu_epi, mu_th)):
        c = draws[:, k]
        assert c.mean() == pytest.approx(mu, rel=0.01)
        assert c.var() / c.mean() == pytest.approx(1.0, abs=0.08)  # dispersion index
        # Goodness of fit to Poisson(mu) over the central bins.
        edges = np.arange(int(mu - 3 * math.sqrt(mu)), int(mu + 3 * math.sqrt(mu)))
        obs = np.array([(c == e).sum() for e in edges])
        exp = 4000 * stats.poisson.pmf(edges, mu)
        chi2 = ((obs - exp) ** 2 / exp).sum()
        assert chi2 < stats.chi2.ppf(0.999, edges.size - 1)


def test_bad_nss_config():
    with pytest.raises(OutOfRangeError, match="height_m"):
        nss.NSSConfig(height_m=0.0).validate()
    with pytest.raises(OutOfRangeError, match="rate_hz"):
        nss.NSSConfig(rate_hz=0.0).validate()


def test_records_are_averaged_into_site_aligned_cells():
    from lunar_drake.science.products import grid_records

    x = np.array([0.5, 1.5, 1.9, -3.1])
    y = np.array([0.5, 0.2, 1.8, 4.9])
    g = grid_records(x, y, np.array([1.0, 2.0, 4.0, 8.0]), cell_m=2.0, margin_cells=0)
    assert (g.x0_m, g.y1_m) == (-4.0, 6.0)  # multiples of the cell
    # (0.5, 0.5), (1.5, 0.2), (1.9, 1.8) share the cell x in [0, 2), y in [0, 2).
    r, c = int((6.0 - 0.5) // 2), int((0.5 + 4.0) // 2)
    assert g.mean[0, r, c] == pytest.approx(7.0 / 3.0) and g.count[r, c] == 3
    r, c = int((6.0 - 4.9) // 2), int((-3.1 + 4.0) // 2)
    assert g.mean[0, r, c] == 8.0 and g.count.sum() == 4
    assert np.isnan(g.mean[0][g.count == 0]).all()


def test_the_ground_places_records_with_its_vo_correction_interpolated_in_time():
    from types import SimpleNamespace as NS

    from lunar_drake.comms.science import ScienceRecord
    from lunar_drake.science.products import ahead, ground_xy, nss_table

    # Keyframes at 10 s (shift 1 m east) and 20 s (1 m east, 2 m north, turned 90 deg).
    kf = [NS(t_capture_s=10.0, correction_x_m=1.0, correction_y_m=0.0, correction_yaw_rad=0.0),
          NS(t_capture_s=20.0, correction_x_m=1.0, correction_y_m=2.0,
             correction_yaw_rad=math.pi / 2)]  # fmt: skip
    x, y = ground_xy([5.0, 15.0, 30.0], [2.0, 2.0, 2.0], [0.0, 0.0, 0.0], kf)
    # 5 s: the first keyframe's; 15 s: halfway (1, 1, 45 deg); 30 s: the last's.
    h = math.sqrt(2.0)
    np.testing.assert_allclose(x, [3.0, 1.0 + h, 1.0], atol=1e-12)
    np.testing.assert_allclose(y, [0.0, 1.0 + h, 4.0], atol=1e-12)
    x0, y0 = ground_xy([5.0], [2.0], [3.0])
    assert x0.tolist() == [2.0] and y0.tolist() == [3.0]
    recs = [(t + 1.3, ScienceRecord(instrument="nss", index=k, t_sample_s=t, values=(250, 150),
                                    integration_s=1.0, pose_estimate=(2.0, 0.0, 0, 0, 0, 0)))
            for k, t in enumerate((5.0, 15.0))]  # fmt: skip
    tab = nss_table(recs, config=nss.NSSConfig(), keyframes=kf)
    np.testing.assert_allclose(tab.x_m, [3.0, 1.0 + h], atol=1e-12)
    np.testing.assert_allclose(tab.y_m, [0.0, 1.0 + h], atol=1e-12)
    raw = nss_table(recs, config=nss.NSSConfig())
    assert raw.x_m.tolist() == [2.0, 2.0] and raw.y_m.tolist() == [0.0, 0.0]
    # The heading too (0 on board; turned 45 deg at 15 s): the detector 0.9 m ahead.
    np.testing.assert_allclose(tab.yaw_rad, [0.0, math.pi / 4], atol=1e-12)
    dx, dy = ahead(tab.x_m, tab.y_m, tab.yaw_rad, 0.9)
    np.testing.assert_allclose(dx, [3.9, 1.0 + h + 0.9 / h], atol=1e-12)
    np.testing.assert_allclose(dy, [0.0, 1.0 + h + 0.9 / h], atol=1e-12)


def test_count_rates_are_the_documented_laws():
    # docs/science.md: epithermal 250 / (1 + 0.2 W), thermal 150 (1 + 0.6 W) / (1 + 0.3 W).
    cfg = nss.NSSConfig()
    epi, th = nss.count_rates(np.array([0.0, 1.0, 5.0]), config=cfg)
    assert epi == pytest.approx([250.0, 250.0 / 1.2, 125.0])
    assert th == pytest.approx([150.0, 150.0 * 1.6 / 1.3, 150.0 * 4.0 / 2.5])


def test_pooling_removes_the_single_record_inversions_bias():
    # 1 s records at W = 0.6 wt%: a record's inversion is convex in its counts, so their
    # mean reads about C0 T / (k N^2) = +0.025 wt% high; the pooled counts do not.
    from lunar_drake.science.products import summed_weh

    cfg = nss.NSSConfig()
    lam = 250.0 / (1.0 + 0.2 * 0.6)  # counts in 1 s at 0.6 wt%, from the documented law
    n = np.random.default_rng(7).poisson(lam, size=20000)
    per_record = nss.weh_from_epithermal(n, np.ones(n.size), config=cfg).mean() - 0.6
    pooled, sigma = (float(v) for v in summed_weh(n.sum(), float(n.size), config=cfg))
    # Standard error of 20000 records: sqrt(lam) / lam^2 * 250 / 0.2 / sqrt(20000), 0.0027.
    se = 250.0 / (0.2 * lam**1.5) / math.sqrt(n.size)
    assert per_record == pytest.approx(250.0 / (0.2 * lam**2), abs=3 * se)  # the bias
    assert abs(pooled - 0.6) < 3 * se and per_record > 5 * se
    assert sigma == pytest.approx(se, rel=0.01)


def test_the_poisson_sigma_matches_the_scatter_of_pooled_cells():
    # 4000 cells of 5 one-second records at 1 wt%: the spread of their pooled estimates
    # against the first-order sigma.
    from lunar_drake.science.products import summed_weh

    cfg = nss.NSSConfig()
    lam = 250.0 / 1.2
    counts = np.random.default_rng(3).poisson(lam, size=(4000, 5))
    est = summed_weh(counts.sum(axis=1), 5.0, config=cfg)[0]
    predicted = float(nss.weh_sigma_from_epithermal(5 * lam, 5.0, config=cfg))
    assert est.std() == pytest.approx(predicted, rel=0.05)  # SE of a std: 1.1 %
    assert math.isinf(nss.weh_sigma_from_epithermal(0, 1.0, config=cfg))


def test_the_score_pools_each_cell_and_recovers_a_two_level_truth():
    # West of x = 0 the ground holds 0.5 wt% WEH, east 2.0 (hydrogen-bearing minerals
    # only); 40 cells of 2 m, 50 records of 0.25 s each, at least 3 m from the step.
    from lunar_drake.science.products import NSSTable, nss_truth

    cfg = nss.NSSConfig()
    res, n = 0.25, 240
    x_px = (np.arange(n) + 0.5 - n / 2) * res
    w_map = np.where(x_px[None, :] < 0.0, 0.5, 2.0) * np.ones((n, 1))
    hmap = _map(np.zeros((n, n)), np.zeros((n, n)), w_map / 9.0e-4, res)
    rng = np.random.default_rng(11)
    cx = np.concatenate([np.arange(-23.0, -3.0, 2.0), np.arange(5.0, 25.0, 2.0)])
    centres = [(x, y) for x in cx for y in (1.0, 5.0)]
    xs, ys = [], []
    for x, y in centres:
        xs += list(x + rng.uniform(-0.8, 0.8, 50))
        ys += list(y + rng.uniform(-0.8, 0.8, 50))
    xs, ys = np.array(xs), np.array(ys)
    w_true = np.where(xs < 0.0, 0.5, 2.0)
    rate = 250.0 / (1.0 + 0.2 * w_true)  # the documented law
    counts = rng.poisson(rate * 0.25).astype(np.float64)
    m = xs.size
    t = np.arange(m, dtype=np.float64)
    # The chassis 0.9 m west of each footprint, heading east: both true and estimated.
    table = NSSTable(t, xs - 0.9, ys, np.zeros(m), counts, np.zeros(m), np.full(m, 0.25),
                     nss.weh_from_epithermal(counts, 0.25, config=cfg))  # fmt: skip
    out = nss_truth(table, truth_times=t, truth_xy_yaw=np.stack([xs - 0.9, ys, np.zeros(m)], 1),
                    hmap=hmap, config=cfg)  # fmt: skip
    np.testing.assert_allclose(out["truth_weh"], w_true, atol=1e-9)
    assert out["cells"] == 40 and out["r"] > 0.95
    # The mean of single-record inversions would read C0 T / (k N^2) high: 0.127 wt% on
    # average here; the pooled cells are unbiased within 3 standard errors (0.02 wt%).
    n_rec = rate * 0.25
    per_record_bias = float(np.mean(250.0 * 0.25 / (0.2 * n_rec**2)))
    se = float(np.sqrt(np.mean((250.0 * 0.25 / (0.2 * n_rec**1.5)) ** 2) / m))
    assert per_record_bias > 0.12 and abs(out["bias_wt_pct"]) < 3 * se < per_record_bias / 2
    # The cells scatter as their Poisson sigma says.
    sigma_cell = [250.0 * 12.5 / (0.2 * (50 * 250.0 / (1 + 0.2 * w) * 0.25) ** 1.5)
                  for w in (0.5, 2.0)]  # fmt: skip
    assert out["rmse_wt_pct"] == pytest.approx(math.sqrt(np.mean(np.square(sigma_cell))), rel=0.3)
