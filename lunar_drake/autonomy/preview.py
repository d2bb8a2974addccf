"""Command preview: the ground runs its copy of the on-board path follower forward on its
own map, from its own pose estimate, before a drive goes up. Pure; no Drake.

:func:`preview_goto` steps the flight software's follower
(:func:`~lunar_drake.autonomy.follower.follow_step`, the same code and parameters the
rover runs) at the flight rate and integrates the commanded twist exactly (each tick an
arc of constant twist: the rover model as the ground knows it, wheels that do not slip),
with heights from the ground's map. The result is what the operator is about to command:
where the rover should go if the estimate and the map are right and the wheels grip.
It ignores slip, the estimate's drift and the link delay (the rover waits for the
command).
"""

from __future__ import annotations

import math

import numpy as np

from lunar_drake.autonomy.follower import FollowerParams, follow_step


def _arc(x: float, y: float, yaw: float, vx: float, vy: float, wz: float, dt: float):
    """The pose after ``dt`` s of a constant chassis twist (exact)."""
    dyaw = wz * dt
    if abs(dyaw) < 1e-9:
        fx, fy = vx * dt, vy * dt
    else:
        s, c = math.sin(dyaw), 1.0 - math.cos(dyaw)
        fx = (vx * s - vy * c) / wz
        fy = (vx * c + vy * s) / wz
    cy, sy = math.cos(yaw), math.sin(yaw)
    return x + fx * cy - fy * sy, y + fx * sy + fy * cy, yaw + dyaw


def preview_goto(*, pose, waypoints, speed_mps: float, tolerance_m: float, rate_hz: float,
                 params: FollowerParams | None = None, height=None, max_time_s: float = 3600.0,
                 every_s: float = 0.5,
                 sun_azimuth_rad: float | None = None) -> np.ndarray:  # fmt: skip
    """The predicted path (N, 4): (t s, x, y, z m) every ``every_s`` from ``pose`` (x, y,
    yaw; m, rad, site frame) following ``waypoints`` ((x, y), ...) until the follower says
    done or ``max_time_s``. ``height(x, y)`` gives z (the ground's map; 0 without).
    ``sun_azimuth_rad``: the Sun's azimuth the goto carries (the ``sun`` heading
    policy; site frame), or None."""
    wp = np.asarray(waypoints, np.float64).reshape(-1, 2)
    x, y, yaw = (float(v) for v in pose)
    dt = 1.0 / float(rate_hz)
    keep = max(round(every_s / dt), 1)
    out = [(0.0, x, y)]
    index, k = 0, 0
    while k * dt < max_time_s:
        twist, index, done = follow_step((x, y, yaw), wp, index, speed_mps=speed_mps,
                                         tolerance_m=tolerance_m, params=params,
                                         sun_azimuth_rad=sun_azimuth_rad)  # fmt: skip
        if done:
            break
        x, y, yaw = _arc(x, y, yaw, *(float(v) for v in twist), dt)
        k += 1
        if k % keep == 0:
            out.append((k * dt, x, y))
    if out[-1][0] != k * dt:
        out.append((k * dt, x, y))
    a = np.array(out)
    z = np.zeros(len(a)) if height is None else np.asarray(height(a[:, 1], a[:, 2]), float)
    return np.column_stack([a, z])


__all__ = ["preview_goto"]
