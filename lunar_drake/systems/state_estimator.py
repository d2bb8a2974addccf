"""StateEstimator (flight "Localization"): the on-board EKF (:mod:`lunar_drake.autonomy.ekf`)
fed with encoders, IMU and star tracker."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy import ekf
from lunar_drake.autonomy import estimator_tick as core
from lunar_drake.dynamics.kinematics import skid_twist_map, wheel_geometry_for
from lunar_drake.moon import GRAVITY_MPS2
from lunar_drake.systems.leaf import Leaf

N_WHEELS = 4
_X, _PC = core.X, core.PC
_ANGLES, _STARTED, _SIZE = core.layout(N_WHEELS)


class StateEstimator(Leaf):
    """The on-board pose estimate with covariance (error-state EKF).

    .. pydrake_system::

        name: StateEstimator
        input_ports:
        - wheel_angles
        - q_WB_measured
        - imu
        - steer_angle_command (explicit steer only)
        output_ports:
        - pose_estimate
        - p_WB_estimate
        - q_WB_estimate
        - pose_covariance

    Inputs are sensor readings (encoder angles, star-tracker quaternion, IMU) and the
    flight software's own steering command; never truth. Every 1 / ``rate_hz`` s:
    :func:`~lunar_drake.autonomy.ekf.predict` with the gyro and the encoder increments
    (rover kinematics, :func:`~lunar_drake.autonomy.odometry.body_displacement`), a
    star-tracker update when a new fix arrived, and a tilt update from the accelerometer
    when quasi-static. ``pose_estimate`` (6,) = x, y (m, site frame), z (m, relative to
    the start), roll, pitch, yaw (rad); ``p_WB_estimate`` (3,), ``q_WB_estimate`` (4,)
    (w, x, y, z); ``pose_covariance`` (36,) the 6 x 6 covariance of [position error,
    world-frame attitude error] (m^2, rad^2), row-major. State (discrete): EKF state
    (15) and covariance (196), last fix (4), previous wheel angles (4), started. It
    ticks at ``config.rate_hz`` (the IMU's rate, so it sees every gyro sample).

    Args:
        description: the RoverDescription.
        config: :class:`~lunar_drake.autonomy.ekf.EstimatorConfig`.
        start_xy_m, start_yaw_rad: the start point (m, site frame) and heading (rad),
            known to operations (the first star-tracker fix refines the attitude).
    """

    def __init__(self, *, description, config: ekf.EstimatorConfig,
                 start_xy_m=(0.0, 0.0), start_yaw_rad: float = 0.0):  # fmt: skip
        super().__init__()
        config.validate()
        self._config = config
        self._params = ekf.kernel_params(config)  # the compiled predict's view of config
        self._geometry = wheel_geometry_for(description)
        self._skid = description.steering == "skid"
        self._dt = 1.0 / float(config.rate_hz)
        g = self._geometry
        # the compiled tick's arguments that do not change (core.tick)
        self._tick_args = (
            self._dt, self._skid, skid_twist_map(g) if self._skid else np.zeros((2, N_WHEELS)),
            g.p_BS, g.steering_offset, g.wheel_radius, *self._params,
        )  # fmt: skip
        self._no_steer = np.zeros(N_WHEELS)
        self.wheel_angles_input = self.DeclareVectorInputPort("wheel_angles", N_WHEELS)
        self.q_WB_input = self.DeclareVectorInputPort("q_WB_measured", 4)
        self.imu_input = self.DeclareVectorInputPort("imu", 6)
        self.steer_input = None
        if not self._skid:
            self.steer_input = self.DeclareVectorInputPort("steer_angle_command", N_WHEELS)
        half = 0.5 * float(start_yaw_rad)
        x, P = ekf.initial_state(
            p0=[start_xy_m[0], start_xy_m[1], 0.0],
            q0=[math.cos(half), 0.0, 0.0, math.sin(half)],
            config=config,
        )
        s0 = np.zeros(_SIZE)
        s0[_X] = x
        s0[_PC] = P.ravel()
        self._state = self.DeclareDiscreteState(BasicVector(s0))
        self.DeclarePeriodicDiscreteUpdateEvent(self._dt, 0.0, self._update)
        xd = {self.xd_ticket()}

        def pose(c, o):
            o.SetFromVector(core.pose(self._s(c)))

        def cov(c, o):
            o.SetFromVector(core.pose_covariance(self._s(c)))

        self.pose_estimate_output = self.DeclareVectorOutputPort(
            "pose_estimate", BasicVector(6), pose, prerequisites_of_calc=xd
        )
        self.p_WB_output = self.DeclareVectorOutputPort(
            "p_WB_estimate", BasicVector(3),
            lambda c, o: o.SetFromVector(self._s(c)[0:3]), prerequisites_of_calc=xd,
        )  # fmt: skip
        self.q_WB_output = self.DeclareVectorOutputPort(
            "q_WB_estimate", BasicVector(4),
            lambda c, o: o.SetFromVector(self._s(c)[3:7]), prerequisites_of_calc=xd,
        )  # fmt: skip
        self.pose_covariance_output = self.DeclareVectorOutputPort(
            "pose_covariance", BasicVector(36), cov, prerequisites_of_calc=xd
        )

    def _s(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _update(self, context, discrete_state):
        s = self._s(context)
        cfg = self._config
        angles = self.wheel_angles_input.Eval(context)
        fix = self.q_WB_input.Eval(context)
        imu = self.imu_input.Eval(context)
        steer = self._no_steer if self._skid else self.steer_input.Eval(context)
        # Sensor samples taken at a tick are visible from the next tick (they land in the
        # same discrete update as this one), so a new star-tracker fix and the IMU
        # reading describe the previous tick: the state before this tick's prediction.
        # Update first, then predict to now. At the first tick (t = 0) the sensors still
        # show their initial values: only record them.
        started = s[_STARTED] > 0.5
        new_fix = cfg.use_star_tracker and core.fix_is_new(s, fix)
        tick = round(context.get_time() / self._dt)
        tilt = cfg.use_tilt and started and tick % cfg.tilt_every == 0
        if new_fix or tilt:
            s = s.copy()
            x, P = s[_X], s[_PC].reshape(ekf.N_ERR, ekf.N_ERR)  # views of the copy (read only)
            if new_fix:
                x, P, _ = ekf.update_attitude(x, P, q_measured=fix, config=cfg)
            if tilt:
                x, P, _ = ekf.update_tilt(
                    x, P, accel_mps2=imu[3:6], gyro_radps=imu[:3], gravity_mps2=GRAVITY_MPS2,
                    config=cfg,
                )  # fmt: skip
            s[_X] = x
            s[_PC] = P.ravel()
        # then predict (once started) and record the fix and the angles: one compiled call
        discrete_state.get_mutable_vector(self._state).SetFromVector(
            core.tick(s, angles, fix, imu, steer, *self._tick_args)
        )
