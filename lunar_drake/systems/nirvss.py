"""NIRVSSSensor: NIRVSS band depths and the LCS temperature under the rover (a plant
sensor)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform

from lunar_drake.science.nirvss import BANDS, NIRVSSConfig, SurfaceMap, measure, spot_means
from lunar_drake.systems.sampled_sensor import SampledSensor


class NIRVSSSensor(SampledSensor):
    """NIRVSS and its LCS on the chassis, looking at a spot ``config.x_m`` ahead of its
    centre (core: :mod:`lunar_drake.science.nirvss`).

    .. pydrake_system::

        name: NIRVSSSensor
        input_ports:
        - body_poses
        output_ports:
        - bands

    ``bands`` (8,): the band depths of :data:`~lunar_drake.science.nirvss.BANDS` then the
    LCS temperature (K), from the world model at the spot's true position; zeros before
    the first sample.
    """

    def __init__(self, *, body_index, smap: SurfaceMap, seed: int, name: str = "rover.nirvss",
                 config: NIRVSSConfig | None = None):  # fmt: skip
        self._config = NIRVSSConfig() if config is None else config
        self._config.validate()
        super().__init__(name=name, seed=seed, rate_hz=self._config.rate_hz,
                         delay_s=self._config.delay_s, initial=[0.0] * (len(BANDS) + 1),
                         output_name="bands")  # fmt: skip
        self._body = int(body_index)
        self._smap = smap
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )

    def sample(self, context, generator, discrete_state):
        X_WB = self.body_poses_input.Eval(context)[self._body]
        p = X_WB.multiply(np.array([self._config.x_m, 0.0, 0.0]))
        spot = spot_means(self._smap, float(p[0]), float(p[1]),
                          radius_m=self._config.spot_radius_m)  # fmt: skip
        return measure(spot, generator, config=self._config)
