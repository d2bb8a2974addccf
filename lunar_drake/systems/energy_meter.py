"""EnergyMeter: mechanical energy delivered by a set of joint actuators."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem


class EnergyMeter(LeafSystem):
    """Integrates actuator power over time.

    .. pydrake_system::

        name: EnergyMeter
        input_ports:
        - actuation
        - state
        output_ports:
        - energy

    ``energy`` (J) = sum over the metered actuators of the integral of max(tau * v, 0)
    (motors draw energy when driving; braking power is not recovered), integrated with a
    left Riemann sum at ``period_s`` (use the plant's time step).

    Args:
        actuation_indices: indices into the ``actuation`` vector (N m) to meter.
        velocity_indices: matching indices into the ``state`` vector [q; v] (rad/s).
        n_actuation, n_state: input sizes. period_s: integration step (s).
    """

    def __init__(
        self,
        *,
        actuation_indices,
        velocity_indices,
        n_actuation: int,
        n_state: int,
        period_s: float,
    ):
        super().__init__()
        self._ia = np.asarray(actuation_indices, dtype=int)
        self._iv = np.asarray(velocity_indices, dtype=int)
        self._dt = float(period_s)
        self.actuation_input = self.DeclareVectorInputPort("actuation", n_actuation)
        self.state_input = self.DeclareVectorInputPort("state", n_state)
        self._energy = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        self.energy_output = self.DeclareStateOutputPort("energy", self._energy)

    def _update(self, context, discrete_state):
        tau = self.actuation_input.Eval(context)[self._ia]
        v = self.state_input.Eval(context)[self._iv]
        e = context.get_discrete_state(self._energy).GetAtIndex(0)
        p = float(np.maximum(tau * v, 0.0).sum())
        discrete_state.get_mutable_vector(self._energy).SetAtIndex(0, e + p * self._dt)
