"""``ground_map.png``: the map the ground ended a run with, for people to look at.

The ground's final costmap around the traverse (grey: cost per metre of free cells;
orange: the a-priori map's hazards, inflated by the rover's footprint; red: the hazards
its stereo found, inflated; purple: the orbital map's steep cells stereo has not yet
seen, lethal until it does), the rover's true path (black on white), the ground's own
pose estimate (magenta, dashed, drawn over the truth; VO-corrected when its perception
runs), its stereo keyframes (hollow; green: VO fused, gold: gated, blue x: rejected)
and the goals (blue stars), with the legend beside the map. Without ground perception (no
cameras) the map is the a-priori one. Matplotlib without pyplot (no backend forced on
the caller); the PNG carries no software tag, so the same run gives the same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_path

#: Keyframe markers (hollow) by VO outcome: (marker, colour).
VO_MARKERS = {"accepted": ("o", "tab:green"), "gated": ("s", "gold"), "rejected": ("x", "blue")}
#: Hazard colours: the a-priori map's, stereo's, and unconfirmed steep orbital cells.
MAP_HAZARD = "tab:orange"
STEREO_HAZARD = "red"
UNCONFIRMED = "tab:purple"


def hazard_classes(final, prior=None) -> dict:
    """Boolean (rows, cols) masks of the ``final`` costmap's lethal cells by origin:
    ``map`` (lethal in the a-priori ``prior`` too), ``stereo`` (lethal only since
    stereo: free in ``prior``), ``unconfirmed`` (``final.unconfirmed``). Without a
    ``prior`` on the same grid every lethal cell counts as the map's."""
    lethal = ~np.isfinite(final.cost)
    unconfirmed = (
        np.zeros(lethal.shape, bool)
        if final.unconfirmed is None
        else np.asarray(final.unconfirmed, bool)
    )
    if prior is not None and np.shape(prior.cost) == lethal.shape:
        stereo = lethal & np.isfinite(prior.cost)
    else:
        stereo = np.zeros(lethal.shape, bool)
    return {"map": lethal & ~stereo & ~unconfirmed, "stereo": stereo, "unconfirmed": unconfirmed}


def _overlay(ax, mask, colour, *, extent, alpha):
    if not mask.any():
        return
    from matplotlib.colors import ListedColormap

    ax.imshow(np.ma.masked_where(~mask, np.ones(mask.shape)), extent=extent,
              cmap=ListedColormap([colour]), vmin=0.0, vmax=1.0, origin="upper",
              alpha=alpha, interpolation="nearest")  # fmt: skip


