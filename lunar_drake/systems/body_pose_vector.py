"""BodyPoseVector: ground truth of one body's pose and velocity as a vector."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialVelocity
from pydrake.systems.framework import BasicVector

from lunar_drake.systems.leaf import Leaf


class BodyPoseVector(Leaf):
    """Ground truth of one body as a vector.

    .. pydrake_system::

        name: BodyPoseVector
        input_ports:
        - body_poses
        - body_spatial_velocities
        output_ports:
        - pose

    ``pose`` = [x, y, z (m), roll, pitch, yaw (rad), vx, vy, vz (m/s, world),
    wx, wy, wz (rad/s, world)] of the body frame in the world (site) frame.
    """

    FIELDS = (
        "x_m",
        "y_m",
        "z_m",
        "roll_rad",
        "pitch_rad",
        "yaw_rad",
        "vx_mps",
        "vy_mps",
        "vz_mps",
        "wx_radps",
        "wy_radps",
        "wz_radps",
    )

    def __init__(self, *, body_index):
        super().__init__()
        self._b = int(body_index)
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.body_spatial_velocities_input = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()])
        )
        self.pose_output = self.DeclareVectorOutputPort("pose", BasicVector(12), self._calc)

    def _calc(self, context, output):
        X = self.body_poses_input.Eval(context)[self._b]
        V = self.body_spatial_velocities_input.Eval(context)[self._b]
        rpy = RollPitchYaw(X.rotation()).vector()
        output.SetFromVector(
            np.concatenate([X.translation(), rpy, V.translational(), V.rotational()])
        )
