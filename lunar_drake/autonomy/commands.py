"""The command vocabulary of the uplink, and the on-board command executor with its
mode manager.

The ground sends a route as a sequence of :class:`DriveCommand` (a body twist held for a
duration), paths to goals as :class:`GotoCommand` (waypoints followed on board with the
pose estimate, :mod:`lunar_drake.autonomy.follower`), and :class:`StopCommand`,
:class:`ResumeCommand`, :class:`MastCommand` and :class:`Heartbeat`. The executor runs
drive and goto commands one after the other at the flight software's tick, engages the
wheel brakes once the rover has been commanded to stand still for ``brake_delay_s``,
and keeps the rover's mode (:data:`MODES`):

* ``idle`` -- nothing commanded yet;
* ``driving`` -- running a drive or goto command (a zero-twist drive stands still);
* ``waiting`` -- its commands are done (or stopped): waiting for the ground;
* ``safed`` -- the virtual bumper (:mod:`lunar_drake.autonomy.safety`) or the loss of
  the uplink stopped it: brakes on, queue dropped, drive and goto commands ignored
  until a :class:`ResumeCommand`.

Every mode change is recorded (:class:`Transition`) and counted in telemetry.
"""

from __future__ import annotations

import dataclasses as dc
import functools
import math

import numpy as np

from lunar_drake.autonomy.follower import FollowerParams, follow_step
from lunar_drake.comms.messages import Ledger

#: Executor modes reported in telemetry (index = telemetry ``mode``).
MODES = ("idle", "driving", "waiting", "safed")
#: Why the rover safed itself (index = telemetry ``safe_reason``; "" = not safed).
SAFE_REASONS = ("", "tilt", "stall", "slip", "uplink_loss", "low_soc")


@dc.dataclass(frozen=True)
class DriveCommand:
    """Hold the chassis-frame twist (vx, vy in m/s, wz in rad/s) for ``duration_s``,
    after every command queued before it. A zero twist stands still (brakes on)."""

    duration_s: float
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header and four float64."""
        return 4 + 4 * 8

    @property
    def twist(self) -> np.ndarray:
        """(vx, vy, wz)."""
        return np.array([self.vx_mps, self.vy_mps, self.wz_radps])


@dc.dataclass(frozen=True)
class GotoCommand:
    """Follow ``waypoints`` ((x, y) site m, from the planned start to the goal) at
    ``speed_mps`` until the estimate is within ``tolerance_m`` of the last one, or
    ``timeout_s`` has passed. ``sun_azimuth_rad``: the Sun's azimuth for the ``sun``
    heading policy (rad, counter-clockwise from +x of the waypoints' frame; the ground
    computes it from the ephemeris for the middle of the drive), or None (``path``)."""

    waypoints: tuple
    speed_mps: float = 0.2
    tolerance_m: float = 0.5
    timeout_s: float = 600.0
    sun_azimuth_rad: float | None = None

    @functools.cached_property
    def waypoints_array(self) -> np.ndarray:
        """``waypoints`` as a read-only (n, 2) float array (m), built once: the executor
        follows it every tick."""
        wp = np.array(self.waypoints, dtype=float).reshape(-1, 2)
        wp.setflags(write=False)
        return wp

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header, three float64, two float64 a waypoint and a
        float64 with the Sun's azimuth."""
        sun = 0 if self.sun_azimuth_rad is None else 8
        return 4 + 3 * 8 + 16 * len(self.waypoints) + sun


@dc.dataclass(frozen=True)
class StopCommand:
    """Stop now and drop every queued command."""

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header."""
        return 4


@dc.dataclass(frozen=True)
class ResumeCommand:
    """Leave ``safed`` (to ``waiting``); no effect otherwise."""

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header."""
        return 4


@dc.dataclass(frozen=True)
class MastCommand:
    """Hold the mast gimbal at ``pan_rad`` (about +z, positive left) and ``tilt_rad``
    (about +y, positive down); ``auto`` returns it to the flight software's own pointing."""

    pan_rad: float = 0.0
    tilt_rad: float = 0.0
    auto: bool = False

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header, two float64 and a flag byte."""
        return 4 + 2 * 8 + 1


@dc.dataclass(frozen=True)
class DrillCommand:
    """Drill at the rover's stop: samples every ``step_m`` down to ``depth_m`` (m), each
    brought up and read by NIRVSS (the executor ignores it; the flight's drill
    controller passes it to the drill, :mod:`lunar_drake.science.drill`)."""

    depth_m: float = 0.5
    step_m: float = 0.1

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header and two float64."""
        return 4 + 2 * 8


@dc.dataclass(frozen=True)
class Heartbeat:
    """The ground's keep-alive: proves the uplink is up (no action)."""

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header."""
        return 4


@dc.dataclass(frozen=True)
class Transition:
    """One mode change: at ``t_s`` (s) from ``before`` to ``after``; ``reason`` (one of
    :data:`SAFE_REASONS`) when it safed the rover."""

    t_s: float
    before: str
    after: str
    reason: str = ""


@dc.dataclass(frozen=True)
class ExecutorState:
    """What the executor holds between ticks.

    Attributes:
        queue: drive commands waiting to run, in order.
        active: the running command, or None.
        active_end_tick: the tick at which ``active`` ends (a goto: its timeout).
        goto_index: the leg of the active goto being followed.
        still_since_tick: first tick of the current stand-still (zero twist), or None
            while moving; the rover starts parked (brakes on).
        last_seq: sequence number of the newest command handled (-1: none).
        motion_seq: that of the newest drive or goto command accepted (-1: none; one
            ignored while safed does not count): the ground's acknowledgement.
        heard_tick: tick of the newest uplink message (any command, heartbeats too).
        mode: the current mode (:data:`MODES`). safed_reason: why it is safed ("" if not).
        ran_any: a drive or goto command has run (idle becomes waiting after it).
        mast: (pan, tilt) rad held by a :class:`MastCommand`, or None (automatic).
        ignored: drive/goto commands dropped while safed.
        transitions: every mode change (:class:`Transition`), a Ledger.
    """

    queue: tuple = ()
    active: DriveCommand | GotoCommand | None = None
    active_end_tick: int = 0
    goto_index: int = 0
    still_since_tick: int | None = -(2**31)
    last_seq: int = -1
    motion_seq: int = -1
    heard_tick: int = 0
    mode: str = "idle"
    safed_reason: str = ""
    ran_any: bool = False
    mast: tuple | None = None
    ignored: int = 0
    transitions: Ledger = dc.field(default_factory=Ledger)

    def __deepcopy__(self, memo):
        return self


@dc.dataclass(frozen=True)
class ExecutorOutput:
    """The executor's commands for this tick."""

    twist: np.ndarray
    brake: bool
    mode: str
    safed_reason: str = ""
    mast: tuple | None = None


