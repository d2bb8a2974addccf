"""Imu: a noisy, biased 6-axis IMU on one MultibodyPlant body, sampled periodically."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialAcceleration, SpatialVelocity
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.dynamics.sensor_models import (
    LUNAR_GRAVITY_W,
    ImuConfig,
    imu_ideal,
    imu_initial_bias,
    imu_measurement,
    sample_index,
)
from lunar_drake.rng import stream_key


class Imu(LeafSystem):
    """Gyro + accelerometer fixed to a body of a MultibodyPlant (paper section 7).

    .. pydrake_system::

        name: Imu
        input_ports:
        - body_poses
        - body_spatial_velocities
        - body_spatial_accelerations
        output_ports:
        - measurement
        - bias_truth

    Inputs are the plant's own body-kinematics ports (abstract lists indexed by
    BodyIndex): ``plant.get_body_poses_output_port()`` (X_WB),
    ``plant.get_body_spatial_velocities_output_port()`` (V_WB, in W) and
    ``plant.get_body_spatial_accelerations_output_port()`` (A_WB, in W).

    ``measurement`` (6,) = [gyro x, y, z (rad/s), accel x, y, z (m/s^2)] in the sensor
    frame S (pose ``X_BS`` in the body): angular velocity of B plus bias plus white
    noise, and specific force ``a_WS - g_W`` (so +1.62 m/s^2 along up at rest on the
    Moon) plus bias plus noise. It is discrete state, updated every
    ``1 / config.sample_rate_hz`` s starting at t = 0 (zero before the first sample)
    and held in between; it does not feed through from the inputs, so the IMU can close
    loops. ``bias_truth`` (6,) is the bias that the *next* sample will carry (ground
    truth for scoring only).

    The bias is discrete state (initial value and random-walk steps drawn from the
    stream); sample k's noise is keyed by (stream_key(seed, name), k, channel), with
    k = round(t * rate). Same seed, name and inputs -> bit-identical outputs.

    Args:
        body_index: the plant BodyIndex (or int) the IMU is fixed to.
        seed: scenario random seed.
        name: system name and noise-stream name (give each IMU its own).
        config: noise model and rate (:class:`ImuConfig`).
        X_BS: sensor pose in the body frame (default identity).
        gravity_W: gravity in W (m/s^2) used for specific force; should match the
            plant's gravity field. Default lunar (0, 0, -1.62).
        w_planet_W: rotation of W relative to inertial space (rad/s) added to the gyro;
            default 0 (see :func:`~lunar_drake.dynamics.sensor_models.imu_ideal`).
    """

    def __init__(
        self,
        *,
        body_index,
        seed: int,
        name: str = "imu",
        config: ImuConfig | None = None,
        X_BS: RigidTransform | None = None,
        gravity_W=LUNAR_GRAVITY_W,
        w_planet_W=(0.0, 0.0, 0.0),
    ):
        super().__init__()
        self.set_name(name)
        self._config = ImuConfig() if config is None else config
        self._body = int(body_index)
        self._key = stream_key(seed, name)
        X_BS = RigidTransform() if X_BS is None else X_BS
        self._R_BS = X_BS.rotation().matrix()
        p = X_BS.translation()
        self._p_BS = None if not np.any(p) else np.array(p)
        self._g_W = np.asarray(gravity_W, dtype=np.float64).reshape(3)
        self._w_planet_W = np.asarray(w_planet_W, dtype=np.float64).reshape(3)

        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self.body_spatial_accelerations_input = self.DeclareAbstractInputPort(
            "body_spatial_accelerations", AbstractValue.Make([SpatialAcceleration()])
        )
        self._meas_index = self.DeclareDiscreteState(6)
        self._bias_index = self.DeclareDiscreteState(
            BasicVector(imu_initial_bias(self._key, config=self._config))
        )
        self.DeclarePeriodicDiscreteUpdateEvent(
            1.0 / self._config.sample_rate_hz, 0.0, self._update
        )
        self.measurement_output = self.DeclareStateOutputPort("measurement", self._meas_index)
        self.bias_truth_output = self.DeclareStateOutputPort("bias_truth", self._bias_index)

    @property
    def config(self) -> ImuConfig:
        """The noise model."""
        return self._config

    def _update(self, context, discrete_state):
        b = self._body
        X_WB = self.body_poses_input.Eval(context)[b]
        V_WB = self.body_spatial_velocities_input.Eval(context)[b]
        A_WB = self.body_spatial_accelerations_input.Eval(context)[b]
        ideal = imu_ideal(
            R_WB=X_WB.rotation().matrix(),
            w_WB_W=V_WB.rotational(),
            alpha_WB_W=A_WB.rotational(),
            a_WBo_W=A_WB.translational(),
            R_BS=self._R_BS,
            p_BS=self._p_BS,
            gravity_W=self._g_W,
            w_planet_W=self._w_planet_W,
        )
        k = sample_index(context.get_time(), self._config.sample_rate_hz)
        bias = context.get_discrete_state(self._bias_index).get_value()
        meas, next_bias = imu_measurement(ideal, bias, self._key, k, config=self._config)
        discrete_state.set_value(self._meas_index, meas)
        discrete_state.set_value(self._bias_index, next_bias)
