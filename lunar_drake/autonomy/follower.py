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

**Heading policy** (flight ``heading``, :class:`HeadingConfig`; ``FollowerParams.heading``):
``path`` (the default) is the above: the chassis faces the direction of travel. ``sun``
(explicit steer only) decouples the two: the chassis velocity points at the aim point
(a holonomic, crab command: body ``vx, vy`` from the world-frame direction, at
``speed_mps``), and the body yaw is steered towards the heading that turns the solar
panel's normal to the Sun's azimuth, ``yaw_des = sun_azimuth - panel_azimuth_rad``, or
the feasible heading nearest it (:func:`sun_heading`), at ``yaw_gain_per_s`` times the
heading error, at most ``max_wz_radps``; beyond ``turn_in_place_rad`` of heading error it
turns in place first. Feasible: the crab angle (the leg's direction in the body frame)
within ``max_crab_rad`` of the body's +x or -x axis. The steering limit bounds it, and
so does the wheels' wrap: a wheel steers within +-90 deg, reversing its speed beyond, so
a crab angle that wanders across +-90 deg (a leg towards or away from the Sun, with the
panel on the side) flips every wheel by 180 deg at each crossing -- measured on the
``goto`` site with the crab at 89.5 deg: the flipping wheels lost 2.4 m of the 15 m and
fooled the estimate -- so ``max_crab_rad`` stays ``crab_margin_deg`` (10 deg) short of
90 deg. The Sun's azimuth (rad, counter-clockwise from the estimate frame's +x) comes
with each goto command (:class:`~lunar_drake.autonomy.commands.GotoCommand`; the ground
computes it from the ephemeris); a goto without one is followed with ``path``.
"""

# No `from __future__ import annotations`: yaml_load_typed reads HeadingConfig's real
# field types.

import dataclasses as dc
import math

import numba
import numpy as np

from lunar_drake.errors import ConfigError, check_range

#: ``flight.heading.policy`` values.
HEADING_POLICIES = ("path", "sun")


@dc.dataclass
class HeadingConfig:
    """How the chassis is pointed while the follower drives a goto (flight ``heading``).

    Attributes:
        policy: ``path`` -- face the direction of travel (pure pursuit arcs; the
            default) -- or ``sun`` -- explicit-steer rovers only: crab along the path
            while the body yaw keeps the solar panel's normal towards the Sun's
            azimuth (sent by the ground with each goto; module docstring).
        yaw_gain_per_s: ``sun``: commanded yaw rate per radian of heading error (1/s),
            capped at the follower's ``max_wz_radps``.
        crab_margin_deg: ``sun``: the crab angle is kept at least this far from
            +-90 deg, where the wheels' steering wraps (module docstring); the panel
            then loses at most ``1 - cos(margin)`` of its sunlight (1.5 % at 10 deg).
    """

    policy: str = "path"
    yaw_gain_per_s: float = 1.0
    crab_margin_deg: float = 10.0

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        if self.policy not in HEADING_POLICIES:
            raise ConfigError(
                f"policy = {self.policy!r} is unknown; choose one of {list(HEADING_POLICIES)}"
            )
        check_range("yaw_gain_per_s", self.yaw_gain_per_s, 0.0, 100.0, lo_open=True,
                    unit=" 1/s")  # fmt: skip
        check_range("crab_margin_deg", self.crab_margin_deg, 0.0, 45.0, unit=" deg")


@dc.dataclass(frozen=True)
class FollowerParams:
    """Pure-pursuit settings (m, m/s, rad/s, rad).

    ``heading`` (:data:`HEADING_POLICIES`), ``yaw_gain_per_s``: the heading policy
    (:class:`HeadingConfig`). ``panel_azimuth_rad``: the solar panel normal's azimuth in
    the chassis frame (``rover.description.solar_panel_azimuth_rad``). ``max_crab_rad``:
    the largest crab angle (direction of travel off the body's +x, or off -x driving
    backwards) the ``sun`` policy drives: the steering limit, less a margin from pi/2
    (the wheels' wrap; module docstring); pi/2 or more allows any.
    """

    lookahead_m: float = 1.5
    max_wz_radps: float = 0.2
    turn_in_place_rad: float = math.radians(50.0)
    min_speed_fraction: float = 0.3
    crab_gain_per_s: float = 0.0
    max_crab_fraction: float = 0.5
    heading: str = "path"
    yaw_gain_per_s: float = 1.0
    panel_azimuth_rad: float = 0.0
    max_crab_rad: float = math.radians(80.0)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def aim_point(xy, waypoints, index: int, lookahead_m: float) -> tuple[np.ndarray, int]:
    """(aim point, new index): ``index`` is the leg being followed (from waypoint
    ``index`` to ``index + 1``); it advances past waypoints within ``lookahead_m``. The
    aim is the first point of the remaining path at distance >= ``lookahead_m`` from
    ``xy`` (the last waypoint if none)."""
    p = np.asarray(xy, dtype=float)
    wp = np.ascontiguousarray(waypoints, dtype=float)
    if wp.ndim != 2 or wp.shape[0] < 1 or wp.shape[1] != 2:
        raise ConfigError(f"waypoints have shape {wp.shape}; a path of (n >= 1, 2) is required")
    ax, ay, k = _aim_point(float(p[0]), float(p[1]), wp, int(index), float(lookahead_m))
    return np.array([ax, ay]), k


@numba.njit(cache=True)
def _aim_point(px, py, wp, index, lookahead_m):  # pragma: no cover - numba
    """:func:`aim_point` compiled: (aim x, aim y, new index)."""
    n = wp.shape[0]
    while index < n - 1 and math.hypot(wp[index + 1, 0] - px, wp[index + 1, 1] - py) < lookahead_m:
        index += 1
    for k in range(index, n - 1):
        ax, ay = wp[k, 0], wp[k, 1]
        # Where the leg a->b leaves the circle of radius lookahead around p.
        dx, dy = wp[k + 1, 0] - ax, wp[k + 1, 1] - ay
        fx, fy = ax - px, ay - py
        A = dx * dx + dy * dy
        if A == 0.0:
            continue
        B = 2.0 * (fx * dx + fy * dy)
        C = (fx * fx + fy * fy) - lookahead_m**2
        disc = B * B - 4.0 * A * C
        if disc < 0.0:
            continue
        t = (-B + math.sqrt(disc)) / (2.0 * A)
        if 0.0 <= t <= 1.0:
            return ax + t * dx, ay + t * dy, k
    return wp[n - 1, 0], wp[n - 1, 1], max(index, n - 2 if n >= 2 else 0)


def sun_heading(leg_rad: float, yaw_des_rad: float, max_crab_rad: float) -> float:
    """The body yaw (rad, in [-pi, pi)) the ``sun`` policy holds on a leg heading
    ``leg_rad`` (world frame) when the panel wants ``yaw_des_rad``.

    The crab angle ``yaw_des`` needs is ``beta = leg - yaw_des``; the wheels drive it when
    ``|beta| <= max_crab_rad`` (forwards) or ``|beta| >= pi - max_crab_rad`` (backwards),
    and then the yaw is ``yaw_des`` (``max_crab_rad >= pi/2``: always). Otherwise the
    rover drives that leg at the feasible crab angle nearest ``beta`` -- the largest one
    on that side, forwards or backwards -- i.e. at the feasible yaw nearest ``yaw_des``,
    which leaves the panel the most sunlight it can have on that leg (its normal
    ``|beta| - max_crab_rad`` or ``pi - max_crab_rad - |beta|`` off the Sun's azimuth).
    The panel has one active face, so the turned-round heading ``yaw_des + pi`` is the
    worst choice, never a compromise. The leg's heading, not the pure-pursuit aim,
    decides, so the choice does not flicker with the aim.
    """
    yaw_des = _wrap(yaw_des_rad)
    lim = float(max_crab_rad)
    if lim >= 0.5 * math.pi:
        return yaw_des
    beta = _wrap(leg_rad - yaw_des)
    if abs(beta) <= lim or abs(beta) >= math.pi - lim:
        return yaw_des
    feasible = (lim, -lim, math.pi - lim, lim - math.pi)
    best = min(feasible, key=lambda b: abs(_wrap(b - beta)))
    return _wrap(leg_rad - best)


def follow_step(pose, waypoints, index: int, *, speed_mps: float, tolerance_m: float,
                params: FollowerParams | None = None,
                sun_azimuth_rad: float | None = None):  # fmt: skip
    """(twist (vx, vy, wz), new index, done) for the estimated ``pose`` (x, y, yaw).

    ``sun_azimuth_rad``: the Sun's azimuth (rad, counter-clockwise from the estimate
    frame's +x); with ``params.heading == "sun"`` the follower crabs along the path and
    steers the yaw to :func:`sun_heading` (module docstring); without it, or with
    ``path``, it faces the direction of travel.
    """
    params = params or FollowerParams()
    x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2])
    wp = np.ascontiguousarray(waypoints, dtype=float)
    if wp.ndim != 2 or wp.shape[0] < 1 or wp.shape[1] != 2:
        raise ConfigError(f"waypoints have shape {wp.shape}; a path of (n >= 1, 2) is required")
    p = params
    if p.heading != "sun" or sun_azimuth_rad is None:
        vx, vy, wz, index, done = _path_step(
            x, y, yaw, wp, int(index), float(speed_mps), float(tolerance_m),
            float(p.lookahead_m), float(p.turn_in_place_rad), float(p.max_wz_radps),
            float(p.min_speed_fraction), float(p.crab_gain_per_s), float(p.max_crab_fraction),
        )  # fmt: skip
        return np.array([vx, vy, wz]), index, done
    if math.hypot(wp[-1, 0] - x, wp[-1, 1] - y) <= tolerance_m:
        return np.zeros(3), len(wp) - 1, True
    ax, ay, index = _aim_point(x, y, wp, int(index), float(p.lookahead_m))
    dx, dy = ax - x, ay - y
    leg = wp[min(index + 1, len(wp) - 1)] - wp[index]
    leg_rad = math.atan2(leg[1], leg[0]) if np.any(leg != 0.0) else math.atan2(dy, dx)
    twist = _sun_step(p, yaw, math.atan2(dy, dx), leg_rad, float(sun_azimuth_rad), speed_mps)
    return twist, index, False


@numba.njit(cache=True)
def _path_step(x, y, yaw, wp, index, speed_mps, tolerance_m, lookahead_m, turn_in_place_rad,
               max_wz_radps, min_speed_fraction, crab_gain_per_s,
               max_crab_fraction):  # pragma: no cover  # fmt: skip
    """The ``path`` policy's step of :func:`follow_step`, compiled:
    (vx, vy, wz, new index, done)."""
    n = wp.shape[0]
    if math.hypot(wp[n - 1, 0] - x, wp[n - 1, 1] - y) <= tolerance_m:
        return 0.0, 0.0, 0.0, n - 1, True
    ax, ay, index = _aim_point(x, y, wp, index, lookahead_m)
    dx, dy = ax - x, ay - y
    d = max(math.hypot(dx, dy), 1e-6)
    alpha = (math.atan2(dy, dx) - yaw + math.pi) % (2.0 * math.pi) - math.pi  # _wrap
    if abs(alpha) > turn_in_place_rad:
        return 0.0, 0.0, math.copysign(max_wz_radps, alpha), index, False
    v = speed_mps * max(math.cos(alpha), min_speed_fraction)
    wz = 2.0 * v * math.sin(alpha) / d
    wz = max(-max_wz_radps, min(max_wz_radps, wz))
    vy = 0.0
    if crab_gain_per_s > 0.0 and n >= 2:
        e, heading = _cross_track(x, y, wp)
        # The path's left normal in the body frame (its y component).
        ny = math.cos(heading - yaw)
        lim = max_crab_fraction * v
        vy = max(-lim, min(lim, -crab_gain_per_s * e * ny))
    return v, vy, wz, index, False


def _sun_step(params: FollowerParams, yaw: float, course: float, leg: float,
              sun_azimuth: float, speed_mps: float) -> np.ndarray:  # fmt: skip
    """The ``sun`` policy's twist: translate along ``course`` (towards the aim, world
    frame) at ``speed_mps``, turn towards :func:`sun_heading` on the ``leg`` heading;
    turn in place first when the heading error exceeds ``turn_in_place_rad``."""
    target = sun_heading(leg, sun_azimuth - params.panel_azimuth_rad, params.max_crab_rad)
    err = _wrap(target - yaw)
    if abs(err) > params.turn_in_place_rad:
        return np.array([0.0, 0.0, math.copysign(params.max_wz_radps, err)])
    wz = max(-params.max_wz_radps, min(params.max_wz_radps, params.yaw_gain_per_s * err))
    beta = course - yaw  # the crab angle: the direction of travel in the body frame
    return np.array([speed_mps * math.cos(beta), speed_mps * math.sin(beta), wz])


def cross_track(xy, waypoints) -> tuple[float, float]:
    """(signed distance m, positive left of the path; heading rad) of the path segment
    nearest ``xy`` (clamped projection: near a corner, the leg the rover is on)."""
    p = np.asarray(xy, dtype=float)
    wp = np.ascontiguousarray(waypoints, dtype=float)
    if wp.ndim != 2 or wp.shape[0] < 2 or wp.shape[1] != 2:
        raise ConfigError(f"waypoints have shape {wp.shape}; a path of (n >= 2, 2) is required")
    e, heading = _cross_track(float(p[0]), float(p[1]), wp)
    return float(e), float(heading)


@numba.njit(cache=True)
def _cross_track(px, py, wp):  # pragma: no cover - numba
    """:func:`cross_track` over the legs of ``wp`` (n, 2): the clamped projection on
    each leg, the first nearest (the same operations as a vectorized numpy pass)."""
    best = np.inf
    k = 0
    for i in range(wp.shape[0] - 1):
        dx = wp[i + 1, 0] - wp[i, 0]
        dy = wp[i + 1, 1] - wp[i, 1]
        L2 = max(dx * dx + dy * dy, 1e-18)
        t = min(max(((px - wp[i, 0]) * dx + (py - wp[i, 1]) * dy) / L2, 0.0), 1.0)
        dist = np.hypot(wp[i, 0] + t * dx - px, wp[i, 1] + t * dy - py)
        if dist < best or i == 0:
            best = dist
            k = i
    dx = wp[k + 1, 0] - wp[k, 0]
    dy = wp[k + 1, 1] - wp[k, 1]
    n = math.sqrt(max(dx * dx + dy * dy, 1e-18))
    return (dx * (py - wp[k, 1]) - dy * (px - wp[k, 0])) / n, math.atan2(dy, dx)


__all__ = [
    "HEADING_POLICIES",
    "FollowerParams",
    "HeadingConfig",
    "aim_point",
    "cross_track",
    "follow_step",
    "sun_heading",
]
