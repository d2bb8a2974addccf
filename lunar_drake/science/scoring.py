"""Scoring the ground's science products against the world model's own layers (numpy;
no Drake). Truth only: nothing here feeds the flight or the ground.

A published map cell claims to describe the ground inside it, so it is scored against
the world layer averaged over that square (:func:`cell_means`: each world pixel weighs
the area it shares with the cell), not against what the instrument's own response
function would have read at the true positions (that figure,
:func:`~lunar_drake.science.products.nss_truth`, is the instrument's performance).
"""

from __future__ import annotations

import math

import numpy as np

from lunar_drake.errors import OutOfBoundsError


def _overlap(lo: float, hi: float, n: int) -> tuple[int, np.ndarray]:
    """First pixel and the lengths (px) of pixels ``[k, k+1)`` inside ``[lo, hi)``
    (pixel coordinates), the range clipped to ``[0, n)``."""
    a, b = max(0.0, lo), min(float(n), hi)
    if b <= a:
        return 0, np.zeros(0)
    k0, k1 = math.floor(a), math.ceil(b)
    edges = np.arange(k0, k1 + 1, dtype=np.float64)
    return k0, np.minimum(edges[1:], b) - np.maximum(edges[:-1], a)


def cell_means(layer, *, x0_m: float, y1_m: float, resolution_m: float, x_west_m, y_south_m,
               cell_m: float) -> np.ndarray:  # fmt: skip
    """The mean of ``layer`` (rows, cols; row 0 north, west edge ``x0_m``, north edge
    ``y1_m``, pixels of ``resolution_m``; site m) over each square cell ``[x_west,
    x_west + cell_m) x [y_south, y_south + cell_m)`` (site m), every pixel weighted by
    the area it shares with the cell (a cell across the grid's edge: over its part on
    the grid). Raises OutOfBoundsError for a cell wholly off the grid."""
    a = np.asarray(layer)
    rows, cols = a.shape
    xw = np.atleast_1d(np.asarray(x_west_m, np.float64))
    ys = np.atleast_1d(np.asarray(y_south_m, np.float64))
    out = np.empty(xw.size)
    n = cell_m / resolution_m
    for k, (x, y) in enumerate(zip(xw, ys, strict=True)):
        u0 = (x - x0_m) / resolution_m
        v0 = (y1_m - y - cell_m) / resolution_m
        c0, wx = _overlap(u0, u0 + n, cols)
        r0, wy = _overlap(v0, v0 + n, rows)
        if not wx.size or not wy.size:
            raise OutOfBoundsError(
                f"cell at ({x:g}, {y:g}) m ({cell_m:g} m) lies off the world model's grid "
                f"(x from {x0_m:g} m, y up to {y1_m:g} m, {cols} x {rows} px)"
            )
        block = a[r0:r0 + wy.size, c0:c0 + wx.size].astype(np.float64)
        out[k] = float(wy @ block @ wx) / float(wy.sum() * wx.sum())
    return out


def agreement(estimate, truth) -> dict:
    """``{cells, r, rmse, bias}`` of paired estimates and truths (finite pairs only):
    the Pearson correlation (None with fewer than 3 pairs or no spread), the RMS
    difference and the mean of estimate less truth (None without pairs)."""
    a, b = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = int(a.size)
    r = float(np.corrcoef(a, b)[0, 1]) if n >= 3 and a.std() > 0 and b.std() > 0 else None
    return {
        "cells": n,
        "r": r,
        "rmse": float(np.sqrt(np.mean((a - b) ** 2))) if n else None,
        "bias": float(np.mean(a - b)) if n else None,
    }


