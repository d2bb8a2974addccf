"""Ground science products from the records the downlink delivered (numpy; no Drake).

* :func:`nss_table`: the received NSS records as arrays, placed by the on-board pose
  estimate they carry -- moved by the ground's VO correction when its perception ran
  (:func:`ground_xy`) -- with the ground's water-equivalent hydrogen from the epithermal
  counts (:func:`~lunar_drake.science.nss.weh_from_epithermal`);
* :func:`grid_mean`: records averaged into square cells (a heat map);
* :func:`summed_weh`: the hydrogen of records pooled together (their summed counts over
  their summed seconds), with its Poisson standard deviation;
* :func:`nss_truth`: scoring only -- the footprint hydrogen of the world model at the
  rover's *true* position at each sample, and the correlation of the ground's gridded
  estimate with it;
* :func:`science_maps`: the ground's maps of each instrument along the path (PNG over
  the site hillshade, GeoTIFF in the site's CRS, with each cell's record count and, for
  NSS, its standard deviation).
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lunar_drake.science.nss import (
    NSSConfig,
    footprint_share,
    footprint_weh,
    weh_from_epithermal,
    weh_sigma_from_epithermal,
)


@dc.dataclass(frozen=True)
class NSSTable:
    """Received NSS records (arrays of equal length, sample order).

    Attributes: t_sample_s, x_m, y_m, yaw_rad (the ground's placing of the chassis: the
    on-board estimate, VO corrected when the ground's perception ran), epithermal,
    thermal (counts), integration_s, weh_est (wt%, the ground's inversion).
    """

    t_sample_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    epithermal: np.ndarray
    thermal: np.ndarray
    integration_s: np.ndarray
    weh_est: np.ndarray

    def __len__(self) -> int:
        return int(self.t_sample_s.size)


def ground_xy(t_s, x_m, y_m, keyframes=()) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ground_pose`'s positions."""
    return ground_pose(t_s, x_m, y_m, np.zeros(np.shape(x_m)), keyframes)[:2]


def ground_pose(t_s, x_m, y_m, yaw_rad, keyframes=()) -> tuple:
    """On-board poses (site m, rad) at times ``t_s`` (s) where the ground places them:
    moved by its VO correction (:class:`~lunar_drake.perception.ground_pipeline.
    KeyframeRecord` ``correction_*``; ``p' = Rz(yaw) p + (x, y)``), interpolated linearly
    in time between keyframes (drift grows between them: an approximation), the first
    keyframe's before it, the last one's after it. Without keyframes, unchanged.
    Returns ``(x, y, yaw)``."""
    t = np.asarray(t_s, np.float64)
    x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    yaw = np.asarray(yaw_rad, np.float64)
    if not len(keyframes):
        return x.copy(), y.copy(), yaw.copy()
    tk = np.array([k.t_capture_s for k in keyframes], np.float64)
    dx, dy = (np.interp(t, tk, [getattr(k, f) for k in keyframes])
              for f in ("correction_x_m", "correction_y_m"))  # fmt: skip
    dyaw = np.interp(t, tk, np.unwrap([k.correction_yaw_rad for k in keyframes]))
    c, s = np.cos(dyaw), np.sin(dyaw)
    return c * x - s * y + dx, s * x + c * y + dy, yaw + dyaw


def ahead(x_m, y_m, yaw_rad, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The points ``distance_m`` ahead of chassis poses (an instrument's footprint)."""
    return (np.asarray(x_m) + distance_m * np.cos(yaw_rad),
            np.asarray(y_m) + distance_m * np.sin(yaw_rad))  # fmt: skip


def nss_table(science_received, *, config: NSSConfig, keyframes=()) -> NSSTable:
    """The NSS records of ``science_received`` ((t_received, ScienceRecord) pairs),
    placed where the ground puts them (:func:`ground_xy` with its ``keyframes``)."""
    recs = [r for _t, r in science_received if r.instrument == "nss"]
    if not recs:
        e = np.zeros(0)
        return NSSTable(e, e, e, e, e, e, e, e)
    t = np.array([r.t_sample_s for r in recs])
    x, y, yaw = ground_pose(t, *([r.pose_estimate[i] for r in recs] for i in (0, 1, 5)),
                            keyframes)  # fmt: skip
    epi = np.array([r.values[0] for r in recs], np.float64)
    th = np.array([r.values[1] for r in recs], np.float64)
    dt = np.array([r.integration_s for r in recs])
    return NSSTable(t, x, y, yaw, epi, th, dt, weh_from_epithermal(epi, dt, config=config))


def grid_mean(x, y, values, *, cell_m: float, origin=(0.0, 0.0)) -> dict:
    """``values`` averaged over square cells of ``cell_m`` (cell (i, j) spans x in
    ``origin_x + [i, i+1) cell_m``): ``{(i, j): (mean, count)}``."""
    x, y, v = (np.asarray(a, np.float64) for a in (x, y, values))
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(v)
    i = np.floor((x[ok] - origin[0]) / cell_m).astype(np.int64)
    j = np.floor((y[ok] - origin[1]) / cell_m).astype(np.int64)
    out = {}
    for key in set(zip(i.tolist(), j.tolist(), strict=True)):
        sel = (i == key[0]) & (j == key[1])
        out[key] = (float(v[ok][sel].mean()), int(sel.sum()))
    return out


def summed_weh(counts, seconds, *, config: NSSConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(weh, sigma)`` (wt%) of records pooled: summed epithermal ``counts`` over summed
    ``seconds`` (arrays, e.g. one entry per cell) -- the Poisson maximum-likelihood rate,
    so the per-record inversion's convexity bias mostly goes -- inverted, and its Poisson
    standard deviation (:func:`~lunar_drake.science.nss.weh_sigma_from_epithermal`);
    NaN and infinite where no count fell (no rate to invert)."""
    n = np.asarray(counts, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(n > 0, weh_from_epithermal(n, seconds, config=config), np.nan)
        sd = weh_sigma_from_epithermal(n, seconds, config=config)
    return w, sd


def nss_truth(table: NSSTable, *, truth_times, truth_xy_yaw, hmap, config: NSSConfig,
              cell_m: float = 2.0, min_records: int = 3) -> dict:  # fmt: skip
    """Scoring: the world model's footprint WEH at the detector's true position at each
    sample (``truth_xy_yaw`` (n, 3) logged at ``truth_times``, interpolated), and the
    Pearson correlation between the ground's estimate and it over ``cell_m`` cells with
    at least ``min_records`` records, binned where the ground puts the detector (each
    cell: the ground's :func:`summed_weh` of its records against the mean of their
    truths). Returns ``{records, cells, r, truth_weh (array), rmse_wt_pct, bias_wt_pct}``
    (the last two over those cells, the bias their mean estimate less truth)."""
    tt = np.asarray(truth_times, np.float64)
    p = np.asarray(truth_xy_yaw, np.float64)
    n = len(table)
    xt = np.interp(table.t_sample_s, tt, p[:, 0])
    yt = np.interp(table.t_sample_s, tt, p[:, 1])
    yaw = np.interp(table.t_sample_s, tt, np.unwrap(p[:, 2]))
    xd, yd = ahead(xt, yt, yaw, config.x_m)
    truth = np.array([footprint_weh(hmap, float(a), float(b), config=config)
                      for a, b in zip(xd, yd, strict=True)])  # fmt: skip
    # Binned where the ground puts the detector: its own pose estimate, heading included.
    xe, ye = ahead(table.x_m, table.y_m, table.yaw_rad, config.x_m)
    epi = grid_mean(xe, ye, table.epithermal, cell_m=cell_m)
    sec = grid_mean(xe, ye, table.integration_s, cell_m=cell_m)
    tru = grid_mean(xe, ye, truth, cell_m=cell_m)
    # Pooled: the sum of a cell's counts over the sum of its seconds.
    keys = sorted(k for k, (m, c) in epi.items() if c >= min_records and m > 0)
    a, _ = summed_weh([epi[k][0] * epi[k][1] for k in keys],
                      [sec[k][0] * sec[k][1] for k in keys], config=config)  # fmt: skip
    b = np.array([tru[k][0] for k in keys])
    r = float(np.corrcoef(a, b)[0, 1]) if len(keys) >= 3 and a.std() > 0 and b.std() > 0 else None
    rmse = float(np.sqrt(np.mean((a - b) ** 2))) if keys else None
    bias = float(np.mean(a - b)) if keys else None
    return {"records": n, "cells": len(keys), "r": r, "truth_weh": truth, "rmse_wt_pct": rmse,
            "bias_wt_pct": bias}


@dc.dataclass(frozen=True)
class Grid:
    """Records gathered into square cells of a site-aligned grid: ``mean`` and ``total``
    (bands, rows, cols; the mean NaN where empty, the sum 0), ``count`` (rows, cols),
    west edge ``x0_m``, north edge ``y1_m`` (site m, multiples of ``cell_m``)."""

    mean: np.ndarray
    total: np.ndarray
    count: np.ndarray
    x0_m: float
    y1_m: float
    cell_m: float

    @property
    def extent(self) -> list:
        rows, cols = self.count.shape
        return [self.x0_m, self.x0_m + cols * self.cell_m, self.y1_m - rows * self.cell_m,
                self.y1_m]  # fmt: skip


def grid_records(x, y, values, *, cell_m: float, margin_cells: int = 2) -> Grid | None:
    """``values`` ((n,) or (n, bands)) averaged over ``cell_m`` cells around the points
    (x, y) (site m); None without a finite point."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    v = np.asarray(values, np.float64)
    v = v[:, None] if v.ndim == 1 else v
    ok = np.isfinite(x) & np.isfinite(y) & np.all(np.isfinite(v), axis=1)
    if not ok.any():
        return None
    x, y, v = x[ok], y[ok], v[ok]
    x0 = (math.floor(x.min() / cell_m) - margin_cells) * cell_m
    y1 = (math.floor(y.max() / cell_m) + 1 + margin_cells) * cell_m
    cols = math.floor((x.max() - x0) / cell_m) + 1 + margin_cells
    rows = math.floor((y1 - y.min()) / cell_m) + 1 + margin_cells
    c = np.floor((x - x0) / cell_m).astype(np.int64)
    r = np.floor((y1 - y) / cell_m).astype(np.int64)
    total = np.zeros((v.shape[1], rows, cols))
    count = np.zeros((rows, cols), np.int64)
    np.add.at(count, (r, c), 1)
    for b in range(v.shape[1]):
        np.add.at(total[b], (r, c), v[:, b])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return Grid(mean, total, count, float(x0), float(y1), float(cell_m))


#: The share of a cell's detector response that must come from inside the cell for the
#: NSS map to publish it (:func:`nss_grid`): at least half of what it measured.
MIN_FOOTPRINT_SHARE = 0.5


def nss_grid(x, y, epithermal, seconds, *, config: NSSConfig, cell_m: float = 2.0,
             min_share: float = MIN_FOOTPRINT_SHARE) -> Grid | None:  # fmt: skip
    """The ground's NSS map from records placed at detector positions (x, y) (site m):
    ``cell_m`` cells with bands ``weh_wt_pct`` (each cell's pooled counts inverted,
    :func:`summed_weh`; published -- finite -- only where the cell's ``footprint_share``
    is at least ``min_share``), ``weh_sigma_wt_pct`` (its Poisson standard deviation,
    where published) and ``footprint_share`` (-: the time-weighted mean over the cell's
    records of the share of each record's detector response that comes from inside the
    cell, :func:`~lunar_drake.science.nss.footprint_share`, at the ground's placing), and
    the records per cell in ``count``. None without a finite record."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    sec = np.asarray(seconds, np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    share = np.full(x.shape, np.nan)
    i, j = np.floor(x[ok] / cell_m), np.floor(y[ok] / cell_m)
    share[ok] = footprint_share(x[ok], y[ok], x_west_m=i * cell_m, y_south_m=j * cell_m,
                                cell_m=cell_m, config=config)  # fmt: skip
    grid = grid_records(x, y, np.stack([np.asarray(epithermal, np.float64), sec, share * sec],
                                       axis=1), cell_m=cell_m)  # fmt: skip
    if grid is None:
        return None
    w, sd = summed_weh(grid.total[0], grid.total[1], config=config)
    with np.errstate(invalid="ignore", divide="ignore"):
        sh = np.where(grid.count > 0, grid.total[2] / grid.total[1], np.nan)
    pub = (grid.count > 0) & (sh >= min_share)
    mean = np.stack([np.where(pub, w, np.nan), np.where(pub, sd, np.nan), sh])
    return dc.replace(grid, mean=mean)


#: Per instrument: (file stem, band names, value unit, the band shown in the PNG). Each
#: GeoTIFF also ends with a ``records`` band (records per cell).
MAPS = {
    "nss": ("nss_map", ("weh_wt_pct", "weh_sigma_wt_pct", "footprint_share"),
            "hydrogen (wt% WEH)", 0),
    "nirvss": ("nirvss_map", None, "band depth (-)", 1),
    "lcs": ("lcs_map", ("temperature_K",), "surface temperature (K, LCS)", 0),
}


def instrument_records(science_received, *, scenario, keyframes=()) -> dict:
    """The received records of each instrument where the ground puts its footprint (the
    downlinked on-board estimate, VO corrected with ``keyframes``, :func:`ground_pose`;
    the footprint ``x_m`` ahead along the ground's heading): ``{name: (x, y, values)}``
    (site m) for ``nss`` (values: epithermal counts, seconds), ``nirvss`` (the band
    depths) and ``lcs`` (K), each present only when records arrived."""
    recs = {}
    nss = nss_table(science_received, config=scenario.sensors.nss, keyframes=keyframes)
    if len(nss):
        recs["nss"] = (*ahead(nss.x_m, nss.y_m, nss.yaw_rad, scenario.sensors.nss.x_m),
                       np.stack([nss.epithermal, nss.integration_s], axis=1))  # fmt: skip
    nir = [r for _t, r in science_received if r.instrument == "nirvss"]
    if nir:
        nx, ny, nyaw = ground_pose([r.t_sample_s for r in nir],
                                   *([r.pose_estimate[i] for r in nir] for i in (0, 1, 5)),
                                   keyframes)  # fmt: skip
        nx, ny = ahead(nx, ny, nyaw, scenario.sensors.nirvss.x_m)
        vals = np.array([r.values for r in nir])
        recs["nirvss"] = (nx, ny, vals[:, :-1])
        recs["lcs"] = (nx, ny, vals[:, -1])
    return recs


def instrument_grid(name: str, x, y, values, *, scenario, cell_m: float = 2.0) -> Grid | None:
    """The ground's map of instrument ``name`` from :func:`instrument_records`' entry:
    NSS by :func:`nss_grid`, the others each cell's mean (:func:`grid_records`)."""
    if name == "nss":
        v = np.asarray(values)
        return nss_grid(x, y, v[:, 0], v[:, 1], config=scenario.sensors.nss, cell_m=cell_m)
    return grid_records(x, y, values, cell_m=cell_m)


def science_maps(out_dir, *, scenario, logs, site=None, cell_m: float = 2.0) -> list:
    """The ground's maps of each instrument along the path, from the records it
    received placed at the downlinked on-board estimate (VO corrected with the run's
    keyframes: :func:`instrument_records`): ``<stem>.png`` (over the site
    hillshade when ``site`` is given) and, with ``site``, ``<stem>.tif`` (the site's CRS,
    one band per quantity, NaN where no record fell, then ``records``, the records per
    cell). NSS (:func:`nss_grid`): water-equivalent hydrogen of each cell's pooled
    counts and its Poisson standard deviation, published only where most of the cell's
    detector response came from the cell itself, and that share; NIRVSS: every band
    (the PNG shows OH); LCS: temperature. Returns the paths."""
    from pathlib import Path

    from lunar_drake.science.nirvss import BANDS

    out = Path(out_dir)
    recs = instrument_records(logs.science_received, scenario=scenario,
                              keyframes=getattr(logs, "keyframes", None) or ())  # fmt: skip
    paths = []
    for name, (x, y, v) in recs.items():
        grid = instrument_grid(name, x, y, v, scenario=scenario, cell_m=cell_m)
        if grid is None:
            continue
        stem, bands, unit, shown = MAPS[name]
        bands = tuple(f"bd_{b}" for b in BANDS) if bands is None else bands
        _map_png(out / f"{stem}.png", grid, band=shown, x=x, y=y, site=site,
                 title=f"{name.upper()} on the ground: {len(x)} records, {cell_m:g} m cells "
                       f"({bands[shown]})", unit=unit)  # fmt: skip
        paths.append(out / f"{stem}.png")
        if site is not None:
            _map_tif(out / f"{stem}.tif", grid, bands=(*bands, "records"), hf=site.heightfield)
            paths.append(out / f"{stem}.tif")
    return paths


def _map_tif(path, grid: Grid, *, bands, hf) -> None:
    from rasterio.transform import Affine

    from lunar_drake.science.world import write_named_bands

    ox, oy = hf.origin_xy
    transform = Affine(grid.cell_m, 0.0, ox + grid.x0_m, 0.0, -grid.cell_m, oy + grid.y1_m)
    data = np.concatenate([grid.mean, grid.count[None].astype(np.float64)]).astype(np.float32)
    write_named_bands(path, data, names=bands, transform=transform, crs=hf.crs,
                      nodata=float("nan"))  # fmt: skip


def _map_png(path, grid: Grid, *, band: int, x, y, site, title: str, unit: str) -> None:

    from matplotlib.figure import Figure

    from lunar_drake.files import atomic_path

    fig = Figure(figsize=(7.5, 6.2), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    ext = grid.extent
    if site is not None:
        from lunar_drake.science.world import hillshade

        hf = site.heightfield
        res = hf.resolution_m
        rows, cols = hf.shape
        c0 = max(0, math.floor(ext[0] / res + cols / 2))
        c1 = min(cols, math.ceil(ext[1] / res + cols / 2))
        r0 = max(0, math.floor(rows / 2 - ext[3] / res))
        r1 = min(rows, math.ceil(rows / 2 - ext[2] / res))
        if c1 > c0 + 1 and r1 > r0 + 1:
            shade = hillshade(np.asarray(hf.read_window(r0, c0, r1 - r0, c1 - c0)), res)
            hext = [(c0 - cols / 2) * res, (c1 - cols / 2) * res, (rows / 2 - r1) * res,
                    (rows / 2 - r0) * res]  # fmt: skip
            ax.imshow(shade, cmap="gray", extent=hext, vmin=0, vmax=1)
    im = ax.imshow(np.ma.masked_invalid(grid.mean[band]), cmap="Blues" if "hydrogen" in unit
                   else "viridis", extent=ext, alpha=0.85, interpolation="nearest")  # fmt: skip
    fig.colorbar(im, ax=ax, label=unit + ", ground estimate", shrink=0.85)
    ax.plot(x, y, "-", color="0.2", lw=0.7, label="on-board estimate")
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8)
    with atomic_path(path, what="figure") as tmp:
        fig.savefig(tmp, format="png")


__all__ = [
    "MAPS",
    "MIN_FOOTPRINT_SHARE",
    "Grid",
    "NSSTable",
    "ahead",
    "grid_mean",
    "grid_records",
    "ground_pose",
    "ground_xy",
    "instrument_grid",
    "instrument_records",
    "nss_grid",
    "nss_table",
    "nss_truth",
    "science_maps",
    "summed_weh",
]
