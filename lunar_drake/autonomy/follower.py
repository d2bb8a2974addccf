"""Waypoint following on board (pure pursuit on the pose estimate). Pure; no Drake.

Given the estimated pose (x, y, yaw) and a path of waypoints, :func:`follow_step`
returns a chassis twist: it aims at the point ``lookahead_m`` ahead along the path
(the first leg point that far from the rover), turns in place when that point lies more
than ``turn_in_place_rad`` off the heading, and otherwise drives an arc of curvature
``2 sin(alpha) / d`` (pure pursuit; ``alpha`` the bearing of the aim point, ``d`` its
distance) at ``speed_mps`` times ``cos(alpha)``. Both steering kinds drive arcs and turn
in place (the rover kinematics turn a twist into wheel speeds and steering angles); an
explicit-steer rover also **crabs** (``crab_gain_per_s`` > 0): a sideways velocity
``-crab_gain_per_s * e`` (``e`` the signed cross-track error from the current leg, at
most ``max_crab_fraction`` of the forward speed) pulls it back onto the path without
turning. The path is done when the estimate is within ``tolerance_m`` of the last
waypoint.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np


@dc.dataclass(frozen=True)
class FollowerParams:
    """Pure-pursuit settings (m, m/s, rad/s, rad)."""

    lookahead_m: float = 1.5
    max_wz_radps: float = 0.2
    turn_in_place_rad: float = math.radians(50.0)
    min_speed_fraction: float = 0.3
    crab_gain_per_s: float = 0.0
    max_crab_fraction: float = 0.5


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def aim_point(xy, waypoints, index: int, lookahead_m: float) -> tuple[np.ndarray, int]:
    """(aim point, new index): ``index`` is the leg being followed (from waypoint
    ``index`` to ``index + 1``); it advances past waypoints within ``lookahead_m``. The
    aim is the first point of the remaining path at distance >= ``lookahead_m`` from
    ``xy`` (the last waypoint if none)."""
    p = np.asarray(xy, dtype=float)
    wp = np.asarray(waypoints, dtype=float)
    n = len(wp)
    while index < n - 1 and np.hypot(*(wp[index + 1] - p)) < lookahead_m:
        index += 1
    for k in range(index, n - 1):
        a, b = wp[k], wp[k + 1]
        # Where the leg a->b leaves the circle of radius lookahead around p.
        d = b - a
        f = a - p
        A = float(d @ d)
        if A == 0.0:
            continue
        B = 2.0 * float(f @ d)
        C = float(f @ f) - lookahead_m**2
        disc = B * B - 4.0 * A * C
        if disc < 0.0:
            continue
        t = (-B + math.sqrt(disc)) / (2.0 * A)
        if 0.0 <= t <= 1.0:
            return a + t * d, k
    return wp[-1].copy(), max(index, n - 2 if n >= 2 else 0)


def follow_step(pose, waypoints, index: int, *, speed_mps: float, tolerance_m: float,
                params: FollowerParams | None = None):  # fmt: skip
    """(twist (vx, vy, wz), new index, done) for the estimated ``pose`` (x, y, yaw)."""
    params = params or FollowerParams()
    x, y, yaw = (float(v) for v in pose)
    wp = np.asarray(waypoints, dtype=float)
    if np.hypot(wp[-1, 0] - x, wp[-1, 1] - y) <= tolerance_m:
        return np.zeros(3), len(wp) - 1, True
    aim, index = aim_point((x, y), wp, index, params.lookahead_m)
    dx, dy = aim[0] - x, aim[1] - y
    d = max(math.hypot(dx, dy), 1e-6)
    alpha = _wrap(math.atan2(dy, dx) - yaw)
    if abs(alpha) > params.turn_in_place_rad:
        return np.array([0.0, 0.0, math.copysign(params.max_wz_radps, alpha)]), index, False
    v = speed_mps * max(math.cos(alpha), params.min_speed_fraction)
    wz = 2.0 * v * math.sin(alpha) / d
    wz = max(-params.max_wz_radps, min(params.max_wz_radps, wz))
    vy = 0.0
    if params.crab_gain_per_s > 0.0 and len(wp) >= 2:
        e, heading = cross_track((x, y), wp)
        # The path's left normal in the body frame (its y component).
        ny = math.cos(heading - yaw)
        lim = params.max_crab_fraction * v
        vy = max(-lim, min(lim, -params.crab_gain_per_s * e * ny))
    return np.array([v, vy, wz]), index, False


def cross_track(xy, waypoints) -> tuple[float, float]:
    """(signed distance m, positive left of the path; heading rad) of the path segment
    nearest ``xy`` (clamped projection: near a corner, the leg the rover is on)."""
    p = np.asarray(xy, dtype=float)
    wp = np.asarray(waypoints, dtype=float)
    a, b = wp[:-1], wp[1:]
    d = b - a
    L2 = np.maximum(np.sum(d * d, axis=1), 1e-18)
    t = np.clip(np.sum((p - a) * d, axis=1) / L2, 0.0, 1.0)
    q = a + t[:, None] * d
    k = int(np.argmin(np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])))
    n = math.sqrt(float(L2[k]))
    e = (d[k, 0] * (p[1] - a[k, 1]) - d[k, 1] * (p[0] - a[k, 0])) / n
    return float(e), math.atan2(d[k, 1], d[k, 0])


__all__ = ["FollowerParams", "aim_point", "cross_track", "follow_step"]
