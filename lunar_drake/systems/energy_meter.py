"""EnergyMeter: mechanical energy delivered by sets of joint actuators."""

from __future__ import annotations

import numpy as np

from lunar_drake.power.actuator_energy import energy_step
from lunar_drake.systems.leaf import Leaf


class EnergyMeter(Leaf):
    """Integrates actuator power over time.

    .. pydrake_system::

        name: EnergyMeter
        input_ports:
        - actuation
        - state
        output_ports:
        - energy
        - <group>_energy (one per extra group)

    ``energy`` (J) = sum over the metered actuators of the integral of max(tau * v, 0)
    (motors draw energy when driving; braking power is not recovered), integrated with a
    left Riemann sum at ``period_s`` (use the plant's time step). Each extra group
    ``(name, actuation_indices, velocity_indices)`` is metered the same way in the same
    update, on its own output ``<name>_energy`` (J).

    Args:
        actuation_indices: indices into the ``actuation`` vector (N m) to meter.
        velocity_indices: matching indices into the ``state`` vector [q; v] (rad/s).
        n_actuation, n_state: input sizes. period_s: integration step (s).
        groups: extra groups ``(name, actuation_indices, velocity_indices)``.
    """

    def __init__(
        self,
        *,
        actuation_indices,
        velocity_indices,
        n_actuation: int,
        n_state: int,
        period_s: float,
        groups=(),
    ):
        super().__init__()
        names = ["", *(str(g[0]) for g in groups)]
        ia = [actuation_indices, *(g[1] for g in groups)]
        iv = [velocity_indices, *(g[2] for g in groups)]
        self._ia = np.concatenate([np.asarray(i, dtype=int).ravel() for i in ia])
        self._iv = np.concatenate([np.asarray(i, dtype=int).ravel() for i in iv])
        if self._ia.shape != self._iv.shape:
            raise ValueError("each group needs as many velocity as actuation indices")
        # Group of each metered joint, for the per-group sums.
        self._group = np.repeat(np.arange(len(names)), [len(np.ravel(i)) for i in ia])
        self._n_groups = len(names)
        self._dt = float(period_s)
        self.actuation_input = self.DeclareVectorInputPort("actuation", n_actuation)
        self.state_input = self.DeclareVectorInputPort("state", n_state)
        self._energy = self.DeclareDiscreteState(self._n_groups)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        xd = {self.discrete_state_ticket(self._energy)}

        def port(k):
            def calc(context, output):
                output.SetAtIndex(0, context.get_discrete_state(self._energy).GetAtIndex(k))

            return self.DeclareVectorOutputPort(
                f"{names[k]}_energy" if k else "energy", 1, calc, prerequisites_of_calc=xd
            )

        self.energy_output = port(0)
        self.group_outputs = {names[k]: port(k) for k in range(1, self._n_groups)}

    def _update(self, context, discrete_state):
        discrete_state.get_mutable_vector(self._energy).set_value(
            energy_step(
                context.get_discrete_state(self._energy).get_value(),
                self.actuation_input.Eval(context),
                self.state_input.Eval(context),
                self._ia, self._iv, self._group, self._dt,
            )
        )  # fmt: skip
