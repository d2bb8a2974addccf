"""Imu: a noisy, biased 6-axis IMU on one MultibodyPlant body (Drake's ideal sensors plus
our bias and noise)."""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform
from pydrake.systems.framework import BasicVector
from pydrake.systems.sensors import Accelerometer, Gyroscope

from lunar_drake.rng import generator
from lunar_drake.sensors.imu import ImuConfig, imu_initial_bias, noisy_reading
from lunar_drake.systems.sampled_sensor import SampledSensor


class Imu(SampledSensor):
    """Gyro + accelerometer noise, bias and sampling (paper section 7).

    .. pydrake_system::

        name: Imu
        input_ports:
        - angular_velocity
        - specific_force
        output_ports:
        - measurement
        - bias_truth

    The ideal readings come in as vectors, in the sensor frame S: ``angular_velocity``
    (3,) w_WS (rad/s) and ``specific_force`` (3,) a_WS - g_W (m/s^2): the outputs of
    Drake's ``Gyroscope`` and ``Accelerometer`` on the body (:func:`add_imu` wires all
    three; the site frame W is treated as inertial).

    ``measurement`` (6,) = [gyro x, y, z (rad/s), accel x, y, z (m/s^2)] in S: the ideal
    reading plus bias plus white noise (+1.62 m/s^2 along up at rest on the Moon);
    sampled and delivered as :class:`SampledSensor` describes (zero before the first
    delivery). ``bias_truth`` (6,) is the bias the *next* sample will carry (ground
    truth, for scoring only). The bias is discrete state: its initial value comes from
    the stream ``(seed, name + "/initial_bias")``, its random-walk steps from each
    sample's generator.

    Args:
        seed: scenario random seed. name: system name and noise-stream name.
        config: rate, delay and noise (:class:`~lunar_drake.sensors.imu.ImuConfig`).
    """

    def __init__(self, *, seed: int, name: str = "imu", config: ImuConfig | None = None):
        self._config = ImuConfig() if config is None else config
        super().__init__(
            name=name,
            seed=seed,
            rate_hz=self._config.rate_hz,
            delay_s=self._config.delay_s,
            initial=np.zeros(6),
            output_name="measurement",
        )
        self.angular_velocity_input = self.DeclareVectorInputPort("angular_velocity", 3)
        self.specific_force_input = self.DeclareVectorInputPort("specific_force", 3)
        bias0 = imu_initial_bias(generator(seed, f"{name}/initial_bias"), config=self._config)
        self._bias = self.DeclareDiscreteState(BasicVector(bias0))
        self._sigmas = (self._config.white_sigma, self._config.bias_step_sigma)
        self.bias_truth_output = self.DeclareStateOutputPort("bias_truth", self._bias)

    @property
    def config(self) -> ImuConfig:
        """Rate, delay and noise model."""
        return self._config

    def sample(self, context, generator, discrete_state):
        # imu_measurement's draws and arithmetic, with the sigmas computed once
        meas, next_bias = noisy_reading(
            self.angular_velocity_input.Eval(context), self.specific_force_input.Eval(context),
            context.get_discrete_state(self._bias).get_value(), generator.standard_normal(12),
            *self._sigmas,
        )  # fmt: skip
        discrete_state.set_value(self._bias, next_bias)
        return meas


def add_imu(
    builder,
    *,
    plant,
    body,
    seed: int,
    name: str = "imu",
    config: ImuConfig | None = None,
    X_BS: RigidTransform | None = None,
) -> Imu:
    """Adds an IMU fixed to ``body`` (a RigidBody of the finalized ``plant``) at ``X_BS``
    (default: the body frame): Drake's ``Gyroscope`` and ``Accelerometer`` (named
    ``name + ".gyroscope"`` and ``".accelerometer"``; the accelerometer subtracts the
    plant's gravity) fed by the plant's body ports, and the :class:`Imu` ``name`` that
    samples them with bias and noise. Returns the Imu."""
    X_BS = RigidTransform() if X_BS is None else X_BS
    gyro = builder.AddNamedSystem(f"{name}.gyroscope", Gyroscope(body, X_BS))
    accel = builder.AddNamedSystem(
        f"{name}.accelerometer",
        Accelerometer(body, X_BS, np.asarray(plant.gravity_field().gravity_vector(), float)),
    )
    imu = builder.AddNamedSystem(name, Imu(seed=seed, name=name, config=config))
    builder.Connect(plant.get_body_poses_output_port(), gyro.get_body_poses_input_port())
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), gyro.get_body_velocities_input_port()
    )
    builder.Connect(plant.get_body_poses_output_port(), accel.get_body_poses_input_port())
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), accel.get_body_velocities_input_port()
    )
    builder.Connect(
        plant.get_body_spatial_accelerations_output_port(),
        accel.get_body_accelerations_input_port(),
    )
    builder.Connect(gyro.get_measurement_output_port(), imu.angular_velocity_input)
    builder.Connect(accel.get_measurement_output_port(), imu.specific_force_input)
    return imu
