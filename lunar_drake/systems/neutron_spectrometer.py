"""NeutronSpectrometer: NSS counts from the world model under the rover (a plant sensor)."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform

from lunar_drake.science.nss import HydrogenMap, NSSConfig, draw_counts, footprint_weh
from lunar_drake.systems.sampled_sensor import SampledSensor


class NeutronSpectrometer(SampledSensor):
    """The NSS on the chassis, ``config.x_m`` ahead of its centre (issue 15; the core is
    :mod:`lunar_drake.science.nss`).

    .. pydrake_system::

        name: NeutronSpectrometer
        input_ports:
        - body_poses
        output_ports:
        - counts

    Each sample (every ``1 / rate_hz`` s) integrates the footprint- and depth-weighted
    hydrogen of the world model (``hmap``, the truth) under the detector's true position
    and draws Poisson counts; ``counts`` (2,) is ``(epithermal, thermal)`` over the last
    integration (zeros before the first), delivered as :class:`SampledSensor` describes.
    """

    def __init__(self, *, body_index, hmap: HydrogenMap, seed: int, name: str = "rover.nss",
                 config: NSSConfig | None = None):  # fmt: skip
        self._config = NSSConfig() if config is None else config
        self._config.validate()
        super().__init__(
            name=name,
            seed=seed,
            rate_hz=self._config.rate_hz,
            delay_s=self._config.delay_s,
            initial=[0.0, 0.0],
            output_name="counts",
        )
        self._body = int(body_index)
        self._hmap = hmap
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )

    @property
    def config(self) -> NSSConfig:
        return self._config

    def detector_xy(self, X_WB: RigidTransform) -> tuple[float, float]:
        """The detector's (x, y) in the site frame (m) for chassis pose ``X_WB``."""
        p = X_WB.multiply(np.array([self._config.x_m, 0.0, 0.0]))
        return float(p[0]), float(p[1])

    def sample(self, context, generator, discrete_state):
        X_WB = self.body_poses_input.Eval(context)[self._body]
        weh = footprint_weh(self._hmap, *self.detector_xy(X_WB), config=self._config)
        return np.array(draw_counts(weh, generator, config=self._config), np.float64)
