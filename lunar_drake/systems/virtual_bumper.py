"""VirtualBumper (flight "safeguarding"): the on-board checks that safe the rover
(:mod:`lunar_drake.autonomy.safety`)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy.commands import MODES, SAFE_REASONS
from lunar_drake.autonomy.odometry import body_displacement
from lunar_drake.autonomy.safety import SafetyConfig, bumper_step
from lunar_drake.dynamics.kinematics import wheel_geometry_for
from lunar_drake.systems.leaf import Leaf

N_WHEELS = 4
# State: [previous wheel angles (4), timers (3), started, trip (index into SAFE_REASONS)]
_ANG, _TIM, _STARTED, _TRIP = slice(0, 4), slice(4, 7), 7, 8


class VirtualBumper(Leaf):
    """Watches tilt, wheel stall and yaw slip while the rover drives.

    .. pydrake_system::

        name: VirtualBumper
        input_ports:
        - pose_estimate
        - imu
        - wheel_angles
        - wheel_speed_command
        - steer_angle_command (explicit steer only)
        - status
        - power (with ``power=True``)
        output_ports:
        - trip

    Inputs are flight signals only: the on-board estimate (6,), the IMU (6,: gyro then
    accelerometer), the encoder angles (4,), the flight software's own wheel-rate and
    steering commands (4,), the executor's ``status`` (its first entry the mode
    index into :data:`~lunar_drake.autonomy.commands.MODES`) and, with ``power``, the
    power sensor (3,: state of charge, array W, load W). Every 1 / ``rate_hz`` s it
    runs :func:`~lunar_drake.autonomy.safety.bumper_step` while the mode is
    ``driving``. ``trip`` (1,) is the index into
    :data:`~lunar_drake.autonomy.commands.SAFE_REASONS` of the condition that tripped
    at the latest tick (0: none); the executor latches it. State: discrete.

    Args:
        description: the RoverDescription. config: :class:`SafetyConfig`. power: declare
            the ``power`` input (the rover has a power system).
    """

    def __init__(self, *, description, config: SafetyConfig, power: bool = False):
        super().__init__()
        config.validate()
        self._config = config
        self._dt = 1.0 / float(config.rate_hz)
        self._geometry = wheel_geometry_for(description)
        self._skid = description.steering == "skid"
        self._tilt = config.tilt_limit_rad(description)
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self.imu_input = self.DeclareVectorInputPort("imu", 6)
        self.wheel_angles_input = self.DeclareVectorInputPort("wheel_angles", N_WHEELS)
        self.wheel_speed_input = self.DeclareVectorInputPort("wheel_speed_command", N_WHEELS)
        self.steer_input = None
        if not self._skid:
            self.steer_input = self.DeclareVectorInputPort("steer_angle_command", N_WHEELS)
        self.status_input = self.DeclareVectorInputPort("status", 5)
        self.power_input = self.DeclareVectorInputPort("power", 3) if power else None
        self._state = self.DeclareDiscreteState(np.zeros(9))
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        self.trip_output = self.DeclareVectorOutputPort(
            "trip",
            BasicVector(1),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._state).get_value()[_TRIP:]),
            prerequisites_of_calc={self.xd_ticket()},
        )

    def _update(self, context, discrete_state):
        s = context.get_discrete_state(self._state).get_value().copy()
        angles = np.asarray(self.wheel_angles_input.Eval(context), float)
        if s[_STARTED] < 0.5 or not self._config.enabled:
            s[_ANG], s[_STARTED], s[_TRIP] = angles, 1.0, 0.0
            discrete_state.get_mutable_vector(self._state).SetFromVector(s)
            return
        mode = MODES[round(self.status_input.Eval(context)[0])]
        delta = angles - s[_ANG]
        steer = np.zeros(N_WHEELS) if self._skid else self.steer_input.Eval(context)
        yaw_enc = body_displacement(delta, steer, geometry=self._geometry, skid=self._skid)[2]
        pose = self.pose_input.Eval(context)
        timers, reason = bumper_step(
            s[_TIM], dt_s=self._dt, driving=mode == "driving", roll_rad=pose[3],
            pitch_rad=pose[4], wheel_rate_cmd=self.wheel_speed_input.Eval(context),
            wheel_rate_meas=delta / self._dt, yaw_rate_encoders=yaw_enc / self._dt,
            yaw_rate_gyro=float(self.imu_input.Eval(context)[2]), tilt_limit_rad=self._tilt,
            config=self._config,
            soc=float(self.power_input.Eval(context)[0]) if self.power_input else math.nan,
        )  # fmt: skip
        s[_ANG], s[_TIM], s[_TRIP] = angles, timers, float(SAFE_REASONS.index(reason))
        discrete_state.get_mutable_vector(self._state).SetFromVector(s)
