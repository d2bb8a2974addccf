"""DrillController (flight) and Drill (plant): drilling at a stop, samples read by NIRVSS."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy.commands import MODES, DrillCommand
from lunar_drake.rng import SampleStream, stream_key
from lunar_drake.science.drill import DrillConfig, ice_at_depth, read_sample
from lunar_drake.science.nirvss import NIRVSSConfig, SurfaceMap, spot_means
from lunar_drake.systems.command_executor import STATUS_FIELDS
from lunar_drake.systems.leaf import Leaf


class DrillController(Leaf):
    """Flight: passes the newest :class:`~lunar_drake.autonomy.commands.DrillCommand`
    of the uplink to the drill while the rover is not driving.

    .. pydrake_system::

        name: DrillController
        input_ports:
        - commands
        - status
        output_ports:
        - drill_command

    ``drill_command`` (3,): (seq, depth_m, step_m) of the newest drill command accepted
    (seq -1: none); ``status`` is the executor's (mode index first). A drill command that
    arrives while the rover drives is dropped. State (abstract): (last seq seen, the
    accepted command).
    """

    def __init__(self, *, rate_hz: float):
        super().__init__()
        self.commands_input = self.DeclareAbstractInputPort("commands", AbstractValue.Make(()))
        self.status_input = self.DeclareVectorInputPort("status", len(STATUS_FIELDS))
        self._state = self.DeclareAbstractState(AbstractValue.Make((-1, (-1.0, 0.0, 0.0))))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.drill_command_output = self.DeclareVectorOutputPort(
            "drill_command", BasicVector(3),
            lambda c, o: o.SetFromVector(c.get_abstract_state(self._state).get_value()[1]),
            prerequisites_of_calc={self.all_state_ticket()},
        )  # fmt: skip

    def _update(self, context, state):
        last, current = context.get_abstract_state(self._state).get_value()
        driving = MODES[int(self.status_input.Eval(context)[0])] == "driving"
        new_last = last
        for d in self.commands_input.Eval(context):
            m = d.message
            if m.seq <= last:
                continue
            new_last = max(new_last, m.seq)
            if isinstance(m.payload, DrillCommand) and not driving:
                current = (float(m.seq), float(m.payload.depth_m), float(m.payload.step_m))
        if new_last != last:
            state.get_mutable_abstract_state(self._state).set_value((new_last, current))


class Drill(Leaf):
    """Plant: the drill and NIRVSS's reading of what it brings up (a sensor).

    .. pydrake_system::

        name: Drill
        input_ports:
        - drill_command
        - body_poses
        output_ports:
        - samples

    A new command seq starts a hole under the drill (``config.x_m`` ahead of the
    chassis centre, at the chassis' true pose then); every ``seconds_per_step`` one
    sample comes up, deepest last. The hole is abandoned if the chassis moves more than
    5 cm from where it started. ``samples`` (4,): (samples so far, depth of the newest
    (m), its NIRVSS ice band depth, its time (s)). Discrete state: (command seq, start
    time, hole x, y, depth, step, samples of this hole, then the output).
    """

    def __init__(self, *, body_index, smap: SurfaceMap, seed: int, config: DrillConfig,
                 nirvss: NIRVSSConfig, name: str = "rover.drill"):  # fmt: skip
        super().__init__()
        config.validate()
        self.set_name(name)
        self._cfg, self._nir = config, nirvss
        self._body = int(body_index)
        self._smap = smap
        self._stream = SampleStream(stream_key(seed, name))
        self.command_input = self.DeclareVectorInputPort("drill_command", 3)
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        init = [-1.0, 0.0, math.nan, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self._xd = self.DeclareDiscreteState(BasicVector(init))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0, 0.0, self._update)
        self.samples_output = self.DeclareVectorOutputPort(
            "samples", BasicVector(4),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._xd).get_value()[7:11]),
            prerequisites_of_calc={self.xd_ticket()},
        )  # fmt: skip

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._xd).get_value().copy()
        t = context.get_time()
        seq, depth, step = (float(v) for v in self.command_input.Eval(context))
        X_WB = self.body_poses_input.Eval(context)[self._body]
        p = X_WB.multiply(np.array([self._cfg.x_m, 0.0, 0.0]))
        if seq >= 0 and seq != x[0]:  # a new hole
            x[0:7] = [seq, t, p[0], p[1], depth, step, 0.0]
        elif x[0] >= 0 and math.isfinite(x[2]) and math.hypot(p[0] - x[2], p[1] - x[3]) > 0.05:
            x[2] = x[3] = math.nan  # moved: the hole is abandoned
        n_total = math.floor(x[4] / x[5] + 1e-9) if x[5] > 0 else 0
        due = math.floor((t - x[1]) / self._cfg.seconds_per_step + 1e-9)
        if math.isfinite(x[2]) and x[6] < n_total and due >= x[6] + 1:
            k = int(x[6]) + 1
            z = k * x[5]
            spot = spot_means(self._smap, x[2], x[3], radius_m=0.05)
            ice = ice_at_depth(spot["dry_layer_m"], spot["ice_wt_pct"], z)
            count = int(x[7]) + 1
            bd = read_sample(ice, self._stream.at(count), ice_per_wt_pct=self._nir.ice_per_wt_pct,
                             sigma=self._nir.sigma_lamp)  # fmt: skip
            x[6], x[7:11] = k, [count, z, bd, t]
        discrete_state.set_value(self._xd, x)
