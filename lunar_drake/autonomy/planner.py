"""Least-cost paths on a hazard costmap (scikit-image's minimum-cost-path search,
``skimage.graph.MCP_Geometric``: Dijkstra on the 8-connected grid with diagonal steps
weighted by sqrt(2)), simplified to waypoints. Pure; no Drake."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
from skimage.graph import MCP_Geometric

from lunar_drake.autonomy.costmap import Costmap
from lunar_drake.errors import LunarDrakeError, OutOfBoundsError, OutOfRangeError


class PlanningError(LunarDrakeError, ValueError):
    """A goal the planner cannot serve: inside a hazard, or unreachable."""


@dc.dataclass(frozen=True)
class Path:
    """A planned path: ``waypoints_xy`` (k, 2) site coordinates (m) from the start to the
    goal (the grid path string-pulled: straight legs over free cells), ``cells`` (n, 2)
    the full grid path (row, col), ``cost`` (the path integral of the cost per metre),
    ``length_m`` (of the grid path)."""

    waypoints_xy: np.ndarray
    cells: np.ndarray
    cost: float
    length_m: float


def _cell(costmap: Costmap, xy, what: str) -> tuple:
    x, y = (float(v) for v in xy)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise OutOfRangeError(f"{what} = ({x!r}, {y!r}) m must be finite site coordinates")
    r, c = costmap.cell_of(x, y)
    if not costmap.inside(r, c):
        raise OutOfBoundsError(
            f"{what} ({x:.2f}, {y:.2f}) m is off the map: {costmap.extent_text()}"
        )
    return r, c


def _segment_free(costmap: Costmap, a, b) -> bool:
    """True if the straight segment between cells ``a`` and ``b`` crosses no lethal cell."""
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]))) * 2 + 1
    rr = np.rint(np.linspace(a[0], b[0], n)).astype(int)
    cc = np.rint(np.linspace(a[1], b[1], n)).astype(int)
    return bool(np.isfinite(costmap.cost[rr, cc]).all())


def _simplify(costmap: Costmap, cells: np.ndarray) -> np.ndarray:
    """String pulling: from each kept cell, the farthest later cell of the path reachable
    by a straight segment over free cells (greedy, forward) becomes the next waypoint."""
    out = [cells[0]]
    i, n = 0, len(cells)
    while i < n - 1:
        j = i + 1
        while j + 1 < n and _segment_free(costmap, cells[i], cells[j + 1]):
            j += 1
        out.append(cells[j])
        i = j
    return np.array(out)


def nearest_free_cell(costmap: Costmap, cell, radius_m: float):
    """The free (finite-cost) cell nearest ``cell`` (row, col) within ``radius_m`` (cell
    centres; the lowest cost among equals), or None."""
    k = math.ceil(radius_m / costmap.resolution_m)
    r0, r1 = max(0, cell[0] - k), min(costmap.shape[0], cell[0] + k + 1)
    c0, c1 = max(0, cell[1] - k), min(costmap.shape[1], cell[1] + k + 1)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    d = np.hypot(rr - cell[0], cc - cell[1]) * costmap.resolution_m
    ok = np.isfinite(costmap.cost[r0:r1, c0:c1]) & (d <= radius_m + 1e-9)
    if not ok.any():
        return None
    i = np.lexsort((costmap.cost[r0:r1, c0:c1][ok], d[ok]))[0]
    return int(rr[ok][i]), int(cc[ok][i])


def _what_breaks(costmap: Costmap, cell, subject: str) -> str:
    """``subject`` and what makes the hazard ``cell`` (row, col) lethal: the limits its
    layers break, or (none: a stereo hazard by stereo's own rule, a hand-made map) that
    it is marked lethal, with its layers."""
    slope, step = float(costmap.slope_deg[cell]), float(costmap.step_m[cell])
    broken = []
    if slope > costmap.max_slope_deg:
        broken.append(f"slope {slope:.1f} deg > max {costmap.max_slope_deg:g} deg")
    if step > costmap.max_step_m:
        broken.append(f"step {step:.2f} m > max {costmap.max_step_m:.2f} m")
    if broken:
        return f"{subject} breaks {' and '.join(broken)}"
    return f"{subject} is marked lethal (slope {slope:.1f} deg, step {step:.2f} m)"


def hazard_reason(costmap: Costmap, cell) -> str:
    """Why the lethal ``cell`` (row, col) of ``costmap`` is lethal, in words: the
    limit(s) the cell breaks; steep on the orbital map and not yet seen by stereo; or
    the nearest hazard within the rover's footprint plus inflation
    (``costmap.inflation_radius_m``), where it is and what it breaks."""
    cell = (int(cell[0]), int(cell[1]))
    unconfirmed = costmap.unconfirmed
    if costmap.lethal_raw[cell]:
        if unconfirmed is not None and unconfirmed[cell]:
            return (
                f"slope {costmap.slope_deg[cell]:.1f} deg on the orbital map, over "
                "ground.map.confirm_slope_deg: lethal until stereo has seen it; choose "
                "another goal, or set confirm_slope_deg: 0 to trust the orbital map"
            )
        return _what_breaks(costmap, cell, "its cell")
    res = costmap.resolution_m
    k = math.ceil(costmap.inflation_radius_m / res) + 1
    r0, r1 = max(0, cell[0] - k), min(costmap.shape[0], cell[0] + k + 1)
    c0, c1 = max(0, cell[1] - k), min(costmap.shape[1], cell[1] + k + 1)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    d = np.hypot(rr - cell[0], cc - cell[1]) * res
    d = np.where(costmap.lethal_raw[r0:r1, c0:c1], d, np.inf)
    i = np.unravel_index(int(np.argmin(d)), d.shape)
    if not np.isfinite(d[i]):
        return "lethal, with no hazard near it (a hand-made map?)"
    h = (int(rr[i]), int(cc[i]))
    hx, hy = (float(v) for v in costmap.centre_of(*h))
    if unconfirmed is not None and unconfirmed[h]:
        what = (f"steep on the orbital map ({costmap.slope_deg[h]:.1f} deg, over "
                "ground.map.confirm_slope_deg), lethal until stereo has seen it")  # fmt: skip
    else:
        what = _what_breaks(costmap, h, "which")
    return (
        f"within the rover's footprint plus inflation ({costmap.inflation_radius_m:.2f} m) "
        f"of a hazard {d[i]:.2f} m away at ({hx:.2f}, {hy:.2f}) m, {what}"
    )


def plan_path(*, costmap: Costmap, start_xy, goal_xy, start_free_radius_m: float = 0.0,
              goal_free_radius_m: float = 0.0) -> Path:  # fmt: skip
    """The least-cost path from ``start_xy`` to ``goal_xy`` (site, m).

    The rover may stand in a hazard's inflation (an estimate near a rock, a replan after
    safing): its own cell, and lethal cells within ``start_free_radius_m`` of the start,
    cost 50 per metre instead of lethal, so the path leaves them by the shortest way. A
    goal inside a hazard is moved to the nearest free cell within
    ``goal_free_radius_m`` (the path then ends at that cell's centre: the rover parks
    beside a rock found next to its goal).

    Raises:
        OutOfBoundsError: start or goal off the map.
        PlanningError: goal (or start) inside a hazard (lethal or within the rover's
            footprint of one; the message says which limit: :func:`hazard_reason`) with
            no free cell within ``goal_free_radius_m``, or no hazard-free path joins
            them.
    """
    s = _cell(costmap, start_xy, "start")
    g = _cell(costmap, goal_xy, "goal")
    end_xy = (float(goal_xy[0]), float(goal_xy[1]))
    if not np.isfinite(costmap.cost[g]):
        moved = nearest_free_cell(costmap, g, goal_free_radius_m) if goal_free_radius_m else None
        if moved is None:
            near = f" and no free cell lies within {goal_free_radius_m:g} m of it"
            raise PlanningError(
                f"goal ({float(goal_xy[0]):.2f}, {float(goal_xy[1]):.2f}) m is inside a hazard "
                f"({hazard_reason(costmap, g)})" + (near if goal_free_radius_m else "")
            )
        g = moved
        end_xy = tuple(float(v) for v in costmap.centre_of(*g))
    cost = costmap.cost
    k = math.ceil(start_free_radius_m / costmap.resolution_m)
    r0, r1 = max(0, s[0] - k), min(cost.shape[0], s[0] + k + 1)
    c0, c1 = max(0, s[1] - k), min(cost.shape[1], s[1] + k + 1)
    win = cost[r0:r1, c0:c1]
    rr, cc = np.mgrid[r0:r1, c0:c1]
    near = np.hypot(rr - s[0], cc - s[1]) * costmap.resolution_m <= start_free_radius_m
    if not np.isfinite(win[near]).all() or not np.isfinite(cost[s]):
        cost = cost.copy()
        sub = cost[r0:r1, c0:c1]
        sub[near & ~np.isfinite(sub)] = 50.0
        if not np.isfinite(cost[s]):
            cost[s] = 50.0
    mcp = MCP_Geometric(cost, fully_connected=True)
    cum, _ = mcp.find_costs([s], [g])
    if not np.isfinite(cum[g]):
        raise PlanningError(
            f"no hazard-free path from ({float(start_xy[0]):.2f}, {float(start_xy[1]):.2f}) "
            f"to ({float(goal_xy[0]):.2f}, {float(goal_xy[1]):.2f}) m on this map"
        )
    cells = np.array(mcp.traceback(g), dtype=int)
    res = costmap.resolution_m
    pts = _simplify(costmap, cells)
    x, y = costmap.centre_of(pts[:, 0], pts[:, 1])
    wp = np.column_stack([x, y])
    wp[0] = [float(start_xy[0]), float(start_xy[1])]
    wp[-1] = end_xy
    steps = np.diff(cells, axis=0)
    length = float(np.sum(np.hypot(steps[:, 0], steps[:, 1]))) * res
    return Path(waypoints_xy=wp, cells=cells, cost=float(cum[g]) * res, length_m=length)


def path_blocked(*, costmap: Costmap, path_xy, from_xy, free_radius_m: float = 1.0,
                 lookahead_m: float = 20.0) -> bool:  # fmt: skip
    """True when the rest of ``path_xy`` ((x, y), ...; site m) from the point nearest
    ``from_xy`` crosses a lethal cell within ``lookahead_m`` of path, ignoring cells
    within ``free_radius_m`` of ``from_xy`` (the rover may stand in an inflation)."""
    w = np.asarray(path_xy, np.float64).reshape(-1, 2)
    p = np.asarray(from_xy, np.float64)[:2]
    if len(w) < 2:
        return False
    a, b = w[:-1], w[1:]
    d = b - a
    L2 = np.maximum(np.sum(d * d, axis=1), 1e-12)
    t = np.clip(np.sum((p - a) * d, axis=1) / L2, 0.0, 1.0)
    q = a + t[:, None] * d
    k = int(np.argmin(np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])))
    rest = np.vstack([q[k], w[k + 1 :]])
    seg = np.diff(rest, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    step = 0.5 * costmap.resolution_m
    travelled = 0.0
    for (x0, y0), (dx, dy), length in zip(rest[:-1], seg, lengths, strict=True):
        n = max(math.ceil(length / step), 1)
        s_ = np.linspace(0.0, 1.0, n + 1)
        xs, ys = x0 + s_ * dx, y0 + s_ * dy
        along = travelled + s_ * length
        keep = (along <= lookahead_m) & (np.hypot(xs - p[0], ys - p[1]) > free_radius_m)
        for x, y in zip(xs[keep], ys[keep], strict=True):
            r, c = costmap.cell_of(float(x), float(y))
            if costmap.inside(r, c) and not np.isfinite(costmap.cost[r, c]):
                return True
        travelled += length
        if travelled > lookahead_m:
            break
    return False


def draw_unconfirmed(ax, unconfirmed, *, extent) -> None:
    """Purple over the ``unconfirmed`` cells (bool (rows, cols) or None; steep orbital
    cells stereo has not yet seen) of a costmap drawn with ``extent``."""
    if unconfirmed is None or not np.any(unconfirmed):
        return
    mask = np.ma.masked_where(~np.asarray(unconfirmed, bool), np.ones(np.shape(unconfirmed)))
    ax.imshow(mask, extent=extent, cmap="Purples", vmin=0.0, vmax=1.0, origin="upper",
              alpha=0.7, interpolation="nearest")  # fmt: skip


def plot_plan(costmap: Costmap, path: Path | None, *, ax, title: str = "") -> None:
    """Draws the costmap (grey: cost, red: lethal, purple: unconfirmed) and the path on
    a matplotlib axis."""
    rows, cols = costmap.shape
    res = costmap.resolution_m
    extent = (costmap.x0_m, costmap.x0_m + cols * res, costmap.y1_m - rows * res, costmap.y1_m)
    finite = np.where(np.isfinite(costmap.cost), costmap.cost, np.nan)
    im = ax.imshow(finite, extent=extent, cmap="Greys", origin="upper")
    ax.figure.colorbar(im, ax=ax, shrink=0.8, label="cost per metre (free cells)")
    lethal = np.ma.masked_where(np.isfinite(costmap.cost), np.ones(costmap.shape))
    ax.imshow(lethal, extent=extent, cmap="autumn", origin="upper", alpha=0.6)
    draw_unconfirmed(ax, costmap.unconfirmed, extent=extent)
    if path is not None:
        ax.plot(path.waypoints_xy[:, 0], path.waypoints_xy[:, 1], "c.-", lw=1.5)
        ax.plot(*path.waypoints_xy[0], "go")
        ax.plot(*path.waypoints_xy[-1], "b*", ms=10)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    if title:
        ax.set_title(title)
    ax.set_aspect("equal")


__all__ = [
    "Path",
    "PlanningError",
    "draw_unconfirmed",
    "nearest_free_cell",
    "path_blocked",
    "plan_path",
    "plot_plan",
]