def executor_step(
    state: ExecutorState,
    deliveries,
    *,
    tick: int,
    rate_hz: float,
    brake_delay_s: float,
    pose=None,
    follower: FollowerParams | None = None,
    trip: str = "",
    uplink_timeout_s: float = 0.0,
) -> tuple[ExecutorState, ExecutorOutput]:
    """Advances the executor to ``tick`` (tick k is at k / rate_hz s).

    ``deliveries`` are uplink deliveries; those with ``seq > state.last_seq`` are
    handled in order (drive and goto: queued, or ignored while safed; stop: clears the
    queue and the running command; resume: leaves safed; mast: holds or releases the
    gimbal; heartbeat: nothing). A command starts at the first tick after the previous
    one ends; a drive lasts ``round(duration_s * rate_hz)`` ticks, a goto until the pose
    estimate ``pose`` (x, y, yaw) is within its tolerance of its goal (or its timeout).

    Safing: ``trip`` (a :data:`SAFE_REASONS` entry from the virtual bumper) or, while a
    command runs, no uplink message for more than ``uplink_timeout_s`` (> 0) safes the
    rover: the queue and the running command are dropped and the brakes engage.
    """
    if trip not in SAFE_REASONS:
        raise ValueError(f"trip = {trip!r}; must be one of {SAFE_REASONS}")
    queue = list(state.queue)
    active, end, last = state.active, state.active_end_tick, state.last_seq
    index, heard, safed = state.goto_index, state.heard_tick, state.safed_reason
    mast, ignored, motion = state.mast, state.ignored, state.motion_seq
    for d in deliveries:
        m = d.message
        if m.seq <= last:
            continue
        last, heard = m.seq, tick
        cmd = m.payload
        if isinstance(cmd, StopCommand):
            queue.clear()
            active = None
        elif isinstance(cmd, ResumeCommand):
            safed = ""
        elif isinstance(cmd, MastCommand):
            mast = None if cmd.auto else (float(cmd.pan_rad), float(cmd.tilt_rad))
        elif isinstance(cmd, (DriveCommand, GotoCommand)):
            if safed:
                ignored += 1
            else:
                queue.append(cmd)
                motion = m.seq
    timeout = round(uplink_timeout_s * rate_hz)
    if not trip and active is not None and timeout > 0 and tick - heard > timeout:
        trip = "uplink_loss"
    if trip and not safed:
        safed = trip
        queue.clear()
        active = None
    ran_any = state.ran_any
    twist = None
    for _ in range(len(queue) + 2):  # finished gotos hand over within the tick
        if active is not None and tick >= end:
            active = None
        while active is None and queue:
            cmd = queue.pop(0)
            duration = cmd.timeout_s if isinstance(cmd, GotoCommand) else cmd.duration_s
            n = round(duration * rate_hz)
            if n > 0:
                active, end, index, ran_any = cmd, tick + n, 0, True
        if isinstance(active, GotoCommand):
            if pose is None:
                raise ValueError("a GotoCommand needs the pose estimate")
            twist, index, done = follow_step(
                pose, active.waypoints_array, index, speed_mps=active.speed_mps,
                tolerance_m=active.tolerance_m, params=follower or FollowerParams(),
                sun_azimuth_rad=active.sun_azimuth_rad,
            )  # fmt: skip
            if done:
                active, twist = None, None
                continue
        break
    if twist is None:
        twist = active.twist if active is not None else np.zeros(3)
    moving = bool((twist != 0.0).any())
    if moving:
        still = None
    else:
        still = tick if state.still_since_tick is None else state.still_since_tick
    brake = still is not None and (tick - still) >= math.ceil(brake_delay_s * rate_hz - 1e-9)
    if safed:
        mode = "safed"
    elif active is not None:
        mode = "driving"
    else:
        mode = "waiting" if ran_any or state.mode != "idle" else "idle"
    transitions = state.transitions
    if mode != state.mode:
        transitions = transitions.append(
            Transition(t_s=tick / rate_hz, before=state.mode, after=mode,
                       reason=safed if mode == "safed" else "")
        )  # fmt: skip
    new = ExecutorState(
        queue=tuple(queue),
        active=active,
        active_end_tick=end,
        goto_index=index,
        still_since_tick=still,
        last_seq=last,
        motion_seq=motion,
        heard_tick=heard,
        mode=mode,
        safed_reason=safed,
        ran_any=ran_any,
        mast=mast,
        ignored=ignored,
        transitions=transitions,
    )
    return new, ExecutorOutput(twist=twist, brake=brake, mode=mode, safed_reason=safed, mast=mast)
