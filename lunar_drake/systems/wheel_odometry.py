"""WheelOdometry (flight "Localization", dead reckoning): pose from encoders, star tracker
and gyro."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.autonomy.odometry import odometry_step, propagate_attitude
from lunar_drake.dynamics.kinematics import wheel_geometry_for
from lunar_drake.rotations import roll_pitch_yaw, rotation_matrix_from_quaternion

N_WHEELS = 4
_Q = slice(6, 10)  # estimated attitude q_WB
_Q_FIX = slice(10, 14)  # the last star-tracker fix seen
_ANGLES = slice(14, 14 + N_WHEELS)  # wheel angles at the previous tick
_STARTED = 14 + N_WHEELS


class WheelOdometry(LeafSystem):
    """The on-board pose estimate by dead reckoning (:mod:`lunar_drake.autonomy.odometry`).

    .. pydrake_system::

        name: WheelOdometry
        input_ports:
        - wheel_angles
        - q_WB_measured
        - imu
        - steer_angle_command (explicit steer only)
        output_ports:
        - pose_estimate
        - p_WB_estimate
        - q_WB_estimate

    Inputs are sensor readings (encoder angles, star-tracker quaternion, IMU) and the
    flight software's own steering command; never truth. Every 1 / ``rate_hz`` s: the
    attitude is reset to each new star-tracker fix and propagated by the IMU gyro in
    between; the encoder increments since the previous tick move the position along it.
    ``pose_estimate`` (6,) = x, y (m, site frame), z (m, relative to the start), roll,
    pitch, yaw (rad); ``p_WB_estimate`` (3,) and ``q_WB_estimate`` (4,) the same as a
    position and a quaternion (w, x, y, z). State: [x, y, z, roll, pitch, yaw, q (4),
    last fix (4), previous wheel angles (4), started flag].

    Args:
        description: the RoverDescription. rate_hz: update rate (Hz).
        start_xy_m: the start point (m, site frame), known to operations.
    """

    def __init__(self, *, description, rate_hz: float, start_xy_m=(0.0, 0.0)):
        super().__init__()
        self._geometry = wheel_geometry_for(description)
        self._skid = description.steering == "skid"
        self._dt = 1.0 / float(rate_hz)
        self.wheel_angles_input = self.DeclareVectorInputPort("wheel_angles", N_WHEELS)
        self.q_WB_input = self.DeclareVectorInputPort("q_WB_measured", 4)
        self.imu_input = self.DeclareVectorInputPort("imu", 6)
        self.steer_input = None
        if not self._skid:
            self.steer_input = self.DeclareVectorInputPort("steer_angle_command", N_WHEELS)
        x0 = np.zeros(_STARTED + 1)
        x0[:2] = start_xy_m
        x0[_Q] = [1.0, 0.0, 0.0, 0.0]
        self._state = self.DeclareDiscreteState(BasicVector(x0))
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)

        def out(lo, hi):
            return lambda c, o: o.SetFromVector(self._x(c)[lo:hi])

        xd = {self.xd_ticket()}
        self.pose_estimate_output = self.DeclareVectorOutputPort(
            "pose_estimate", BasicVector(6), out(0, 6), prerequisites_of_calc=xd
        )
        self.p_WB_output = self.DeclareVectorOutputPort(
            "p_WB_estimate", BasicVector(3), out(0, 3), prerequisites_of_calc=xd
        )
        self.q_WB_output = self.DeclareVectorOutputPort(
            "q_WB_estimate", BasicVector(4), out(_Q.start, _Q.stop), prerequisites_of_calc=xd
        )

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _update(self, context, discrete_state):
        x = self._x(context).copy()
        angles = np.asarray(self.wheel_angles_input.Eval(context), float)
        fix = np.asarray(self.q_WB_input.Eval(context), float)
        if not np.array_equal(fix, x[_Q_FIX]):
            q = fix
        else:
            gyro = np.asarray(self.imu_input.Eval(context), float)[:3]
            q = propagate_attitude(x[_Q], gyro, self._dt)
        R_WB = rotation_matrix_from_quaternion(q)
        if x[_STARTED] > 0.5:
            steer = np.zeros(N_WHEELS) if self._skid else self.steer_input.Eval(context)
            x[:3] = odometry_step(
                x[:3],
                angles - x[_ANGLES],
                steer,
                R_WB,
                geometry=self._geometry,
                skid=self._skid,
            )
        x[3:6] = roll_pitch_yaw(R_WB)
        x[_Q] = q
        x[_Q_FIX] = fix
        x[_ANGLES] = angles
        x[_STARTED] = 1.0
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
