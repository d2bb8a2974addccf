"""``ground_map.png``: the map the ground ended a run with, for people to look at.

The ground's final costmap (the a-priori map refined, with the hazards its stereo found
merged in; grey: cost per metre, red: lethal or within the rover's footprint of a
hazard, purple: the orbital map's steep cells stereo has not yet seen, lethal until it
does) around the traverse, the rover's true path (white), the ground's own pose
estimate (cyan, dashed; VO-corrected when its perception runs), its stereo keyframes
(dots: green VO fused, orange gated, red rejected) and the goals (stars). Matplotlib
without pyplot (no backend forced on the caller); the PNG carries no software tag, so
the same run gives the same bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_path

VO_COLOURS = {"accepted": "tab:green", "gated": "tab:orange", "rejected": "tab:red"}


def write_ground_map(path, *, logs, scenario, margin_m: float = 8.0) -> Path | None:
    """Writes ``path`` (PNG) from a run's ``logs`` (:class:`~lunar_drake.simulation.
    SimulationLogs` with a ``ground_costmap``) and its ``scenario``; the view is the
    traverse and the goals with ``margin_m`` (m) round them. Returns the path, or None
    when the run kept no ground costmap."""
    from matplotlib.figure import Figure

    from lunar_drake.autonomy.planner import draw_unconfirmed

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
    fig = Figure(figsize=(8.0, float(np.clip(8.0 * aspect + 1.0, 4.0, 11.0))))
    ax = fig.subplots()
    finite = np.where(np.isfinite(cost), cost, np.nan)
    ax.imshow(finite, extent=extent, cmap="Greys", origin="upper", interpolation="nearest")
    lethal = np.ma.masked_where(np.isfinite(cost), np.ones(cost.shape))
    ax.imshow(lethal, extent=extent, cmap="autumn", origin="upper", alpha=0.6,
              interpolation="nearest")  # fmt: skip
    if cm.unconfirmed is not None:
        draw_unconfirmed(ax, cm.unconfirmed[r0:r1, c0:c1], extent=extent)
    ax.plot(truth[:, 0], truth[:, 1], color="white", lw=2.2)
    ax.plot(truth[:, 0], truth[:, 1], color="black", lw=0.8, label="truth")
    if len(est_xy):
        ax.plot(est_xy[:, 0], est_xy[:, 1], "--", color="tab:cyan", lw=1.2,
                label="ground's estimate")  # fmt: skip
    for kind, colour in VO_COLOURS.items():
        k = [(r.x_m, r.y_m) for r in logs.keyframes if r.vo == kind]
        if k:
            k = np.array(k)
            ax.plot(k[:, 0], k[:, 1], "o", ms=3.5, color=colour, label=f"keyframe: VO {kind}")
    if len(goals):
        ax.plot(goals[:, 0], goals[:, 1], "*", ms=14, color="tab:blue", mec="white",
                label="goals")  # fmt: skip
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_aspect("equal")
    title = f"The ground's map at t = {logs.simulated_s:.0f} s (red: hazards"
    if cm.unconfirmed is not None:
        title += "; purple: steep, unseen"
    ax.set_title(title + ")", fontsize=11)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path, what=path.name) as tmp:
        fig.savefig(tmp, dpi=100, format="png", metadata={"Software": None})
    return path


__all__ = ["write_ground_map"]
