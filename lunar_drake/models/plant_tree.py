"""The joint tree of a MultibodyPlant as :class:`~lunar_drake.dynamics.tree_kinematics.
TreeKinematics` data (read once, after ``Finalize``)."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.tree import BodyIndex

from lunar_drake.dynamics.tree_kinematics import JOINT_KINDS, TreeKinematics
from lunar_drake.errors import ConfigError


def tree_kinematics_from_plant(plant) -> TreeKinematics:
    """The parents, joint types and fixed frames of every body of the finalized
    ``plant``. Raises ConfigError for a joint type :mod:`~lunar_drake.dynamics.
    tree_kinematics` does not model, or a body reached by other than one joint."""
    nb = plant.num_bodies()
    parent = np.full(nb, -1, np.int64)
    kind = np.zeros(nb, np.int64)
    q_start = np.zeros(nb, np.int64)
    v_start = np.zeros(nb, np.int64)
    eye = np.hstack([np.eye(3), np.zeros((3, 1))])
    X_PF = np.tile(eye, (nb, 1, 1))
    X_MB = np.tile(eye, (nb, 1, 1))
    X_FM = np.tile(eye, (nb, 1, 1))
    axis_F = np.zeros((nb, 3))
    world = int(plant.world_body().index())
    for i in plant.GetJointIndices():
        j = plant.get_joint(i)
        name = j.type_name()
        if name not in JOINT_KINDS:
            raise ConfigError(
                f"joint {j.name()!r} is {name!r}; the compiled tree kinematics model "
                f"{sorted(JOINT_KINDS)}"
            )
        b = int(j.child_body().index())
        if b == world or parent[b] != -1:
            raise ConfigError(
                f"joint {j.name()!r}: body {j.child_body().name()!r} already hangs from a "
                "joint or is the world; each body needs exactly one joint with the body as "
                "its child, its parent nearer the world"
            )
        parent[b] = int(j.parent_body().index())
        kind[b] = JOINT_KINDS[name]
        q_start[b] = j.position_start()
        v_start[b] = j.velocity_start()
        X_PF[b] = j.frame_on_parent().GetFixedPoseInBodyFrame().GetAsMatrix34()
        X_MB[b] = j.frame_on_child().GetFixedPoseInBodyFrame().inverse().GetAsMatrix34()
        if name == "weld":
            X_FM[b] = j.X_FM().GetAsMatrix34()
        elif name == "revolute":
            axis_F[b] = j.revolute_axis()
    unplaced = [
        plant.get_body(BodyIndex(b)).name() for b in range(nb) if b != world and parent[b] < 0
    ]
    if unplaced:
        raise ConfigError(
            f"bodies {unplaced} are the child of no joint; each body needs exactly one joint "
            "with the body as its child, its parent nearer the world"
        )
    depth = np.zeros(nb, np.int64)
    for b in range(nb):
        a = b
        while parent[a] >= 0:
            depth[b] += 1
            a = parent[a]
    order = np.array([b for b in np.argsort(depth, kind="stable") if b != world], np.int64)
    return TreeKinematics(
        order=order, parent=parent, kind=kind, q_start=q_start, v_start=v_start, X_PF=X_PF,
        X_MB=X_MB, X_FM=X_FM, axis_F=axis_F, nq=plant.num_positions(),
        nv=plant.num_velocities(),
    )  # fmt: skip