def published_cells(grid, band: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(value, x_west_m, y_south_m)`` of the cells of a
    :class:`~lunar_drake.science.products.Grid` whose ``band`` is finite (published)."""
    v = grid.mean[band]
    r, c = np.nonzero(np.isfinite(v))
    return v[r, c], grid.x0_m + c * grid.cell_m, grid.y1_m - (r + 1) * grid.cell_m


def world_agreement(grid, layer, *, x0_m: float, y1_m: float, resolution_m: float,
                    band: int = 0, scale: float = 1.0) -> dict:  # fmt: skip
    """:func:`agreement` of a map's published cells (``band`` of ``grid``, times
    ``scale``) with the world ``layer`` averaged over each cell (:func:`cell_means`)."""
    v, xw, ys = published_cells(grid, band)
    world = cell_means(layer, x0_m=x0_m, y1_m=y1_m, resolution_m=resolution_m, x_west_m=xw,
                       y_south_m=ys, cell_m=grid.cell_m)  # fmt: skip
    return agreement(scale * v, world)


def nss_world(grid, *, hmap, config) -> dict:
    """The NSS map (:func:`~lunar_drake.science.products.nss_grid`) against the world:
    its published cells' hydrogen against the world model's depth-weighted hydrogen
    column (:func:`~lunar_drake.science.nss.weh_column`: minerals' hydrogen plus the ice
    below the dry layer, wt% WEH) averaged over each cell (:func:`world_agreement`)."""
    from lunar_drake.science.nss import weh_column

    return world_agreement(grid, weh_column(hmap, config=config), x0_m=hmap.x0_m,
                           y1_m=hmap.y1_m, resolution_m=hmap.resolution_m)  # fmt: skip


def nirvss_layers(smap, *, config) -> dict:
    """Per NIRVSS band, ``(layer, coefficient)``: the world layer it reads (what the
    spot holds: surface frost area fraction, OH ppm, exposed ice wt% -- the ice where
    the dry layer is 0 --, each mineral's wt%) and its band depth per unit of it."""
    from lunar_drake.science.config import MINERALS

    L = smap.layers
    exposed = np.where(np.asarray(L["dry_layer_m"]) <= 0.0, L["ice_wt_pct"], 0.0)
    out = {
        "frost": (L["frost_area_frac"], config.frost_per_area_frac),
        "oh": (L["oh_ppm"], config.oh_per_ppm),
        "ice": (exposed, config.ice_per_wt_pct),
    }
    for k, m in enumerate(MINERALS):
        out[m] = (L["minerals"][k], config.mineral_per_wt_pct[k])
    return out


def nirvss_world(grid, *, smap, config) -> dict:
    """The NIRVSS map (bands in :data:`~lunar_drake.science.nirvss.BANDS` order) against
    the world: per band with a non-zero coefficient, :func:`world_agreement` of its
    cells' mean band depth over the coefficient (the abundance the band implies, in the
    layer's unit) with the layer averaged over each cell (:func:`nirvss_layers`)."""
    from lunar_drake.science.nirvss import BANDS

    out = {}
    for k, (band, (layer, coef)) in enumerate(nirvss_layers(smap, config=config).items()):
        assert band == BANDS[k]
        if coef > 0:
            out[band] = world_agreement(grid, layer, x0_m=smap.x0_m, y1_m=smap.y1_m,
                                        resolution_m=smap.resolution_m, band=k,
                                        scale=1.0 / coef)  # fmt: skip
    return out


#: The square (m) a drill hole's samples claim to describe: about the hole's width.
HOLE_M = 0.1


def drill_holes(records, *, hole_x_m: float, ice_per_wt_pct: float, sigma: float) -> list:
    """The ground's drill product from the received drill records (ScienceRecord values
    (sample number, depth m, ice band depth), in order; a new hole where the depth does
    not grow):
    per hole, ``hole_xy_est_m`` (``hole_x_m`` ahead of the on-board estimate at its
    first sample), ``depth_m`` and ``ice_est_wt_pct`` of each sample (band depth over
    ``ice_per_wt_pct``), ``dry_layer_est_m`` (the depth of the first sample whose ice
    exceeds 3 ``sigma`` of band noise, None if none does) and ``above_m`` (the sample
    before it, 0 at the first: the dry layer lies in ``(above_m, dry_layer_est_m]``)."""
    holes = []
    for r in records:
        _k, depth, bd = (float(v) for v in r.values[:3])
        if not holes or depth <= holes[-1]["depth_m"][-1]:
            p = r.pose_estimate
            holes.append({"hole_xy_est_m": (p[0] + hole_x_m * math.cos(p[5]),
                                            p[1] + hole_x_m * math.sin(p[5])),
                          "depth_m": [], "ice_est_wt_pct": []})  # fmt: skip
        holes[-1]["depth_m"].append(depth)
        holes[-1]["ice_est_wt_pct"].append(bd / ice_per_wt_pct)
    detect = 3.0 * sigma / ice_per_wt_pct
    for h in holes:
        icy = [i for i, v in enumerate(h["ice_est_wt_pct"]) if v > detect]
        h["dry_layer_est_m"] = h["depth_m"][icy[0]] if icy else None
        h["above_m"] = (h["depth_m"][icy[0] - 1] if icy[0] > 0 else 0.0) if icy else None
    return holes


def drill_world(holes, *, smap) -> dict:
    """The drill product (:func:`drill_holes`) against the world at each hole the ground
    claims (its layers averaged over :data:`HOLE_M` around ``hole_xy_est_m``): per hole
    the world's ``dry_layer_m`` and ``ice_wt_pct`` there, whether the dry layer lies in
    the bracket the samples give (``dry_layer_bracketed``; deeper than the last sample
    when none was icy), and each sample's ice against the world's at its depth (none
    above the dry layer); ``rmse_wt_pct`` over all samples."""
    geo = {"x0_m": smap.x0_m, "y1_m": smap.y1_m, "resolution_m": smap.resolution_m}
    out, err = [], []
    for h in holes:
        x, y = h["hole_xy_est_m"]
        at = {k: float(cell_means(smap.layers[k], x_west_m=x - HOLE_M / 2,
                                  y_south_m=y - HOLE_M / 2, cell_m=HOLE_M, **geo)[0])
              for k in ("dry_layer_m", "ice_wt_pct")}  # fmt: skip
        dry, ice = at["dry_layer_m"], at["ice_wt_pct"]
        world = [ice if z >= dry else 0.0 for z in h["depth_m"]]
        e = np.subtract(h["ice_est_wt_pct"], world)
        err += list(e)
        d = h["dry_layer_est_m"]
        ok = (h["above_m"] < dry <= d) if d is not None else dry > max(h["depth_m"])
        out.append({"hole_xy_est_m": [round(float(v), 4) for v in (x, y)],
                    "dry_layer_est_m": d, "dry_layer_world_m": dry, "ice_world_wt_pct": ice,
                    "dry_layer_bracketed": bool(ok),
                    "rmse_wt_pct": float(np.sqrt(np.mean(e**2)))})  # fmt: skip
    return {"holes": out, "rmse_wt_pct": float(np.sqrt(np.mean(np.square(err)))) if err
            else None}  # fmt: skip


__all__ = ["HOLE_M", "agreement", "cell_means", "drill_holes", "drill_world", "nirvss_layers",
           "nirvss_world", "nss_world", "published_cells", "world_agreement"]  # fmt: skip
