"""EarthLineOfSight: whether the rover's antenna sees the Earth over the terrain."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus

from lunar_drake.comms.line_of_sight import earth_margin_deg
from lunar_drake.systems.leaf import Leaf


class EarthLineOfSight(Leaf):
    """The Earth's elevation above the terrain horizon at the rover's antenna.

    .. pydrake_system::

        name: EarthLineOfSight
        input_ports:
        - earth_direction_W
        - pose
        output_ports:
        - earth_visible
        - earth_margin_deg

    Every ``period_s`` (and at initialization) it marches the site raster from the
    antenna (``antenna_height_m`` above the chassis origin, along world z) toward the
    Earth's azimuth (:func:`~lunar_drake.comms.line_of_sight.earth_margin_deg`) and holds
    the result in discrete state ``[visible (1/0), margin (deg)]``: the Earth's centre
    ``margin`` degrees above the terrain horizon, visible when the margin exceeds
    ``min_margin_deg``. ``pose`` is the chassis pose vector
    (:class:`~lunar_drake.systems.body_pose_vector.BodyPoseVector`): physics of the
    radio path, part of the plant, read by the link model, never by the software.

    Args:
        heightfield: the site raster. period_s: update period (s), > 0.
        antenna_height_m: antenna above the chassis origin (m). min_margin_deg: the
            Earth counts as visible above this margin (deg).
    """

    def __init__(
        self,
        *,
        heightfield,
        period_s: float = 1.0,
        antenna_height_m: float = 1.0,
        min_margin_deg: float = 0.0,
    ):
        super().__init__()
        if not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s = {period_s!r} must be a positive number")
        self._hf = heightfield
        self._h = float(antenna_height_m)
        self._min = float(min_margin_deg)
        self.earth_direction_input = self.DeclareVectorInputPort("earth_direction_W", 3)
        self.pose_input = self.DeclareVectorInputPort("pose", 12)
        self._state = self.DeclareDiscreteState(BasicVector([1.0, 90.0]))
        self.DeclarePeriodicDiscreteUpdateEvent(period_s, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.earth_visible_output = self.DeclareVectorOutputPort(
            "earth_visible", 1, lambda c, o: o.SetFromVector(c.get_discrete_state(0).value()[:1])
        )
        self.earth_margin_output = self.DeclareVectorOutputPort(
            "earth_margin_deg",
            1,
            lambda c, o: o.SetFromVector(c.get_discrete_state(0).value()[1:]),
        )

    def _update(self, context, state):
        pose = self.pose_input.Eval(context)
        p = np.array([pose[0], pose[1], pose[2] + self._h])
        margin = earth_margin_deg(
            heightfield=self._hf, p_W=p, earth_direction_W=self.earth_direction_input.Eval(context)
        )
        state.get_mutable_vector(0).SetFromVector([1.0 if margin > self._min else 0.0, margin])
        return EventStatus.Succeeded()
