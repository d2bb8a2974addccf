"""Imu: a noisy, biased 6-axis IMU on one MultibodyPlant body."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.multibody.math import SpatialAcceleration, SpatialVelocity
from pydrake.systems.framework import BasicVector

from lunar_drake.moon import GRAVITY_W
from lunar_drake.rng import generator
from lunar_drake.sensors.imu import ImuConfig, imu_ideal, imu_initial_bias, imu_measurement
from lunar_drake.systems.sampled_sensor import SampledSensor


class Imu(SampledSensor):
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

    Inputs are the plant's body-kinematics ports (abstract lists indexed by BodyIndex):
    ``plant.get_body_poses_output_port()`` (X_WB),
    ``plant.get_body_spatial_velocities_output_port()`` (V_WB, in W) and
    ``plant.get_body_spatial_accelerations_output_port()`` (A_WB, in W).

    ``measurement`` (6,) = [gyro x, y, z (rad/s), accel x, y, z (m/s^2)] in the sensor
    frame S: angular velocity of B plus bias plus white noise, and specific force
    ``a_WS - g_W`` (+1.62 m/s^2 along up at rest on the Moon) plus bias plus noise;
    sampled and delivered as :class:`SampledSensor` describes (zero before the first
    delivery). ``bias_truth`` (6,) is the bias the *next* sample will carry (ground
    truth, for scoring only). The bias is discrete state: its initial value comes from
    the stream ``(seed, name + "/initial_bias")``, its random-walk steps from each
    sample's generator.

    Args:
        body_index: the plant BodyIndex (or int) the IMU is fixed to.
        seed: scenario random seed. name: system name and noise-stream name.
        config: rate, delay and noise (:class:`~lunar_drake.sensors.imu.ImuConfig`).
        X_BS: sensor pose in the body frame (default identity).
        gravity_W: gravity in W (m/s^2) for the specific force; must match the plant's.
        w_planet_W: rotation of W relative to inertial space (rad/s) added to the gyro.
    """

    def __init__(
        self,
        *,
        body_index,
        seed: int,
        name: str = "imu",
        config: ImuConfig | None = None,
        X_BS: RigidTransform | None = None,
        gravity_W=GRAVITY_W,
        w_planet_W=(0.0, 0.0, 0.0),
    ):
        self._config = ImuConfig() if config is None else config
        super().__init__(
            name=name,
            seed=seed,
            rate_hz=self._config.rate_hz,
            delay_s=self._config.delay_s,
            initial=np.zeros(6),
            output_name="measurement",
        )
        self._body = int(body_index)
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
        bias0 = imu_initial_bias(generator(seed, f"{name}/initial_bias"), config=self._config)
        self._bias = self.DeclareDiscreteState(BasicVector(bias0))
        self.bias_truth_output = self.DeclareStateOutputPort("bias_truth", self._bias)

    @property
    def config(self) -> ImuConfig:
        """Rate, delay and noise model."""
        return self._config

    def sample(self, context, generator, discrete_state):
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
        bias = context.get_discrete_state(self._bias).get_value()
        meas, next_bias = imu_measurement(ideal, bias, generator, config=self._config)
        discrete_state.set_value(self._bias, next_bias)
        return meas
