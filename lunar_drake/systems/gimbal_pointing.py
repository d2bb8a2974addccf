"""GimbalPointing (flight "Camera/Gimbal Pointing"): pan/tilt to look at a point."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem


def pan_tilt_to(p_GT_G: np.ndarray) -> tuple[float, float]:
    """Pan (about +z, positive left) and tilt (about +y, positive down) that point the
    gimbal's +x axis at a target at ``p_GT_G`` (m) in the gimbal base frame G."""
    x, y, z = (float(v) for v in p_GT_G)
    return math.atan2(y, x), math.atan2(-z, math.hypot(x, y))


class GimbalPointing(LeafSystem):
    """Closed-loop pointing of the mast gimbal at a world target, at ``rate_hz``.

    .. pydrake_system::

        name: GimbalPointing
        input_ports:
        - body_poses
        - target_W (optional)
        output_ports:
        - gimbal_command

    With ``target_W`` unconnected, the target is a ground point ``lookahead_m`` ahead of
    the chassis (x forward) at the chassis' ground level -- a driving view. Commands
    are clipped to the joint limits. The base frame G is the chassis frame translated
    to the pan axis (``p_CG``, m).

    Args:
        chassis_index: BodyIndex of the chassis. p_CG: pan-axis point in the chassis (m).
        ground_below_m: chassis origin height above the ground (m).
        lookahead_m: look-ahead distance (m). pan_limits, tilt_limits: (min, max) rad.
    """

    def __init__(
        self,
        *,
        chassis_index,
        p_CG,
        ground_below_m: float,
        lookahead_m: float = 6.0,
        pan_limits=(-math.pi, math.pi),
        tilt_limits=(-math.pi / 2, math.pi / 2),
        rate_hz: float = 10.0,
    ):
        super().__init__()
        self._c = int(chassis_index)
        self._p_CG = np.asarray(p_CG, float)
        self._ground = float(ground_below_m)
        self._look = float(lookahead_m)
        self._pan = pan_limits
        self._tilt = tilt_limits
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.target_input = self.DeclareVectorInputPort("target_W", 3)
        self._cmd = self.DeclareDiscreteState(np.array(self._lookahead_angles(), float))
        self.DeclarePeriodicDiscreteUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.gimbal_command_output = self.DeclareStateOutputPort("gimbal_command", self._cmd)

    def _lookahead_angles(self):
        p_GT = np.array([self._look - self._p_CG[0], -self._p_CG[1], -self._ground - self._p_CG[2]])
        return pan_tilt_to(p_GT)

    def _update(self, context, discrete_state):
        X_WC = self.body_poses_input.Eval(context)[self._c]
        if self.target_input.HasValue(context):
            p_WT = self.target_input.Eval(context)
            p_GT = X_WC.rotation().inverse().multiply(p_WT - X_WC.translation()) - self._p_CG
            pan, tilt = pan_tilt_to(p_GT)
        else:
            pan, tilt = self._lookahead_angles()
        pan = min(max(pan, self._pan[0]), self._pan[1])
        tilt = min(max(tilt, self._tilt[0]), self._tilt[1])
        discrete_state.get_mutable_vector(self._cmd).SetFromVector([pan, tilt])
