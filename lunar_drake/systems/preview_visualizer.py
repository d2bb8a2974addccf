"""PreviewVisualizer: the ground's command preview drawn in Meshcat."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Rgba
from pydrake.systems.framework import EventStatus

from lunar_drake.systems.leaf import Leaf


class PreviewVisualizer(Leaf):
    """Draws the predicted path of the newest goto the ground sent (the operator's
    ``preview`` output: (seq, (N, 4) rows of t, x, y, z)) as a line ``lift_m`` above the
    ground's map at ``path``, every ``period_s``, beside the live rover.

    .. pydrake_system::

        name: PreviewVisualizer
        input_ports:
        - preview
    """

    def __init__(self, *, meshcat, period_s: float = 1.0, path: str = "/ground/preview",
                 lift_m: float = 0.1):  # fmt: skip
        super().__init__()
        self._meshcat = meshcat
        self._path = path
        self._lift = float(lift_m)
        self.preview_input = self.DeclareAbstractInputPort(
            "preview", AbstractValue.Make((-1, None))
        )
        self.DeclarePeriodicPublishEvent(period_s, 0.0, self._publish)

    def _publish(self, context):
        _, pts = self.preview_input.Eval(context)
        if pts is not None and len(pts) >= 2:
            xyz = np.asarray(pts, float)[:, 1:4].T.copy()
            xyz[2] += self._lift
            self._meshcat.SetLine(self._path, xyz, 3.0, Rgba(0.1, 0.8, 1.0, 1.0))
        return EventStatus.Succeeded()
