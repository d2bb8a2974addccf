"""MeshcatSun: the Sun as Meshcat's directional light."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import EventStatus

from lunar_drake.systems.leaf import Leaf


class MeshcatSun(Leaf):
    """Points Meshcat's directional light along the Sun direction (site frame) and dims
    it when the Sun is below the horizon; publishes at ``period_s`` and at init.

    .. pydrake_system::

        name: MeshcatSun
        input_ports:
        - sun_direction_W
    """

    def __init__(self, *, meshcat, period_s: float = 1.0, distance_m: float = 100.0):
        super().__init__()
        self._meshcat = meshcat
        self._d = float(distance_m)
        self.sun_direction_input = self.DeclareVectorInputPort("sun_direction_W", 3)
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)

    def _publish(self, context):
        s = np.asarray(self.sun_direction_input.Eval(context), float)
        path = "/Lights/DirectionalLight/<object>"
        self._meshcat.SetProperty(path, "position", (s * self._d).tolist())
        self._meshcat.SetProperty(path, "intensity", 1.5 if s[2] > 0 else 0.05)
        return EventStatus.Succeeded()
