"""StarTracker: noisy absolute attitude of a MultibodyPlant body."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix

from lunar_drake.sensors.star_tracker import StarTrackerConfig, star_tracker_measurement
from lunar_drake.systems.sampled_sensor import SampledSensor


class StarTracker(SampledSensor):
    """Star tracker fixed to a plant body, reporting the body attitude (paper section 7).

    .. pydrake_system::

        name: StarTracker
        input_ports:
        - body_poses
        output_ports:
        - q_WB_measured

    ``body_poses`` is the plant's ``get_body_poses_output_port()``. ``q_WB_measured``
    (4,) is the measured attitude of the body in W as a unit quaternion (w, x, y, z),
    w >= 0: the tracker frame S (boresight +z_S, fixed in B by ``R_BS``) is perturbed
    by a small rotation with independent per-axis noise (cross-boresight about x_S,
    y_S; roll about z_S), then mapped back to B. Sampled and delivered as
    :class:`SampledSensor` describes (identity before the first delivery).

    Args:
        body_index: the plant BodyIndex (or int) the tracker is fixed to.
        seed: scenario random seed. name: system name and noise-stream name.
        config: :class:`~lunar_drake.sensors.star_tracker.StarTrackerConfig`.
        R_BS: tracker orientation in the body (RotationMatrix); default identity, i.e.
            boresight along body +z (zenith when the rover is level).
    """

    def __init__(
        self,
        *,
        body_index,
        seed: int,
        name: str = "star_tracker",
        config: StarTrackerConfig | None = None,
        R_BS: RotationMatrix | None = None,
    ):
        self._config = StarTrackerConfig() if config is None else config
        super().__init__(
            name=name,
            seed=seed,
            rate_hz=self._config.rate_hz,
            delay_s=self._config.delay_s,
            initial=[1.0, 0.0, 0.0, 0.0],
            output_name="q_WB_measured",
        )
        self._body = int(body_index)
        self._R_BS = np.eye(3) if R_BS is None else R_BS.matrix()
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )

    @property
    def config(self) -> StarTrackerConfig:
        """Rate, delay and noise model."""
        return self._config

    def sample(self, context, generator, discrete_state):
        X_WB = self.body_poses_input.Eval(context)[self._body]
        return star_tracker_measurement(
            X_WB.rotation().matrix(), generator, config=self._config, R_BS=self._R_BS
        )
