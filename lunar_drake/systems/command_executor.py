"""CommandExecutor (flight): runs the uplinked commands; brakes when parked."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.autonomy.commands import MODES, ExecutorState, executor_step


class CommandExecutor(LeafSystem):
    """The on-board command executor (:func:`~lunar_drake.autonomy.commands.executor_step`).

    .. pydrake_system::

        name: CommandExecutor
        input_ports:
        - commands
        - pose_estimate (optional)
        output_ports:
        - twist_command
        - brake_command
        - status

    ``commands`` is the uplink inbox (a tuple of deliveries). Every 1 / ``rate_hz`` s
    new commands are queued and run in order; a goto follows its waypoints on
    ``pose_estimate`` (6,: x, y, z, roll, pitch, yaw; the on-board estimate).
    ``twist_command`` (3,) = (vx, vy, wz) in the chassis frame (m/s, m/s, rad/s);
    ``brake_command`` (1,) is 1 once the rover has been commanded to stand still for
    ``brake_delay_s`` (and from the start), else 0;
    ``status`` (2,) = (mode index into MODES, newest command seq handled). State: the
    ExecutorState (abstract) and the outputs (discrete).

    Args:
        rate_hz: tick rate (Hz). brake_delay_s: stand-still time before braking (s).
    """

    def __init__(self, *, rate_hz: float, brake_delay_s: float):
        super().__init__()
        self._rate = float(rate_hz)
        self._brake_delay = float(brake_delay_s)
        self.commands_input = self.DeclareAbstractInputPort("commands", AbstractValue.Make(()))
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self._core = self.DeclareAbstractState(AbstractValue.Make(ExecutorState()))
        # [vx, vy, wz, brake, mode, last_seq]
        self._out = self.DeclareDiscreteState(BasicVector([0, 0, 0, 1, 0, -1]))
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
            "status", BasicVector(2), out(4, 6), prerequisites_of_calc=xd
        )

    def _update(self, context, state):
        tick = round(context.get_time() * self._rate)
        core = context.get_abstract_state(self._core).get_value()
        pose = None
        if self.pose_input.HasValue(context):
            e = self.pose_input.Eval(context)
            pose = (e[0], e[1], e[5])
        core, out = executor_step(
            core,
            self.commands_input.Eval(context),
            tick=tick,
            rate_hz=self._rate,
            brake_delay_s=self._brake_delay,
            pose=pose,
        )
        state.get_mutable_abstract_state(self._core).set_value(core)
        state.get_mutable_discrete_state(self._out).SetFromVector(
            np.concatenate([out.twist, [float(out.brake), MODES.index(out.mode), core.last_seq]])
        )
