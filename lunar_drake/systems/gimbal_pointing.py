"""GimbalPointing (flight "Camera/Gimbal Pointing"): pan/tilt to look at a point."""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import BasicVector

from lunar_drake.errors import check_range
from lunar_drake.rotations import rotation_matrix_from_quaternion
from lunar_drake.systems.leaf import Leaf


@dc.dataclass
class GimbalPointingConfig:
    """How the flight software points the mast cameras.

    Attributes:
        rate_hz: pointing update rate (Hz).
        lookahead_m: with no target, look at the ground this far ahead of the chassis
            origin along the chassis x axis (m).
    """

    rate_hz: float = 10.0
    lookahead_m: float = 6.0

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("rate_hz", self.rate_hz, 0.0, 1000.0, lo_open=True, unit=" Hz")
        check_range("lookahead_m", self.lookahead_m, 0.5, 1000.0, unit=" m")


def pan_tilt_to(p_GT_G: np.ndarray) -> tuple[float, float]:
    """Pan (about +z, positive left) and tilt (about +y, positive down) that point the
    gimbal's +x axis at a target at ``p_GT_G`` (m) in the gimbal base frame G."""
    x, y, z = (float(v) for v in p_GT_G)
    return math.atan2(y, x), math.atan2(-z, math.hypot(x, y))


def gimbal_centre_C(description) -> np.ndarray:
    """Pan/tilt centre in the chassis frame C (m), from the rover description (the mast
    stands on the chassis top at x = ``mast_x_m``)."""
    d = description
    return np.array([d.mast_x_m, 0.0, d.chassis_height_m / 2 + d.mast_height_m])


class GimbalPointing(Leaf):
    """Points the mast gimbal, from the rover's own estimate and commands, never truth.

    .. pydrake_system::

        name: GimbalPointing
        input_ports:
        - q_WB_estimate (optional)
        - p_WB_estimate (optional)
        - target_W (optional)
        - hold (optional)
        output_ports:
        - gimbal_command

    With ``target_W`` unconnected the target is a ground point ``lookahead_m`` ahead of
    the chassis origin (x forward) at the nominal ground level below it: a driving view,
    fixed in the chassis frame. With ``target_W`` (m, site frame) connected, the pan/tilt
    that look at it from the estimated pose (``p_WB_estimate`` (3,), ``q_WB_estimate``
    (4,) = (w, x, y, z)). Commands (pan, tilt in rad) are clipped to the joint limits and
    updated at ``config.rate_hz``; G is the chassis frame translated to the pan axis.
    ``hold`` (3,) = (held, pan, tilt) overrides both while held is 1 (the operator's
    mast command, through the executor).

    Args:
        description: the RoverDescription (mast geometry, joint limits).
        config: :class:`GimbalPointingConfig`.
    """

    def __init__(self, *, description, config: GimbalPointingConfig):
        super().__init__()
        config.validate()
        d = description
        self._p_CG = gimbal_centre_C(d)
        self._ground = float(d.nominal_chassis_height_m())
        self._look = float(config.lookahead_m)
        self._pan = (d.gimbal_pan_min_rad, d.gimbal_pan_max_rad)
        self._tilt = (d.gimbal_tilt_min_rad, d.gimbal_tilt_max_rad)
        self.q_WB_input = self.DeclareVectorInputPort("q_WB_estimate", 4)
        self.p_WB_input = self.DeclareVectorInputPort("p_WB_estimate", 3)
        self.target_input = self.DeclareVectorInputPort("target_W", 3)
        self.hold_input = self.DeclareVectorInputPort("hold", 3)
        self._cmd = self.DeclareDiscreteState(BasicVector(self._clip(*self._lookahead())))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / config.rate_hz, 0.0, self._update)
        self.gimbal_command_output = self.DeclareStateOutputPort("gimbal_command", self._cmd)

    def _lookahead(self):
        p_GT = np.array([self._look, 0.0, -self._ground]) - self._p_CG
        return pan_tilt_to(p_GT)

    def _clip(self, pan, tilt):
        return [
            min(max(pan, self._pan[0]), self._pan[1]),
            min(max(tilt, self._tilt[0]), self._tilt[1]),
        ]

    def _update(self, context, discrete_state):
        hold = self.hold_input.Eval(context) if self.hold_input.HasValue(context) else None
        if hold is not None and hold[0] > 0.5:
            pan, tilt = float(hold[1]), float(hold[2])
        elif self.target_input.HasValue(context):
            R_WC = rotation_matrix_from_quaternion(self.q_WB_input.Eval(context))
            p_WC = np.asarray(self.p_WB_input.Eval(context))
            p_WT = np.asarray(self.target_input.Eval(context))
            pan, tilt = pan_tilt_to(R_WC.T @ (p_WT - p_WC) - self._p_CG)
        else:
            pan, tilt = self._lookahead()
        discrete_state.get_mutable_vector(self._cmd).SetFromVector(self._clip(pan, tilt))
