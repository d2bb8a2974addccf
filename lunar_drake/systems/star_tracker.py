"""StarTracker: noisy absolute attitude of a MultibodyPlant body, sampled periodically."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.dynamics.sensor_models import (
    StarTrackerConfig,
    sample_index,
    star_tracker_measurement,
)
from lunar_drake.rng import stream_key


class StarTracker(LeafSystem):
    """Star tracker fixed to a plant body, reporting the body attitude (paper section 7).

    .. pydrake_system::

        name: StarTracker
        input_ports:
        - body_poses
        output_ports:
        - R_WB_measured

    ``body_poses`` is the plant's ``get_body_poses_output_port()`` (list of X_WB indexed
    by BodyIndex). ``R_WB_measured`` (4,) is the measured body attitude in W as a unit
    quaternion (w, x, y, z) with w >= 0: the tracker's frame S (boresight +z_S, fixed in
    B by ``R_BS``) is perturbed by a small rotation with independent per-axis noise
    (cross-boresight about x_S, y_S; roll about z_S), then mapped back to B. Discrete
    state, updated every ``1 / config.sample_rate_hz`` s from t = 0 (identity before the
    first sample), no feedthrough. Sample k's noise is keyed by
    (stream_key(seed, name), k, axis). Sun/Earth/Moon-limb exclusion and loss of lock
    at high rates are not modelled.

    Args:
        body_index: the plant BodyIndex (or int) the tracker is fixed to.
        seed: scenario random seed.
        name: system name and noise-stream name.
        config: :class:`StarTrackerConfig`.
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
        super().__init__()
        self.set_name(name)
        self._config = StarTrackerConfig() if config is None else config
        self._body = int(body_index)
        self._key = stream_key(seed, name)
        self._R_BS = np.eye(3) if R_BS is None else R_BS.matrix()
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self._q_index = self.DeclareDiscreteState(BasicVector([1.0, 0.0, 0.0, 0.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(
            1.0 / self._config.sample_rate_hz, 0.0, self._update
        )
        self.R_WB_measured_output = self.DeclareStateOutputPort("R_WB_measured", self._q_index)

    @property
    def config(self) -> StarTrackerConfig:
        """The noise model."""
        return self._config

    def _update(self, context, discrete_state):
        X_WB = self.body_poses_input.Eval(context)[self._body]
        k = sample_index(context.get_time(), self._config.sample_rate_hz)
        q = star_tracker_measurement(
            X_WB.rotation().matrix(), self._key, k, config=self._config, R_BS=self._R_BS
        )
        discrete_state.set_value(self._q_index, q)
