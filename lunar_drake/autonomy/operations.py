"""Ground operations: goals, replanning, operator requests and the ground's pose
estimate, all from what the downlink delivered. Pure; no Drake.

Each ground tick :func:`operator_step` takes the newest telemetry the downlink delivered
and the operator's requests (the scenario's ``ground.goals`` and ``ground.actions``,
or Python calls: :class:`~lunar_drake.systems.ground_operator.GroundOperator`) and
returns the commands to send up:

* **goals** are driven one at a time: the ground plans from its pose estimate to the
  goal on its costmap and sends a goto; when telemetry says the rover finished it (the
  goto acknowledged, the mode ``waiting``), the goal is *reached on the ground* if the
  ground's estimate is within ``goal_tolerance_m`` less its own position sigma (never
  less than ``goto_tolerance_m`` + 0.1 m: :func:`reach_radius_m`), else the ground
  replans a final approach from the estimate (at most ``max_replans`` times, then the
  goal is ``failed``); within ``goal_tolerance_m`` but not that radius, it is reached
  when a final approach cannot help (the rover at the planned end, a goal moved off a
  hazard, or the replans spent). While the
  rover drives, an estimate more than ``replan_deviation_m`` off the planned path
  makes the ground stop it and replan. A goal added while driving waits its turn.
* **safed**: when telemetry reports a new safing, the ground (``auto_resume``, at most
  ``max_resumes`` resumes sent in a run, resent ones included) sends a resume and a goto
  replanned from the estimate, in one uplink pass (the executor handles them in order).
* **lost**: a goto telemetry has not acknowledged after ``ack_timeout_s`` plus the
  round trip (twice the newest telemetry packet's measured latency: a symmetric link
  assumed; without it a 10 s one-way delay made every goto look lost) is sent again,
  replanned and after a stop (with a resume if the rover is safed and resumes are
  left), at most ``max_resends`` times, then the goal fails; a resume not acknowledged
  (the rover still safed, its command seq older) is sent again as often.
* **requests**: ``stop`` (stop, and pause goal driving), ``resume`` (resume, and
  continue the goals from the estimate), ``drive_arc`` (speed, curvature, distance),
  ``point_mast`` (pan, tilt; or automatic), ``goal`` (x, y), ``drive`` (a route
  segment).
* a **heartbeat** goes up whenever nothing else was sent for ``heartbeat_s``.

The ground's pose estimate is the newest downlinked estimate carried forward to now
with the twist command in the same packet (exact arc), for at most
``max_extrapolation_s``: telemetry is a light time old when it lands.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lunar_drake.autonomy.commands import (
    MODES,
    SAFE_REASONS,
    DrillCommand,
    DriveCommand,
    GotoCommand,
    Heartbeat,
    MastCommand,
    ResumeCommand,
    StopCommand,
)
from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS
from lunar_drake.comms.messages import Ledger, Message, payload_size_bytes
from lunar_drake.errors import LunarDrakeError

TOPIC = "commands"
#: Operator request kinds.
REQUESTS = ("goal", "stop", "resume", "drive_arc", "point_mast", "drive", "drill")
#: What becomes of a goal (on the ground's own judgement, from telemetry).
GOAL_STATUS = ("pending", "active", "reached", "failed")

_F = {name: k for k, name in enumerate(TELEMETRY_FIELDS)}


@dc.dataclass(frozen=True)
class Request:
    """An operator request: ``kind`` (one of :data:`REQUESTS`) and its arguments
    (goal: x_m, y_m; drive_arc: speed_mps, curvature_per_m, distance_m; point_mast:
    pan_rad, tilt_rad, or none for automatic pointing; drive: a DriveCommand)."""

    kind: str
    args: tuple = ()


@dc.dataclass(frozen=True)
class Event:
    """Something the ground did or saw: at ``t_s`` (s), ``kind`` and a ``detail``."""

    t_s: float
    kind: str
    detail: str = ""


@dc.dataclass(frozen=True)
class OperatorParams:
    """The ground's settings (from the scenario's ``ground`` section).

    Attributes: drive_speed_mps, goto_tolerance_m (on board), goal_tolerance_m (the
    ground's judgement on the downlinked estimate), heartbeat_s, auto_resume,
    max_resumes, max_replans, replan_deviation_m, max_extrapolation_s, ack_timeout_s,
    max_resends, resume_soc: see
    :class:`~lunar_drake.scenario.GroundConfig`.
    """

    drive_speed_mps: float = 0.2
    goto_tolerance_m: float = 0.2
    goal_tolerance_m: float = 1.0
    heartbeat_s: float = 5.0
    auto_resume: bool = True
    max_resumes: int = 3
    max_replans: int = 3
    replan_deviation_m: float = 2.0
    max_extrapolation_s: float = 10.0
    ack_timeout_s: float = 20.0
    max_resends: int = 5
    resume_soc: float = 0.5


@dc.dataclass(frozen=True)
class OperatorState:
    """What the ground holds between ticks (immutable).

    Attributes:
        pending: requests not yet handled. next_seq: the next command seq.
        goals: ((x, y), ...) every goal so far; status: their :data:`GOAL_STATUS`.
        active: index of the goal being driven (-1: none). paused: goal driving
            stopped by the operator. goto_seq: seq of the goto in flight (-1: none, plan
            one). goto_sent_s: when it went up. path: its waypoints. replans: replans
            of the active goal. resends: its gotos sent again for want of an
            acknowledgement.
        resume_seq, resume_sent_s: the newest resume sent (-1 none) and when;
            resume_resends: how often it was sent again.
        resumes: automatic resumes so far. safe_seen: the telemetry ``mode_changes``
            of the newest safing handled. charging: a ``low_soc`` safing waits for
            ``resume_soc`` before its resume.
        tel_seq, packet, t_sent, t_received: the newest telemetry handled (-1 / None).
        last_sent_s: when a command last went up (s). outbox: this tick's messages.
        events: a Ledger of :class:`Event`. map_seen: the map version whose hazards the
            path was last checked against. preview: (seq, path) of the newest goto sent
            with a preview: its predicted path ((t, x, y, z) rows;
            :mod:`~lunar_drake.autonomy.preview`); (-1, None) before.
    """

    pending: tuple = ()
    next_seq: int = 0
    goals: tuple = ()
    status: tuple = ()
    active: int = -1
    paused: bool = False
    goto_seq: int = -1
    goto_sent_s: float = -math.inf
    path: tuple = ()
    replans: int = 0
    resends: int = 0
    resume_seq: int = -1
    resume_sent_s: float = -math.inf
    resume_resends: int = 0
    resumes: int = 0
    safe_seen: int = -1
    charging: bool = False
    tel_seq: int = -1
    packet: np.ndarray | None = None
    t_sent: float = math.nan
    t_received: float = math.nan
    last_sent_s: float = -math.inf
    outbox: tuple = ()
    events: Ledger = dc.field(default_factory=Ledger)
    map_seen: int = 0
    preview: tuple = (-1, None)

    def __deepcopy__(self, memo):
        return self


def ground_pose(packet, t_sent: float, now: float, *, max_extrapolation_s: float) -> np.ndarray:
    """The downlinked pose estimate (x, y, z, roll, pitch, yaw) carried from ``t_sent``
    to ``now`` (s) along the packet's commanded twist (vx, vy in the chassis frame, wz;
    an exact arc), for at most ``max_extrapolation_s``; unchanged while braked."""
    p = np.asarray(packet, np.float64)
    pose = p[:6].copy()
    dt = min(max(now - t_sent, 0.0), max_extrapolation_s)
    if p[_F["brake"]] > 0.5 or dt <= 0.0:
        return pose
    vx, vy, wz = p[_F["vx_cmd_mps"]], p[_F["vy_cmd_mps"]], p[_F["wz_cmd_radps"]]
    yaw = pose[5]
    dyaw = wz * dt
    if abs(dyaw) < 1e-9:
        fx, fy = vx * dt, vy * dt
    else:  # the body displacement of a constant twist, integrated exactly
        s, c = math.sin(dyaw), 1.0 - math.cos(dyaw)
        fx = (vx * s - vy * c) / wz
        fy = (vx * c + vy * s) / wz
    pose[0] += fx * math.cos(yaw) - fy * math.sin(yaw)
    pose[1] += fx * math.sin(yaw) + fy * math.cos(yaw)
    pose[5] = (yaw + dyaw + math.pi) % (2.0 * math.pi) - math.pi
    return pose


def corrected_pose(pose, correction) -> np.ndarray:
    """``pose`` (x, y, z, roll, pitch, yaw) moved by a planar ``correction`` (dx, dy,
    dyaw): ``p' = Rz(dyaw) p + d``, ``yaw' = yaw + dyaw`` (the ground's VO fusion)."""
    out = np.asarray(pose, np.float64).copy()
    dx, dy, dyaw = (float(v) for v in correction)
    if dx == 0.0 and dy == 0.0 and dyaw == 0.0:
        return out
    c, s = math.cos(dyaw), math.sin(dyaw)
    x, y = out[0], out[1]
    out[0], out[1] = c * x - s * y + dx, s * x + c * y + dy
    out[5] = (out[5] + dyaw + math.pi) % (2.0 * math.pi) - math.pi
    return out


def goal_shift_limit_m(params) -> float:
    """How far (m) the ground may move a goal that a hazard covers (stereo found a rock
    beside it) to the nearest free cell: the scored ``goal_tolerance_m`` less the
    on-board ``goto_tolerance_m`` and 0.1 m, so the rover parked there still counts."""
    return max(0.0, params.goal_tolerance_m - params.goto_tolerance_m - 0.1)


def reach_radius_m(params, sigma_m: float) -> float:
    """How near (m) the ground's estimate must be to a goal for the ground to call it
    reached at once: the scored ``goal_tolerance_m`` less the estimate's own position
    sigma ``sigma_m`` (m, per axis; NaN counts as 0), so a goal judged reached on an
    estimate one sigma off (along the way to it) still is; never less than what the
    rover can park to (``goto_tolerance_m`` + 0.1 m), never more than
    ``goal_tolerance_m``. Farther, :func:`operator_step` plans a final approach, unless
    the rover already stands at the planned end (a goal the planner moved off a hazard)
    or the replans are spent: then ``goal_tolerance_m`` decides."""
    sig = float(sigma_m) if math.isfinite(sigma_m) else 0.0
    tol = params.goal_tolerance_m
    return min(tol, max(tol - max(sig, 0.0), params.goto_tolerance_m + 0.1))


def onboard_points(points_xy, correction) -> tuple:
    """Points ((x, y), ...) of the ground's frame in the rover's on-board estimate frame:
    the inverse of :func:`corrected_pose`'s map, ``p = Rz(-dyaw) (p' - d)``. A goto's
    waypoints go up in this frame: the rover follows them with its own estimate, so a
    goal the ground placed with VO is reached where the ground means it."""
    dx, dy, dyaw = (float(v) for v in correction)
    c, s = math.cos(dyaw), math.sin(dyaw)
    out = []
    for x, y in points_xy:
        u, v = float(x) - dx, float(y) - dy
        out.append((c * u + s * v, -s * u + c * v))
    return tuple(out)


def onboard_azimuth(azimuth_rad: float, correction) -> float:
    """An azimuth (rad, counter-clockwise from +x) of the ground's frame in the rover's
    on-board estimate frame (:func:`onboard_points`: turned by ``-dyaw``), in
    [-pi, pi)."""
    a = float(azimuth_rad) - float(correction[2])
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def distance_to_path(xy, path) -> float:
    """Horizontal distance (m) from ``xy`` to the polyline ``path`` ((x, y), ...)."""
    p = np.asarray(xy, np.float64)[:2]
    w = np.asarray(path, np.float64).reshape(-1, 2)
    if len(w) == 1:
        return float(np.hypot(*(p - w[0])))
    a, b = w[:-1], w[1:]
    d = b - a
    L2 = np.maximum(np.sum(d * d, axis=1), 1e-12)
    t = np.clip(np.sum((p - a) * d, axis=1) / L2, 0.0, 1.0)
    q = a + t[:, None] * d
    return float(np.min(np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])))


