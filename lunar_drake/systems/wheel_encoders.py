"""WheelEncoders: quantized wheel angles sampled periodically (wheel odometry input)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import MatrixGain

from lunar_drake.dynamics.sensor_models import (
    WheelEncoderConfig,
    encoder_angles,
    encoder_counts,
    sample_index,
)
from lunar_drake.errors import ConfigError
from lunar_drake.rng import stream_key


class WheelEncoders(LeafSystem):
    """Incremental encoders on n wheel joints (paper section 7, wheel odometry).

    .. pydrake_system::

        name: WheelEncoders
        input_ports:
        - wheel_angles
        output_ports:
        - counts
        - angles

    ``wheel_angles`` (n,) are the wheel joint angles (rad), e.g. from the plant state
    through :func:`wheel_angle_selector`. ``counts`` (n,) are the integer counts (as
    floats) of the last sample, nearest count to the angle (plus optional angle noise
    before quantization); ``angles`` (n,) are those counts converted back to rad.
    ``counts`` is discrete state, updated every ``1 / config.sample_rate_hz`` s from
    t = 0 (zero before the first sample), no feedthrough.

    Args:
        n_wheels: number of wheels n.
        seed: scenario random seed (only used when ``config.angle_noise_sigma_rad > 0``).
        name: system name and noise-stream name.
        config: :class:`WheelEncoderConfig`.
    """

    def __init__(
        self,
        *,
        n_wheels: int,
        seed: int,
        name: str = "wheel_encoders",
        config: WheelEncoderConfig | None = None,
    ):
        super().__init__()
        if int(n_wheels) != n_wheels or n_wheels < 1:
            raise ConfigError(f"n_wheels = {n_wheels!r}; must be an integer >= 1")
        self.set_name(name)
        self._n = int(n_wheels)
        self._config = WheelEncoderConfig() if config is None else config
        self._key = stream_key(seed, name)
        self.wheel_angles_input = self.DeclareVectorInputPort("wheel_angles", self._n)
        self._counts_index = self.DeclareDiscreteState(self._n)
        self.DeclarePeriodicDiscreteUpdateEvent(
            1.0 / self._config.sample_rate_hz, 0.0, self._update
        )
        self.counts_output = self.DeclareStateOutputPort("counts", self._counts_index)
        self.angles_output = self.DeclareVectorOutputPort(
            "angles",
            self._n,
            self._calc_angles,
            prerequisites_of_calc={self.discrete_state_ticket(self._counts_index)},
        )

    @property
    def config(self) -> WheelEncoderConfig:
        """The encoder model."""
        return self._config

    def _update(self, context, discrete_state):
        angles = self.wheel_angles_input.Eval(context)
        k = sample_index(context.get_time(), self._config.sample_rate_hz)
        counts = encoder_counts(angles, config=self._config, key=self._key, step=k)
        discrete_state.set_value(self._counts_index, counts)

    def _calc_angles(self, context, output):
        counts = context.get_discrete_state(self._counts_index).get_value()
        output.SetFromVector(encoder_angles(counts, config=self._config))


def wheel_angle_selector(plant, joints: Sequence) -> MatrixGain:
    """A MatrixGain mapping the plant state [q; v] to the angles (rad) of ``joints``.

    ``joints`` are single-dof (revolute) Joint objects of the finalized ``plant``, in the
    order of the encoders. Connect ``plant.get_state_output_port()`` (or a model
    instance's state port together with that instance's joints' offsets) to its input.
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
