"""The command vocabulary of the uplink, and the on-board command executor.

The ground sends a route as a sequence of :class:`DriveCommand` (a body twist held for a
duration), paths to goals as :class:`GotoCommand` (waypoints followed on board with the
pose estimate, :mod:`lunar_drake.autonomy.follower`), and may send
:class:`StopCommand`. The executor runs them one after the other at the flight
software's tick and engages the wheel brakes once the rover has been commanded to stand
still for ``brake_delay_s``.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lunar_drake.autonomy.follower import FollowerParams, follow_step

#: Executor modes reported in telemetry.
MODES = ("idle", "driving", "holding")


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
    ``timeout_s`` has passed."""

    waypoints: tuple
    speed_mps: float = 0.2
    tolerance_m: float = 0.5
    timeout_s: float = 600.0

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header, three float64 and two float64 a waypoint."""
        return 4 + 3 * 8 + 16 * len(self.waypoints)


@dc.dataclass(frozen=True)
class StopCommand:
    """Stop now and drop every queued command."""

    def size_bytes(self) -> int:
        """Encoded size: a 4-byte header."""
        return 4


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
    """

    queue: tuple = ()
    active: DriveCommand | GotoCommand | None = None
    active_end_tick: int = 0
    goto_index: int = 0
    still_since_tick: int | None = -(2**31)
    last_seq: int = -1

    def __deepcopy__(self, memo):
        return self


@dc.dataclass(frozen=True)
class ExecutorOutput:
    """The executor's commands for this tick."""

    twist: np.ndarray
    brake: bool
    mode: str


def executor_step(
    state: ExecutorState,
    deliveries,
    *,
    tick: int,
    rate_hz: float,
    brake_delay_s: float,
    pose=None,
    follower: FollowerParams | None = None,
) -> tuple[ExecutorState, ExecutorOutput]:
    """Advances the executor to ``tick`` (tick k is at k / rate_hz s).

    ``deliveries`` are uplink deliveries; those with ``seq > state.last_seq`` are
    handled in order (drive and goto: queued; stop: clears the queue and the running
    command). A command starts at the first tick after the previous one ends; a drive
    lasts ``round(duration_s * rate_hz)`` ticks, a goto until the pose estimate ``pose``
    (x, y, yaw) is within its tolerance of its goal (or its timeout).
    """
    queue = list(state.queue)
    active, end, last = state.active, state.active_end_tick, state.last_seq
    index = state.goto_index
    for d in deliveries:
        m = d.message
        if m.seq <= last:
            continue
        last = m.seq
        if isinstance(m.payload, StopCommand):
            queue.clear()
            active = None
        elif isinstance(m.payload, (DriveCommand, GotoCommand)):
            queue.append(m.payload)
    twist = None
    for _ in range(len(queue) + 2):  # finished gotos hand over within the tick
        if active is not None and tick >= end:
            active = None
        while active is None and queue:
            cmd = queue.pop(0)
            duration = cmd.timeout_s if isinstance(cmd, GotoCommand) else cmd.duration_s
            n = round(duration * rate_hz)
            if n > 0:
                active, end, index = cmd, tick + n, 0
        if isinstance(active, GotoCommand):
            if pose is None:
                raise ValueError("a GotoCommand needs the pose estimate")
            twist, index, done = follow_step(
                pose, active.waypoints, index, speed_mps=active.speed_mps,
                tolerance_m=active.tolerance_m, params=follower or FollowerParams(),
            )  # fmt: skip
            if done:
                active, twist = None, None
                continue
        break
    if twist is None:
        twist = active.twist if active is not None else np.zeros(3)
    moving = bool(np.any(twist != 0.0))
    if moving:
        still = None
    else:
        still = tick if state.still_since_tick is None else state.still_since_tick
    brake = still is not None and (tick - still) >= math.ceil(brake_delay_s * rate_hz - 1e-9)
    mode = "driving" if moving else ("holding" if active is not None else "idle")
    new = ExecutorState(
        queue=tuple(queue),
        active=active,
        active_end_tick=end,
        goto_index=index,
        still_since_tick=still,
        last_seq=last,
    )
    return new, ExecutorOutput(twist=twist, brake=brake, mode=mode)