def _set(tup: tuple, k: int, v) -> tuple:
    return (*tup[:k], v, *tup[k + 1 :])


def operator_step(state: OperatorState, deliveries, *, now: float, params: OperatorParams,
                  planner, start_pose, requests=(), correction=(0.0, 0.0, 0.0),
                  sigma_m: float = 0.0, map_version: int = 0, blocked=None,
                  preview=None, sun_azimuth=None) -> OperatorState:  # fmt: skip
    """One ground tick at ``now`` (s).

    ``deliveries``: the downlink telemetry inbox (newest handled once); ``requests``:
    new :class:`Request` s (appended to the pending ones); ``planner(start_xy,
    goal_xy)`` returns waypoints ((x, y), ...) or raises a LunarDrakeError (a goal it
    cannot serve fails); ``start_pose`` (x, y, yaw) is the spawn pose, the estimate
    before the first telemetry. ``correction`` (dx, dy, dyaw) moves the downlinked
    estimate to the ground's own (:func:`corrected_pose`; VO), ``sigma_m`` (m) is that
    estimate's position sigma (:func:`reach_radius_m`). ``map_version`` and
    ``blocked(path, xy)`` (True when the path from xy now crosses a hazard): when the
    map's version changes while the rover drives a goal, a blocked path is stopped and
    replanned (not counted against ``max_replans``). ``preview(pose, waypoints)``: the
    predicted path of a goto about to be sent (kept in the state's ``preview``).
    ``sun_azimuth(t_s)``: the Sun's azimuth (rad, counter-clockwise from the site frame's
    +x) at time ``t_s``, from the ground's ephemeris, or None; given (the ``sun`` heading
    policy), each goto carries it for the middle of its planned drive (now plus half
    the path length over ``drive_speed_mps``), turned into the rover's frame like the
    waypoints, and ``preview`` is called with ``sun_azimuth_rad=`` it (site frame). The
    returned state's ``outbox`` holds the messages to send now.
    """
    s = state
    pending = s.pending + tuple(requests)
    events = s.events
    # The newest telemetry.
    tel_seq, packet, t_sent, t_recv = s.tel_seq, s.packet, s.t_sent, s.t_received
    for d in deliveries:
        if d.message.seq > tel_seq:
            tel_seq, packet = d.message.seq, d.message.payload
            t_sent, t_recv = d.message.t_sent_s, d.t_received_s
    if packet is None:
        pose = np.array([start_pose[0], start_pose[1], 0.0, 0.0, 0.0, start_pose[2]])
    else:
        pose = ground_pose(packet, t_sent, now, max_extrapolation_s=params.max_extrapolation_s)
    pose = corrected_pose(pose, correction)
    # How long an acknowledgement may take: the timeout plus the round trip, measured.
    rtt = 2.0 * (t_recv - t_sent) if packet is not None else 0.0
    ack_timeout = params.ack_timeout_s + (rtt if math.isfinite(rtt) else 0.0)
    goals, status, active, paused = s.goals, s.status, s.active, s.paused
    goto_seq, path, replans, resumes = s.goto_seq, s.path, s.replans, s.resumes
    goto_sent, resends = s.goto_sent_s, s.resends
    resume_seq, resume_sent, resume_resends = s.resume_seq, s.resume_sent_s, s.resume_resends
    charging = s.charging
    seq = s.next_seq
    out = []

    def send(cmd):
        nonlocal seq, resume_seq, resume_sent
        out.append(Message(topic=TOPIC, seq=seq, t_sent_s=now, payload=cmd,
                           size_bytes=payload_size_bytes(cmd)))  # fmt: skip
        if isinstance(cmd, ResumeCommand):
            resume_seq, resume_sent = seq, now
        seq += 1
        return seq - 1

    def note(kind, detail=""):
        nonlocal events
        events = events.append(Event(t_s=now, kind=kind, detail=detail))

    for r in pending:
        if r.kind == "goal":
            goals += ((float(r.args[0]), float(r.args[1])),)
            status += ("pending",)
            note("goal", f"{len(goals) - 1}: ({r.args[0]:.2f}, {r.args[1]:.2f}) m")
        elif r.kind == "stop":
            send(StopCommand())
            paused, goto_seq = True, -1
            note("stop")
        elif r.kind == "resume":
            send(ResumeCommand())
            paused, goto_seq, resume_resends = False, -1, 0
            note("resume")
        elif r.kind == "drive_arc":
            v, k, dist = (float(a) for a in r.args)
            send(DriveCommand(duration_s=abs(dist / v), vx_mps=v, wz_radps=v * k))
            note("drive_arc", f"{v:g} m/s, {k:g} 1/m, {dist:g} m")
        elif r.kind == "drive":
            send(r.args[0])
        elif r.kind == "drill":
            depth, step = (float(a) for a in r.args)
            send(DrillCommand(depth_m=depth, step_m=step))
            note("drill", f"to {depth:g} m in steps of {step:g} m")
        elif r.kind == "point_mast":
            cmd = MastCommand(auto=True) if not r.args else MastCommand(*map(float, r.args))
            send(cmd)
            note("point_mast", "auto" if cmd.auto else f"{cmd.pan_rad:.3f}, {cmd.tilt_rad:.3f} rad")
        else:
            raise ValueError(f"request kind {r.kind!r}; must be one of {REQUESTS}")
    mode = MODES[int(packet[_F["mode"]])] if packet is not None else "idle"
    # The goto in flight is acknowledged once the rover accepted it (or a later motion
    # command): a newer heartbeat alone does not prove it arrived.
    acked = packet is not None and packet[_F["motion_seq"]] >= goto_seq >= 0

    predicted = s.preview

    def plan_goto(why):
        nonlocal goto_seq, goto_sent, path, active, status, predicted
        goal = goals[active]
        try:
            wp = planner((pose[0], pose[1]), goal)
        except LunarDrakeError as exc:
            status = _set(status, active, "failed")
            note("goal_failed", f"{active}: {exc}")
            active, goto_seq, path = -1, -1, ()
            return
        length = float(np.sum(np.hypot(*np.diff(np.asarray(wp), axis=0).T))) if len(wp) > 1 else 0
        wp_ground = tuple((float(x), float(y)) for x, y in wp)
        sun = None
        if sun_azimuth is not None:  # for the middle of the drive (the Sun ~0.5 deg/h)
            sun = float(sun_azimuth(now + 0.5 * length / params.drive_speed_mps))
        cmd = GotoCommand(
            waypoints=onboard_points(wp_ground, correction),  # the rover's frame
            speed_mps=params.drive_speed_mps,
            tolerance_m=params.goto_tolerance_m,
            timeout_s=3.0 * length / params.drive_speed_mps + 60.0,
            sun_azimuth_rad=None if sun is None else onboard_azimuth(sun, correction),
        )
        goto_seq, goto_sent, path = send(cmd), now, wp_ground
        if preview is not None:
            if sun is None:
                predicted = (goto_seq, preview(pose, wp_ground))
            else:
                predicted = (goto_seq, preview(pose, wp_ground, sun_azimuth_rad=sun))
        note("plan", f"{why}: goal {active}, {len(wp)} waypoints, {length:.1f} m")

    # A new safing: resume (and replan below).
    if packet is not None and mode == "safed":
        changes = int(packet[_F["mode_changes"]])
        if changes != s.safe_seen:
            reason = SAFE_REASONS[int(packet[_F["safe_reason"]])]
            note("safed", reason)
            s_seen = changes
            if reason == "low_soc":
                charging = True
                note("charging", f"parked until the state of charge reaches "
                                 f"{params.resume_soc:.2f}")  # fmt: skip
            elif params.auto_resume and resumes < params.max_resumes and not paused:
                send(ResumeCommand())
                resumes += 1
                goto_seq = -1
                note("resume", f"automatic ({resumes} of {params.max_resumes})")
        else:
            s_seen = s.safe_seen
    else:
        s_seen = s.safe_seen
    if packet is not None and mode != "safed":
        charging = False
    # Charged after a low_soc safing: resume (and replan below).
    soc = float(packet[_F["soc"]]) if packet is not None else math.nan
    if charging and mode == "safed" and soc >= params.resume_soc:
        charging = False
        if params.auto_resume and resumes < params.max_resumes and not paused:
            send(ResumeCommand())
            resumes += 1
            goto_seq = -1
            note("resume", f"charged to {soc:.2f} ({resumes} of {params.max_resumes})")
    # A resume the rover has not acknowledged (still safed, older command seq): again.
    if (
        packet is not None
        and mode == "safed"
        and resume_seq >= 0
        and packet[_F["command_seq"]] < resume_seq
        and now - resume_sent > ack_timeout
        and resume_resends < params.max_resends
        and not any(isinstance(m.payload, ResumeCommand) for m in out)
    ):
        resume_resends += 1
        send(ResumeCommand())
        note("resume", f"sent again ({resume_resends} of {params.max_resends})")

    def start_next():
        # Activate pending goals in order until one gets a plan (or none is left).
        nonlocal active, status, goto_seq, path, replans, resends
        active, goto_seq, path, replans, resends = -1, -1, (), 0, 0
        while "pending" in status:
            active = status.index("pending")
            status = _set(status, active, "active")
            plan_goto("start")
            if active >= 0:
                return

    def give_up(detail):
        nonlocal status
        status = _set(status, active, "failed")
        note("goal_failed", f"{active}: {detail}")
        start_next()

    map_seen = s.map_seen

    def hazard_ahead() -> bool:
        # Checked once per new map version while the rover drives an acknowledged goto.
        nonlocal map_seen
        if not (acked and mode == "driving" and path and blocked is not None):
            return False
        if map_version == map_seen:
            return False
        map_seen = map_version
        return bool(blocked(path, pose[:2]))

    # Goals.
    if active < 0 and not paused and "pending" in status:
        if mode != "safed":
            start_next()
    elif active >= 0 and not paused:
        if goto_seq < 0:
            resumed = any(isinstance(m.payload, ResumeCommand) for m in out)
            if mode != "safed" or resumed:
                plan_goto("after a resume" if resumed else "start")
                if active < 0:
                    start_next()
        elif not acked and now - goto_sent > ack_timeout:
            # Not acknowledged: lost on the way up (an outage, out of sight of Earth), or
            # ignored by a safed rover.
            note("no_ack", f"goto seq {goto_seq} sent at {goto_sent:.1f} s")
            resuming = any(isinstance(m.payload, ResumeCommand) for m in out)
            can_resume = resuming or (params.auto_resume and resumes < params.max_resumes)
            if mode == "safed" and not can_resume:
                goto_sent = math.inf  # safed for good: left to the operator's resume
                note("left_safed", f"{resumes} automatic resumes spent")
            elif resends >= params.max_resends:
                give_up(f"goto not acknowledged after {resends} resends")
            else:
                resends += 1
                send(StopCommand())  # an unacknowledged copy may yet run: stop it first
                if mode == "safed" and not resuming:
                    send(ResumeCommand())
                    resumes += 1
                    note("resume", f"with the resent goto ({resumes} of {params.max_resumes})")
                plan_goto("resend")
                if active < 0:
                    start_next()
        elif acked and mode in ("waiting", "idle"):
            err = math.hypot(pose[0] - goals[active][0], pose[1] - goals[active][1])
            end = path[-1] if path else goals[active]
            at_end = math.hypot(pose[0] - end[0], pose[1] - end[1]) <= params.goto_tolerance_m + 0.1
            approach_futile = at_end or replans >= params.max_replans
            if err <= reach_radius_m(params, sigma_m) or (
                approach_futile and err <= params.goal_tolerance_m
            ):
                status = _set(status, active, "reached")
                note("goal_reached", f"{active}: estimate {err:.2f} m from it")
                start_next()
            elif replans < params.max_replans:
                replans += 1
                plan_goto(f"replan {replans} ({err:.2f} m short)")
                if active < 0:
                    start_next()
            else:
                give_up(f"{err:.2f} m short after {replans} replans")
        elif hazard_ahead():
            send(StopCommand())
            plan_goto("replan (a new hazard on the path)")
            if active < 0:
                start_next()
        elif acked and mode == "driving" and path and replans < params.max_replans:
            off = distance_to_path(pose[:2], path)
            if off > params.replan_deviation_m:
                send(StopCommand())
                replans += 1
                plan_goto(f"replan {replans} ({off:.2f} m off the path)")
                if active < 0:
                    start_next()
    if not out and now - s.last_sent_s >= params.heartbeat_s - 1e-9:
        send(Heartbeat())
    return OperatorState(
        pending=(),
        next_seq=seq,
        goals=goals,
        status=status,
        active=active,
        paused=paused,
        goto_seq=goto_seq,
        goto_sent_s=goto_sent,
        path=path,
        replans=replans,
        resends=resends,
        resume_seq=resume_seq,
        resume_sent_s=resume_sent,
        resume_resends=resume_resends,
        resumes=resumes,
        safe_seen=s_seen,
        charging=charging,
        tel_seq=tel_seq,
        packet=packet,
        t_sent=t_sent,
        t_received=t_recv,
        last_sent_s=now if out else s.last_sent_s,
        outbox=tuple(out),
        events=events,
        map_seen=map_seen,
        preview=predicted,
    )


__all__ = [
    "GOAL_STATUS",
    "REQUESTS",
    "Event",
    "OperatorParams",
    "OperatorState",
    "Request",
    "corrected_pose",
    "distance_to_path",
    "goal_shift_limit_m",
    "ground_pose",
    "onboard_azimuth",
    "onboard_points",
    "operator_step",
    "reach_radius_m",
]
