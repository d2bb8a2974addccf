"""Scores against the world: a map cell against the world layers averaged over the cell,
each reference computed here by its own quadrature, not by the code under test."""

import math

import numpy as np
import pytest
from scipy import integrate

from lunar_drake.errors import OutOfBoundsError
from lunar_drake.science import nss
from lunar_drake.science.scoring import agreement, cell_means


def _column_by_quadrature(dry, ice, h_ppm, *, L=0.25, zmax=1.0):
    """Depth-weighted WEH (wt%) of one world pixel: hydrogen-bearing minerals (1/9 of
    water is hydrogen: 9e-4 wt% per ppm) at every depth, ice below the dry layer, each
    depth weighted by exp(-z / L) over the top zmax metres (scipy's quad)."""
    def weh(z):
        return 9.0e-4 * h_ppm + (ice if z >= dry else 0.0)

    pts = [dry] if 0.0 < dry < zmax else None
    num, _ = integrate.quad(lambda z: weh(z) * math.exp(-z / L), 0.0, zmax, points=pts)
    den, _ = integrate.quad(lambda z: math.exp(-z / L), 0.0, zmax)
    return num / den


def _cell_mean_by_sampling(field, *, x0, y1, res, xw, ys, cell, step=0.01):
    """A piecewise-constant raster (row 0 north) averaged over a square by sampling it
    every ``step`` m (midpoints), each sample reading the pixel it falls in."""
    n = round(cell / step)
    u = (np.arange(n) + 0.5) * step
    cols = np.floor((xw + u - x0) / res).astype(int)
    rows = np.floor((y1 - (ys + u)) / res).astype(int)
    return float(field[np.ix_(rows, cols)].mean())


