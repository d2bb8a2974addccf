"""WheelEncoders: quantized wheel angles (wheel odometry input)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.primitives import MatrixGain

from lunar_drake.errors import ConfigError
from lunar_drake.sensors.wheel_encoders import WheelEncoderConfig, encoder_angles
from lunar_drake.systems.sampled_sensor import SampledSensor


class WheelEncoders(SampledSensor):
    """Incremental encoders on n wheel joints (paper section 7, wheel odometry).

    .. pydrake_system::

        name: WheelEncoders
        input_ports:
        - wheel_angles
        output_ports:
        - angles

    ``wheel_angles`` (n,) are the true wheel joint angles (rad), e.g. from the plant
    state through :func:`wheel_angle_selector`. ``angles`` (n,) are the measured angles
    (rad): whole encoder counts times the count angle (plus optional angle noise before
    quantization); sampled and delivered as :class:`SampledSensor` describes (zero
    before the first delivery).

    Args:
        n_wheels: number of wheels n. seed: scenario random seed.
        name: system name and noise-stream name.
        config: :class:`~lunar_drake.sensors.wheel_encoders.WheelEncoderConfig`.
    """

    def __init__(
        self,
        *,
        n_wheels: int,
        seed: int,
        name: str = "wheel_encoders",
        config: WheelEncoderConfig | None = None,
    ):
        if int(n_wheels) != n_wheels or n_wheels < 1:
            raise ConfigError(f"n_wheels = {n_wheels!r}; must be an integer >= 1")
        self._config = WheelEncoderConfig() if config is None else config
        super().__init__(
            name=name,
            seed=seed,
            rate_hz=self._config.rate_hz,
            delay_s=self._config.delay_s,
            initial=np.zeros(int(n_wheels)),
            output_name="angles",
        )
        self._n = int(n_wheels)
        self.wheel_angles_input = self.DeclareVectorInputPort("wheel_angles", self._n)

    @property
    def config(self) -> WheelEncoderConfig:
        """Rate, delay, resolution and noise."""
        return self._config

    def sample(self, context, generator, discrete_state):
        angles = self.wheel_angles_input.Eval(context)
        return encoder_angles(angles, config=self._config, generator=generator)


def wheel_angle_selector(plant, joints: Sequence) -> MatrixGain:
    """A MatrixGain mapping the plant state [q; v] to the angles (rad) of ``joints``.

    ``joints`` are single-dof (revolute) Joint objects of the finalized ``plant``, in the
    order of the encoders; connect ``plant.get_state_output_port()`` to its input.
    """
    nx = plant.num_positions() + plant.num_velocities()
    d = np.zeros((len(joints), nx))
    for i, joint in enumerate(joints):
        if joint.num_positions() != 1:
            raise ConfigError(
                f"joint {joint.name()!r} has {joint.num_positions()} positions; "
                "a wheel encoder needs a single-dof joint"
            )
        d[i, joint.position_start()] = 1.0
    return MatrixGain(d)
