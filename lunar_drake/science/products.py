"""Ground science products from the records the downlink delivered (numpy; no Drake).

* :func:`nss_table`: the received NSS records as arrays, placed by the on-board pose
  estimate they carry, with the ground's water-equivalent hydrogen from the epithermal
  counts (:func:`~lunar_drake.science.nss.weh_from_epithermal`);
* :func:`grid_mean`: records averaged into square cells (a heat map);
* :func:`nss_truth`: scoring only -- the footprint hydrogen of the world model at the
  rover's *true* position at each sample, and the correlation of the ground's gridded
  estimate with it;
* :func:`nss_map_png`: the ground's hydrogen heat map along the path.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np

from lunar_drake.science.nss import NSSConfig, footprint_weh, weh_from_epithermal


@dc.dataclass(frozen=True)
class NSSTable:
    """Received NSS records (arrays of equal length, sample order).

    Attributes: t_sample_s, x_m, y_m (on-board estimate), epithermal, thermal (counts),
    integration_s, weh_est (wt%, the ground's inversion).
    """

    t_sample_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    epithermal: np.ndarray
    thermal: np.ndarray
    integration_s: np.ndarray
    weh_est: np.ndarray

    def __len__(self) -> int:
        return int(self.t_sample_s.size)


def nss_table(science_received, *, config: NSSConfig) -> NSSTable:
    """The NSS records of ``science_received`` ((t_received, ScienceRecord) pairs)."""
    recs = [r for _t, r in science_received if r.instrument == "nss"]
    if not recs:
        e = np.zeros(0)
        return NSSTable(e, e, e, e, e, e, e)
    t = np.array([r.t_sample_s for r in recs])
    x = np.array([r.pose_estimate[0] for r in recs])
    y = np.array([r.pose_estimate[1] for r in recs])
    epi = np.array([r.values[0] for r in recs], np.float64)
    th = np.array([r.values[1] for r in recs], np.float64)
    dt = np.array([r.integration_s for r in recs])
    return NSSTable(t, x, y, epi, th, dt, weh_from_epithermal(epi, dt, config=config))


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


def nss_truth(table: NSSTable, *, truth_times, truth_xy_yaw, hmap, config: NSSConfig,
              cell_m: float = 2.0, min_records: int = 3) -> dict:  # fmt: skip
    """Scoring: the world model's footprint WEH at the detector's true position at each
    sample (``truth_xy_yaw`` (n, 3) logged at ``truth_times``, interpolated), and the
    Pearson correlation between the ground's estimate and it over ``cell_m`` cells with
    at least ``min_records`` records (each cell: the mean of its records, binned by the
    ground's position). Returns ``{records, cells, r, truth_weh (array),
    rmse_wt_pct}``."""
    tt = np.asarray(truth_times, np.float64)
    p = np.asarray(truth_xy_yaw, np.float64)
    n = len(table)
    xt = np.interp(table.t_sample_s, tt, p[:, 0])
    yt = np.interp(table.t_sample_s, tt, p[:, 1])
    yaw = np.interp(table.t_sample_s, tt, np.unwrap(p[:, 2]))
    xd, yd = xt + config.x_m * np.cos(yaw), yt + config.x_m * np.sin(yaw)
    truth = np.array([footprint_weh(hmap, float(a), float(b), config=config)
                      for a, b in zip(xd, yd, strict=True)])  # fmt: skip
    xe = table.x_m + config.x_m * np.cos(yaw)
    ye = table.y_m + config.x_m * np.sin(yaw)
    est = grid_mean(xe, ye, table.weh_est, cell_m=cell_m)
    tru = grid_mean(xe, ye, truth, cell_m=cell_m)
    keys = sorted(k for k, (_m, c) in est.items() if c >= min_records)
    a = np.array([est[k][0] for k in keys])
    b = np.array([tru[k][0] for k in keys])
    r = float(np.corrcoef(a, b)[0, 1]) if len(keys) >= 3 and a.std() > 0 and b.std() > 0 else None
    rmse = float(np.sqrt(np.mean((a - b) ** 2))) if keys else None
    return {"records": n, "cells": len(keys), "r": r, "truth_weh": truth, "rmse_wt_pct": rmse}


def nss_map_png(path, *, logs, scenario, cell_m: float = 2.0) -> None:
    """The ground's hydrogen heat map: received NSS records averaged over ``cell_m``
    cells at the on-board estimate, with the estimated path; written atomically."""
    import os
    from pathlib import Path

    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    from lunar_drake.files import temp_sibling

    t = nss_table(logs.science_received, config=scenario.sensors.nss)
    cells = grid_mean(t.x_m, t.y_m, t.weh_est, cell_m=cell_m)
    fig = Figure(figsize=(7.5, 6.2), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    if cells:
        vals = np.array([m for m, _c in cells.values()])
        norm = Normalize(vmin=min(0.0, float(vals.min())), vmax=max(1.0, float(vals.max())))
        from matplotlib import colormaps
        from matplotlib.cm import ScalarMappable
        from matplotlib.patches import Rectangle

        cmap = colormaps["Blues"]
        for (i, j), (m, _c) in cells.items():
            ax.add_patch(Rectangle((i * cell_m, j * cell_m), cell_m, cell_m, color=cmap(norm(m))))
        fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax,
                     label="water-equivalent hydrogen (wt%, ground estimate)")  # fmt: skip
    ax.plot(t.x_m, t.y_m, "-", color="0.3", lw=0.8, label="on-board estimate")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(f"NSS on the ground: {len(t)} records, {cell_m:g} m cells")
    ax.legend(loc="upper right", fontsize=8)
    tmp = temp_sibling(Path(path))
    try:
        fig.savefig(tmp, format="png")
        os.replace(tmp, path)
    finally:
        if Path(tmp).exists():
            Path(tmp).unlink()


__all__ = ["NSSTable", "grid_mean", "nss_map_png", "nss_table", "nss_truth"]
