"""CommandExecutor (flight): runs the uplinked commands, keeps the mode, brakes when
parked."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy.commands import MODES, SAFE_REASONS, ExecutorState, executor_step
from lunar_drake.systems.leaf import Leaf

#: Columns of the executor's ``status`` output (and of flight_status.csv).
STATUS_FIELDS = ("mode", "command_seq", "safe_reason", "mode_changes", "motion_seq")


class CommandExecutor(Leaf):
    """The on-board command executor and mode manager
    (:func:`~lunar_drake.autonomy.commands.executor_step`).

    .. pydrake_system::

        name: CommandExecutor
        input_ports:
        - commands
        - pose_estimate (optional)
        - bumper_trip (optional)
        output_ports:
        - twist_command
        - brake_command
        - status
        - mast_command

    ``commands`` is the uplink inbox (a tuple of deliveries). Every 1 / ``rate_hz`` s new
    commands are handled and run in order; a goto follows its waypoints on
    ``pose_estimate`` (6,: x, y, z, roll, pitch, yaw; the on-board estimate);
    ``bumper_trip`` (1,) is the virtual bumper's trip (index into SAFE_REASONS; 0 none).
    ``twist_command`` (3,) = (vx, vy, wz) in the chassis frame (m/s, m/s, rad/s);
    ``brake_command`` (1,) is 1 once the rover has been commanded to stand still for
    ``brake_delay_s`` (and from the start), else 0; ``status`` (4,) =
    :data:`STATUS_FIELDS` (mode index into MODES, newest command seq handled, safe
    reason index, number of mode changes so far, seq of the newest drive or goto
    accepted); ``mast_command`` (3,) = (held, pan,
    tilt rad): held 1 while a MastCommand holds the gimbal. State: the ExecutorState
    (abstract) and the outputs (discrete).

    Args:
        rate_hz: tick rate (Hz). brake_delay_s: stand-still time before braking (s).
        uplink_timeout_s: safe the rover when a command runs and nothing came up the
            uplink for this long (s; 0: never).
        follower: :class:`~lunar_drake.autonomy.follower.FollowerParams` for gotos.
    """

    def __init__(self, *, rate_hz: float, brake_delay_s: float, uplink_timeout_s: float = 0.0,
                 follower=None):  # fmt: skip
        super().__init__()
        self._follower = follower
        self._rate = float(rate_hz)
        self._brake_delay = float(brake_delay_s)
        self._uplink_timeout = float(uplink_timeout_s)
        self.commands_input = self.DeclareAbstractInputPort("commands", AbstractValue.Make(()))
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self.trip_input = self.DeclareVectorInputPort("bumper_trip", 1)
        self._core = self.DeclareAbstractState(AbstractValue.Make(ExecutorState()))
        # [vx, vy, wz, brake, mode, last_seq, safe_reason, mode_changes, motion_seq,
        #  held, pan, tilt]
        self._out = self.DeclareDiscreteState(BasicVector([0, 0, 0, 1, 0, -1, 0, 0, -1, 0, 0, 0]))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / self._rate, 0.0, self._update)

        def out(lo, hi):
            return lambda c, o: o.SetFromVector(c.get_discrete_state(self._out).get_value()[lo:hi])

        xd = {self.xd_ticket()}
        self.twist_output = self.DeclareVectorOutputPort(
            "twist_command", BasicVector(3), out(0, 3), prerequisites_of_calc=xd
        )
        self.brake_output = self.DeclareVectorOutputPort(
            "brake_command", BasicVector(1), out(3, 4), prerequisites_of_calc=xd
        )
        self.status_output = self.DeclareVectorOutputPort(
            "status", BasicVector(5), out(4, 9), prerequisites_of_calc=xd
        )
        self.mast_output = self.DeclareVectorOutputPort(
            "mast_command", BasicVector(3), out(9, 12), prerequisites_of_calc=xd
        )

    def executor_state(self, context) -> ExecutorState:
        """The ExecutorState in ``context`` (this system's context): its
        ``transitions`` ledger holds every mode change."""
        return context.get_abstract_state(self._core).get_value()

    def _update(self, context, state):
        tick = round(context.get_time() * self._rate)
        core = self.executor_state(context)
        pose = None
        if self.pose_input.HasValue(context):
            e = self.pose_input.Eval(context)
            pose = (e[0], e[1], e[5])
        trip = ""
        if self.trip_input.HasValue(context):
            trip = SAFE_REASONS[round(self.trip_input.Eval(context)[0])]
        core, out = executor_step(
            core,
            self.commands_input.Eval(context),
            tick=tick,
            rate_hz=self._rate,
            brake_delay_s=self._brake_delay,
            pose=pose,
            trip=trip,
            uplink_timeout_s=self._uplink_timeout,
            follower=self._follower,
        )
        state.get_mutable_abstract_state(self._core).set_value(core)
        held, pan, tilt = (0.0, 0.0, 0.0) if out.mast is None else (1.0, *out.mast)
        tw = out.twist
        state.get_mutable_discrete_state(self._out).SetFromVector(
            np.array(
                [
                    tw[0], tw[1], tw[2],
                    float(out.brake), MODES.index(out.mode), core.last_seq,
                    SAFE_REASONS.index(out.safed_reason), len(core.transitions),
                    core.motion_seq,
                    held, pan, tilt,
                ],
                dtype=float,
            )
        )  # fmt: skip
