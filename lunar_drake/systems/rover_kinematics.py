"""RoverKinematics (flight "Rover Kinematics"): body twist -> wheel speeds and steering."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector

from lunar_drake.dynamics.kinematics import (
    explicit_steer_one,
    skid_steer_wheel_speeds,
    steer_kernel_args,
    wheel_geometry_for,
)
from lunar_drake.systems.leaf import Leaf

N_WHEELS = 4


class RoverKinematics(Leaf):
    """Turns the chassis twist command into wheel-speed and steering-angle set-points.

    .. pydrake_system::

        name: RoverKinematics
        input_ports:
        - twist_command
        output_ports:
        - wheel_speed_command
        - steer_angle_command (explicit steer only)

    ``twist_command`` is (vx, vy, wz) in the chassis frame (m/s, m/s, rad/s).
    ``wheel_speed_command`` (4,) are the drive rates (rad/s, wheels fl, fr, rl, rr);
    ``steer_angle_command`` (4,) the steering angles (rad; explicit steer only), saturated
    at the steering limit and kept through zero-twist commands (no spurious flips).
    Updated periodically at ``rate_hz`` (the flight software's tick) and held. It knows
    the rover only from its description (no plant).

    Args:
        description: the RoverDescription. rate_hz: update rate (Hz).
    """

    def __init__(self, *, description, rate_hz: float = 50.0):
        super().__init__()
        self._geometry = wheel_geometry_for(description)
        self._skid = description.steering == "skid"
        self._steer_args = steer_kernel_args(self._geometry)
        self.twist_input = self.DeclareVectorInputPort("twist_command", 3)
        # State: [wheel speeds (4), steering angles (4)].
        self._state = self.DeclareDiscreteState(2 * N_WHEELS)
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.wheel_speed_output = self.DeclareVectorOutputPort(
            "wheel_speed_command",
            BasicVector(N_WHEELS),
            lambda c, o: o.SetFromVector(self._x(c)[:N_WHEELS]),
            prerequisites_of_calc={self.xd_ticket()},
        )
        self.steer_angle_output = None
        if not self._skid:
            self.steer_angle_output = self.DeclareVectorOutputPort(
                "steer_angle_command",
                BasicVector(N_WHEELS),
                lambda c, o: o.SetFromVector(self._x(c)[N_WHEELS:]),
                prerequisites_of_calc={self.xd_ticket()},
            )

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _update(self, context, discrete_state):
        twist = np.asarray(self.twist_input.Eval(context), float)
        x = self._x(context).copy()
        if self._skid:
            x[:N_WHEELS] = skid_steer_wheel_speeds(
                np.array([twist[0], 0.0, twist[2]]), geometry=self._geometry
            )
        else:
            delta, omega = explicit_steer_one(
                twist[0], twist[1], twist[2], x[N_WHEELS:], self._steer_args
            )
            x[:N_WHEELS] = omega
            x[N_WHEELS:] = delta
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