def write_ground_map(path, *, logs, scenario, margin_m: float = 8.0) -> Path | None:
    """Writes ``path`` (PNG) from a run's ``logs`` (:class:`~lunar_drake.simulation.
    SimulationLogs` with a ``ground_costmap``, and ``ground_prior_costmap`` to tell the
    stereo hazards from the map's) and its ``scenario``; the view is the traverse and
    the goals with ``margin_m`` (m) round them. Returns the path, or None when the run
    kept no ground costmap."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    cm = logs.ground_costmap
    if cm is None:
        return None
    truth = np.asarray(logs.vectors["truth.pose"].data)[:, :2]
    est = logs.vectors.get("ground.pose_estimate")
    est_xy = np.asarray(est.data)[:, :2] if est is not None else np.zeros((0, 2))
    goals = np.array([(g.x_m, g.y_m) for g in scenario.ground.goals]).reshape(-1, 2)
    pts = np.vstack([truth, est_xy, goals])
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0) - margin_m, pts.max(axis=0) + margin_m
    res = cm.resolution_m
    rows, cols = cm.shape
    c0 = int(np.clip(np.floor((lo[0] - cm.x0_m) / res), 0, cols - 1))
    c1 = int(np.clip(np.ceil((hi[0] - cm.x0_m) / res), c0 + 1, cols))
    r0 = int(np.clip(np.floor((cm.y1_m - hi[1]) / res), 0, rows - 1))
    r1 = int(np.clip(np.ceil((cm.y1_m - lo[1]) / res), r0 + 1, rows))
    cost = cm.cost[r0:r1, c0:c1]
    extent = (cm.x0_m + c0 * res, cm.x0_m + c1 * res, cm.y1_m - r1 * res, cm.y1_m - r0 * res)
    aspect = (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9)
    # The map 8 in wide, the legend in a column to its right.
    fig = Figure(figsize=(11.0, float(np.clip(8.0 * aspect + 1.2, 4.5, 11.0))),
                 layout="constrained")  # fmt: skip
    ax = fig.subplots()
    finite = np.where(np.isfinite(cost), cost, np.nan)
    grey = ax.imshow(finite, extent=extent, cmap="Greys", origin="upper",
                     interpolation="nearest")  # fmt: skip
    # The grey scale is the planner's cost per metre of the free cells (1: level and
    # smooth; slope, steps and roughness raise it); lethal cells are left white under
    # their hazard colour.
    fig.colorbar(grey, ax=ax, shrink=0.5, pad=0.01,
                 label="planner cost per metre (free cells; 1 = level, smooth)")  # fmt: skip
    classes = hazard_classes(cm, getattr(logs, "ground_prior_costmap", None))
    classes = {k: v[r0:r1, c0:c1] for k, v in classes.items()}
    handles = []
    for key, colour, alpha, label in (
        ("map", MAP_HAZARD, 0.55, "hazard on the a-priori map (inflated)"),
        ("stereo", STEREO_HAZARD, 0.8, "hazard found by stereo (inflated)"),
        ("unconfirmed", UNCONFIRMED, 0.7, "steep on the orbital map, not yet seen"),
    ):
        if classes[key].any():
            _overlay(ax, classes[key], colour, extent=extent, alpha=alpha)
            handles.append(Patch(facecolor=colour, alpha=alpha, label=label))
    # The truth wide (black on a white halo), the estimate thin and dashed over it: both
    # show where they coincide.
    ax.plot(truth[:, 0], truth[:, 1], color="white", lw=4.5, zorder=3)
    (line,) = ax.plot(truth[:, 0], truth[:, 1], color="black", lw=2.5, zorder=3,
                      label="true path")  # fmt: skip
    handles.insert(0, line)
    if len(est_xy):
        (line,) = ax.plot(est_xy[:, 0], est_xy[:, 1], color="magenta", lw=1.4,
                          ls=(0, (3, 2)), zorder=5, label="ground's estimate")  # fmt: skip
        handles.insert(1, line)
    for kind, (marker, colour) in VO_MARKERS.items():
        k = [(r.x_m, r.y_m) for r in logs.keyframes if r.vo == kind]
        if k:
            k = np.array(k)
            (m,) = ax.plot(k[:, 0], k[:, 1], marker, ms=5, mfc="none", mec=colour,
                           mew=1.2, ls="none", zorder=4, label=f"keyframe: VO {kind}")  # fmt: skip
            handles.append(m)
    if len(goals):
        (g,) = ax.plot(goals[:, 0], goals[:, 1], "*", ms=14, color="tab:blue", mec="white",
                       ls="none", zorder=6, label="goals")  # fmt: skip
        handles.append(g)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_aspect("equal")
    source = scenario.ground.map.source
    ax.set_title(f"The ground's map at t = {logs.simulated_s:.0f} s ({source} a-priori map)",
                 fontsize=11)  # fmt: skip
    fig.legend(handles=handles, fontsize=8, loc="outside right upper", frameon=False)
    path = Path(path)
    with atomic_path(path, what=path.name) as tmp:
        fig.savefig(tmp, dpi=100, format="png", metadata={"Software": None})
    return path


__all__ = ["hazard_classes", "write_ground_map"]