def _world(seed=5, n=120, res=0.1):
    rng = np.random.default_rng(seed)
    # Patches of ice a few pixels wide: a dry layer of 0, 0.2 or 1.5 m per 0.3 m block.
    blocks = rng.choice([0.0, 0.2, 1.5], size=(n // 3, n // 3), p=[0.2, 0.2, 0.6])
    dry = np.kron(blocks, np.ones((3, 3)))
    ice = rng.uniform(0.5, 5.0, (n, n))
    h = rng.uniform(20.0, 80.0, (n, n))
    return nss.HydrogenMap.centred(dry_layer_m=dry, ice_wt_pct=ice, h_minerals_ppm=h,
                                   resolution_m=res)  # fmt: skip


def test_cell_means_match_a_quadrature_of_the_world_column():
    hm = _world()
    cfg = nss.NSSConfig()
    # The reference column, pixel by pixel, by quadrature over depth: it is linear in the
    # ice and the minerals' hydrogen, so one quadrature per dry layer and unit of each.
    col = np.empty(hm.dry_layer_m.shape)
    for d in np.unique(hm.dry_layer_m):
        sel = hm.dry_layer_m == d
        per_ice = _column_by_quadrature(d, 1.0, 0.0)
        per_ppm = _column_by_quadrature(d, 0.0, 1.0)
        col[sel] = per_ice * hm.ice_wt_pct[sel] + per_ppm * hm.h_minerals_ppm[sel]
    got_col = nss.weh_column(hm, config=cfg)
    np.testing.assert_allclose(got_col, col, rtol=1e-7, atol=1e-9)
    # Cells on and off the pixel lattice, and one narrower than a pixel.
    cases = [(-4.0, -2.0, 2.0), (0.0, 0.0, 2.0), (-3.13, 1.37, 2.0), (2.04, -5.96, 1.0),
             (1.01, 1.02, 0.05)]  # fmt: skip
    for xw, ys, cell in cases:
        ref = _cell_mean_by_sampling(col, x0=hm.x0_m, y1=hm.y1_m, res=hm.resolution_m, xw=xw,
                                     ys=ys, cell=cell, step=min(0.01, cell / 20))  # fmt: skip
        got = cell_means(got_col, x0_m=hm.x0_m, y1_m=hm.y1_m, resolution_m=hm.resolution_m,
                         x_west_m=[xw], y_south_m=[ys], cell_m=cell)[0]  # fmt: skip
        assert got == pytest.approx(ref, rel=2e-3), (xw, ys, cell)
    # Across the grid's east edge (x = 6 m): the mean of its part on the grid.
    part = cell_means(got_col, x0_m=hm.x0_m, y1_m=hm.y1_m, resolution_m=hm.resolution_m,
                      x_west_m=[5.0], y_south_m=[0.0], cell_m=2.0)[0]  # fmt: skip
    assert part == pytest.approx(col[40:60, 110:120].mean(), rel=1e-9)
    with pytest.raises(OutOfBoundsError, match=r"cell at \(7, 0\) m .*off the world"):
        cell_means(got_col, x0_m=hm.x0_m, y1_m=hm.y1_m, resolution_m=hm.resolution_m,
                   x_west_m=[7.0], y_south_m=[0.0], cell_m=2.0)  # fmt: skip


def test_agreement_counts_only_finite_pairs():
    a = agreement([1.0, 2.0, np.nan, 4.0, 3.0], [1.5, 2.0, 7.0, 4.5, np.nan])
    assert a["cells"] == 3
    assert a["r"] == pytest.approx(np.corrcoef([1, 2, 4], [1.5, 2, 4.5])[0, 1])
    assert a["bias"] == pytest.approx(-1.0 / 3.0)
    assert a["rmse"] == pytest.approx(math.sqrt(0.5 / 3.0))
    assert agreement([1.0, 2.0], [1.0, 3.0])["r"] is None  # fewer than 3 pairs


def test_footprint_share_of_a_square():
    cfg = nss.NSSConfig(height_m=0.5, footprint_radius_m=2.0)
    big = 10.0
    # The whole disk inside; on an edge half of it; at a corner a quarter.
    got = nss.footprint_share([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], x_west_m=[-5.0, 0.0, 0.0],
                              y_south_m=[-5.0, -5.0, 0.0], cell_m=big, config=cfg,
                              step_m=0.01)  # fmt: skip
    np.testing.assert_allclose(got, [1.0, 0.5, 0.25], rtol=2e-3)
    # Anywhere else: against scipy's dblquad of h / (h^2 + r^2)^1.5 over the square.
    h, R = 0.5, 2.0
    x, y, xw, ys, s = 0.3, -0.2, -0.7, -1.5, 2.0

    def f(v, u):
        d2 = (u - x) ** 2 + (v - y) ** 2
        return h / (h * h + d2) ** 1.5 if d2 <= R * R else 0.0

    num, _ = integrate.dblquad(f, xw, xw + s, ys, ys + s, epsabs=1e-10)
    den = 2 * math.pi * (1 - h / math.hypot(h, R))
    got = nss.footprint_share(x, y, x_west_m=xw, y_south_m=ys, cell_m=s, config=cfg)[0]
    assert got == pytest.approx(num / den, rel=3e-3)


def _patchy_world(seed=3, w=40.0, hgt=16.0, res=0.1):
    """Ice in round patches 0.3-1.5 m across (a dry layer of 0 there, 1.5 m elsewhere),
    some of them in clusters, over hydrogen-bearing minerals of 40-60 ppm."""
    rng = np.random.default_rng(seed)
    ny, nx = round(hgt / res), round(w / res)
    y, x = np.mgrid[0:ny, 0:nx]
    x = -w / 2 + (x + 0.5) * res
    y = hgt / 2 - (y + 0.5) * res
    ice = np.zeros((ny, nx))
    dry = np.full((ny, nx), 1.5)
    for _ in range(260):
        cx, cy = rng.uniform(-w / 2, w / 2), rng.uniform(-hgt / 2, hgt / 2)
        rad = rng.uniform(0.15, 0.75)
        inside = np.hypot(x - cx, y - cy) <= rad
        ice[inside] = rng.uniform(1.0, 5.0)
        dry[inside] = rng.choice([0.0, 0.1])
    h = rng.uniform(40.0, 60.0, (ny, nx))
    return nss.HydrogenMap.centred(dry_layer_m=dry, ice_wt_pct=ice, h_minerals_ppm=h,
                                   resolution_m=res)  # fmt: skip


def test_the_nss_map_is_scored_against_the_world_over_the_cells_it_publishes():
    from lunar_drake.science.products import NSSTable, nss_grid, nss_truth
    from lunar_drake.science.scoring import nss_world

    cfg = nss.NSSConfig()
    hm = _patchy_world()
    rng = np.random.default_rng(8)
    # Lanes east along y = 1 (the middle of a row of 2 m cells), y = -3.9 (0.1 m inside
    # a cell's south edge) and y = 5.3; a record every 0.17 m (1 s at 0.17 m/s).
    xs = np.arange(-17.0, 17.0, 0.17)
    lanes = (1.0, -3.9, 5.3)
    xd = np.concatenate([xs] * len(lanes))
    yd = np.concatenate([np.full(xs.size, v) for v in lanes])
    truth = np.array([nss.footprint_weh(hm, a, b, config=cfg) for a, b in zip(xd, yd, strict=True)])
    counts = rng.poisson(250.0 / (1.0 + 0.2 * truth)).astype(np.float64)  # the documented law
    m = xd.size
    sec = np.ones(m)
    grid = nss_grid(xd, yd, counts, sec, config=cfg)
    published = np.isfinite(grid.mean[0])
    share = grid.mean[2]
    # Published exactly where at least half of the response came from the cell itself:
    # the middle lane's cells (about 0.67) are, the edge lane's (about 0.5 at 0.1 m from
    # the edge, below half nearer it) mostly not.
    assert np.array_equal(published, (grid.count > 0) & (share >= 0.5))
    rows_of = {v: int(np.floor((grid.y1_m - v) / 2.0)) for v in lanes}
    assert published[rows_of[1.0]].sum() >= 16 and np.nanmin(share[rows_of[1.0]]) > 0.6
    assert published[rows_of[-3.9]].sum() <= 3
    # The world's column over each published cell, by this file's own quadrature.
    col = np.empty(hm.dry_layer_m.shape)
    for d in np.unique(hm.dry_layer_m):
        sel = hm.dry_layer_m == d
        col[sel] = (_column_by_quadrature(d, 1.0, 0.0) * hm.ice_wt_pct[sel]
                    + _column_by_quadrature(d, 0.0, 1.0) * hm.h_minerals_ppm[sel])  # fmt: skip
    r_idx, c_idx = np.nonzero(published)
    ref = [_cell_mean_by_sampling(col, x0=hm.x0_m, y1=hm.y1_m, res=hm.resolution_m,
                                  xw=grid.x0_m + c * 2.0, ys=grid.y1_m - (r + 1) * 2.0,
                                  cell=2.0, step=0.05)
           for r, c in zip(r_idx, c_idx, strict=True)]  # fmt: skip
    est = grid.mean[0][published]
    r_ref = float(np.corrcoef(est, ref)[0, 1])
    world = nss_world(grid, hmap=hm, config=cfg)
    assert world["cells"] == published.sum()
    assert world["r"] == pytest.approx(r_ref, abs=1e-3)
    assert world["bias"] == pytest.approx(float(np.mean(est - np.array(ref))), abs=5e-3)
    # The pinned figures: the map against the world over its cells, and the instrument
    # against the footprint at the true positions (here the ground places records
    # exactly).
    assert r_ref >= 0.85
    t = np.arange(m, dtype=np.float64)
    table = NSSTable(t, xd - 0.9, yd, np.zeros(m), counts, np.zeros(m), sec,
                     nss.weh_from_epithermal(counts, sec, config=cfg))  # fmt: skip
    foot = nss_truth(table, truth_times=t,
                     truth_xy_yaw=np.stack([xd - 0.9, yd, np.zeros(m)], 1), hmap=hm,
                     config=cfg)  # fmt: skip
    assert foot["r"] >= 0.95
    # Publishing every cell a record fell in (no share threshold) scores worse: the edge
    # lane's cells describe mostly their neighbours' ground.
    every = nss_world(nss_grid(xd, yd, counts, sec, config=cfg, min_share=0.0), hmap=hm,
                      config=cfg)  # fmt: skip
    print(f"world r {r_ref:.3f} ({world['cells']} cells), unmasked {every['r']:.3f} "
          f"({every['cells']}), footprint {foot['r']:.3f} ({foot['cells']})")
    assert every["cells"] > world["cells"] and every["r"] < r_ref - 0.03
