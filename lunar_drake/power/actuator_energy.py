"""Mechanical energy delivered by groups of joint actuators, one step at a time (the
:class:`~lunar_drake.systems.energy_meter.EnergyMeter` core). No Drake."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def energy_step(energy, actuation, state, actuation_indices, velocity_indices, group, dt):
    """Energy (J) per group after one left-Riemann step of ``dt`` s: ``energy`` (g,) plus
    ``dt`` times each group's sum of ``max(tau v, 0)`` (motors draw energy when driving;
    braking power is not recovered), ``tau = actuation[actuation_indices]`` (N m),
    ``v = state[velocity_indices]`` (rad/s), actuator ``i`` in group ``group[i]``.
    The sums run in actuator order (as ``np.bincount``)."""
    power = np.zeros(energy.size)
    for i in range(actuation_indices.size):
        power[group[i]] += max(actuation[actuation_indices[i]] * state[velocity_indices[i]], 0.0)
    return energy + power * dt
