"""Forward kinematics of a rover's joint tree from its state vector: each body's pose
``X_WB`` and spatial velocity ``V_WB`` (angular, then the velocity of its origin; both in
W), and the generalized forces ``J^T F`` of spatial forces on its bodies; compiled.

The contact needs five bodies' poses and velocities at every plant step. Read from the
MultibodyPlant's list ports they cost 45 us a step in conversions to Python (a list of
16 RigidTransforms, one of 16 SpatialVelocities, then one array each); from the plant's
state vector and :func:`body_kinematics` about 5 us. The tree (parents, joint types,
fixed frames) is data read once from the plant (:func:`TreeKinematics` fields; the
Drake side is :func:`lunar_drake.models.plant_tree.tree_kinematics_from_plant`). The
contact's forces go back to the plant the same way: as generalized forces
(:func:`generalized_forces`, a vector port) rather than a list of
``ExternallyAppliedSpatialForce`` objects built in Python every step.

Joints: weld (fixed ``X_FM``), revolute (angle ``q`` about a unit axis fixed in F and
M; ``v = q'``) and quaternion floating (``q = [qw, qx, qy, qz, x, y, z]`` of ``X_FM``,
``v = [w_FM, v_FM]`` in F), Drake's conventions. A body B hangs from its parent P
through frame F (on P, ``X_PF``) and frame M (on B, ``X_BM``):
``X_WB = X_WP X_PF X_FM(q) X_MB``.
"""

from __future__ import annotations

import dataclasses as dc

import numba
import numpy as np

from lunar_drake.errors import ConfigError

WELD, REVOLUTE, QUATERNION_FLOATING = 0, 1, 2
#: Joint type names (Drake's ``Joint.type_name()``) to the codes above.
JOINT_KINDS = {"weld": WELD, "revolute": REVOLUTE, "quaternion_floating": QUATERNION_FLOATING}


@dc.dataclass(frozen=True)
class TreeKinematics:
    """A joint tree, one row per body (index 0 the world, no joint).

    Attributes:
        order: (m,) the bodies other than the world, each after its parent.
        parent: (nb,) parent body of each body (-1 for the world).
        kind: (nb,) joint type code of each body's inboard joint (:data:`JOINT_KINDS`).
        q_start, v_start: (nb,) the joint's first position / velocity in the state.
        X_PF: (nb, 3, 4) the joint's frame F on the parent, ``[R | p]``.
        X_MB: (nb, 3, 4) the body frame in the joint's frame M on the body.
        X_FM: (nb, 3, 4) a weld's fixed ``X_FM`` (identity otherwise).
        axis_F: (nb, 3) a revolute joint's unit axis in F (and M).
        nq, nv: sizes of the state ``x = [q, v]``.
    """

    order: np.ndarray
    parent: np.ndarray
    kind: np.ndarray
    q_start: np.ndarray
    v_start: np.ndarray
    X_PF: np.ndarray
    X_MB: np.ndarray
    X_FM: np.ndarray
    axis_F: np.ndarray
    nq: int
    nv: int

    @property
    def n_bodies(self) -> int:
        """Bodies, the world included."""
        return len(self.parent)


def body_kinematics(tree: TreeKinematics, x, bodies, X_out, V_out) -> None:
    """Fills ``X_out[k]`` (3, 4) ``[R_WB | p_WB]`` and ``V_out[k]`` (6,) ``[w_WB, v_WBo]``
    (rad/s, m/s; in W) of body ``bodies[k]`` from the state ``x = [q, v]``
    (``tree.nq + tree.nv``). Raises ConfigError for a state of the wrong size or not
    finite, a body index out of the tree or outputs of the wrong shape."""
    x, bodies = _checked(tree, x, bodies)
    m = len(bodies)
    if np.shape(X_out) != (m, 3, 4) or np.shape(V_out) != (m, 6):
        raise ConfigError(
            f"outputs of shapes {np.shape(X_out)} and {np.shape(V_out)}; "
            f"{m} bodies need ({m}, 3, 4) and ({m}, 6)"
        )
    body_kinematics_kernel(*kernel_args(tree), x, bodies, X_out, V_out)


def _checked(tree: TreeKinematics, x, bodies) -> tuple[np.ndarray, np.ndarray]:
    """``(x, bodies)`` as float64 and int64 arrays, or ConfigError naming what is wrong."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape != (tree.nq + tree.nv,):
        raise ConfigError(f"state has shape {x.shape}; the tree needs ({tree.nq + tree.nv},)")
    bad = int(np.count_nonzero(~np.isfinite(x)))
    if bad:
        raise ConfigError(
            f"state has {bad} non-finite value(s); positions and velocities must be finite"
        )
    bodies = np.asarray(bodies, np.int64).ravel()
    if bodies.size and (bodies.min() < 0 or bodies.max() >= tree.n_bodies):
        raise ConfigError(f"bodies {bodies.tolist()}: a body index is 0..{tree.n_bodies - 1}")
    return x, bodies


def kernel_args(tree: TreeKinematics) -> tuple:
    """The arguments of :func:`body_kinematics_kernel` before ``x`` (the velocity starts
    offset by ``nq``: indices into ``x``)."""
    return (tree.order, tree.parent, tree.kind, tree.q_start, tree.v_start + tree.nq,
            tree.X_PF, tree.X_MB, tree.X_FM, tree.axis_F)  # fmt: skip


@numba.njit(cache=True, inline="always")
def _rot_mul(A, B, out):
    """``out = A B`` for the 3x3 blocks of (3, 4) poses (any 3x3 views)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@numba.njit(cache=True, inline="always")
def _compose(A, B, out):
    """``out = A B`` for (3, 4) poses ``[R | p]``."""
    _rot_mul(A, B, out)
    for i in range(3):
        out[i, 3] = A[i, 0] * B[0, 3] + A[i, 1] * B[1, 3] + A[i, 2] * B[2, 3] + A[i, 3]


@numba.njit(cache=True)
def body_kinematics_kernel(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld,
                           axis_F, x, bodies, X_out, V_out):  # pragma: no cover  # fmt: skip
    """:func:`body_kinematics` compiled: ``*kernel_args(tree), x, bodies, X_out, V_out``
    (``x`` float64 (nq + nv,), ``bodies`` int64; no checks)."""
    X, V, _, _ = _all_frames(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld,
                             axis_F, x)  # fmt: skip
    for k in range(bodies.shape[0]):
        X_out[k] = X[bodies[k]]
        V_out[k] = V[bodies[k]]


@numba.njit(cache=True, inline="always")
def _all_frames(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld, axis_F,
                x):  # pragma: no cover  # fmt: skip
    """``(X, V, X_WF, X_WM)`` of every body (and its joint) from the state ``x``
    (:func:`_tree_kinematics` into new arrays)."""
    nb = parent.shape[0]
    X = np.empty((nb, 3, 4))
    V = np.empty((nb, 6))
    X_WF = np.empty((nb, 3, 4))
    X_WM = np.empty((nb, 3, 4))
    _tree_kinematics(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld, axis_F,
                     x, X, V, X_WF, X_WM)  # fmt: skip
    return X, V, X_WF, X_WM


@numba.njit(cache=True, inline="always")
def _tree_kinematics(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld, axis_F,
                     x, X, V, X_WF_all, X_WM_all):  # pragma: no cover  # fmt: skip
    """Every body's ``X[b]`` and ``V[b]`` (the world's: identity, zero) and every joint's
    frames ``X_WF_all[b]``, ``X_WM_all[b]`` in W (b > 0) from the state ``x``."""
    for i in range(3):
        for j in range(4):
            X[0, i, j] = 1.0 if i == j else 0.0
    V[0, :] = 0.0
    X_FM = np.empty((3, 4))
    w_FM = np.zeros(3)
    v_FM = np.zeros(3)
    wB = np.empty(3)
    rM = np.empty(3)
    rB = np.empty(3)
    for b in order:
        p = parent[b]
        X_WF = X_WF_all[b]
        X_WM = X_WM_all[b]
        _compose(X[p], X_PF[b], X_WF)
        w_FM[:] = 0.0
        v_FM[:] = 0.0
        k = kind[b]
        if k == WELD:
            X_FM[:, :] = X_FM_weld[b]
        elif k == REVOLUTE:  # Rodrigues about the axis, origin on it
            q = x[q_start[b]]
            c = np.cos(q)
            s = np.sin(q)
            t = 1.0 - c
            ax, ay, az = axis_F[b, 0], axis_F[b, 1], axis_F[b, 2]
            X_FM[0, 0] = c + t * ax * ax
            X_FM[0, 1] = t * ax * ay - s * az
            X_FM[0, 2] = t * ax * az + s * ay
            X_FM[1, 0] = t * ax * ay + s * az
            X_FM[1, 1] = c + t * ay * ay
            X_FM[1, 2] = t * ay * az - s * ax
            X_FM[2, 0] = t * ax * az - s * ay
            X_FM[2, 1] = t * ay * az + s * ax
            X_FM[2, 2] = c + t * az * az
            X_FM[0, 3] = 0.0
            X_FM[1, 3] = 0.0
            X_FM[2, 3] = 0.0
            qd = x[v_index[b]]
            w_FM[0] = ax * qd
            w_FM[1] = ay * qd
            w_FM[2] = az * qd
        else:  # QUATERNION_FLOATING (the only other code)
            # q = [qw, qx, qy, qz, x, y, z], v = [w_FM, v_FM] in F
            i0 = q_start[b]
            w, qx, qy, qz = x[i0], x[i0 + 1], x[i0 + 2], x[i0 + 3]
            s = 2.0 / (w * w + qx * qx + qy * qy + qz * qz)  # unit or not, as Drake
            X_FM[0, 0] = 1.0 - s * (qy * qy + qz * qz)
            X_FM[0, 1] = s * (qx * qy - w * qz)
            X_FM[0, 2] = s * (qx * qz + w * qy)
            X_FM[1, 0] = s * (qx * qy + w * qz)
            X_FM[1, 1] = 1.0 - s * (qx * qx + qz * qz)
            X_FM[1, 2] = s * (qy * qz - w * qx)
            X_FM[2, 0] = s * (qx * qz - w * qy)
            X_FM[2, 1] = s * (qy * qz + w * qx)
            X_FM[2, 2] = 1.0 - s * (qx * qx + qy * qy)
            for i in range(3):
                X_FM[i, 3] = x[i0 + 4 + i]
                w_FM[i] = x[v_index[b] + i]
                v_FM[i] = x[v_index[b] + 3 + i]
        _compose(X_WF, X_FM, X_WM)
        _compose(X_WM, X_MB[b], X[b])
        # w_WB = w_WP + R_WF w_FM; v_WM = v_WP + w_WP x (p_WM - p_WP) + R_WF v_FM
        # (F moves with P; M's origin moves in F at v_FM); v_WB = v_WM + w_WB x p_MB_W
        wP0, wP1, wP2 = V[p, 0], V[p, 1], V[p, 2]
        for i in range(3):
            wB[i] = V[p, i] + X_WF[i, 0] * w_FM[0] + X_WF[i, 1] * w_FM[1] + X_WF[i, 2] * w_FM[2]
            rM[i] = X_WM[i, 3] - X[p, i, 3]
            rB[i] = X[b, i, 3] - X_WM[i, 3]
        vM0 = V[p, 3] + (wP1 * rM[2] - wP2 * rM[1])
        vM1 = V[p, 4] + (wP2 * rM[0] - wP0 * rM[2])
        vM2 = V[p, 5] + (wP0 * rM[1] - wP1 * rM[0])
        vM0 += X_WF[0, 0] * v_FM[0] + X_WF[0, 1] * v_FM[1] + X_WF[0, 2] * v_FM[2]
        vM1 += X_WF[1, 0] * v_FM[0] + X_WF[1, 1] * v_FM[1] + X_WF[1, 2] * v_FM[2]
        vM2 += X_WF[2, 0] * v_FM[0] + X_WF[2, 1] * v_FM[1] + X_WF[2, 2] * v_FM[2]
        V[b, 0], V[b, 1], V[b, 2] = wB[0], wB[1], wB[2]
        V[b, 3] = vM0 + (wB[1] * rB[2] - wB[2] * rB[1])
        V[b, 4] = vM1 + (wB[2] * rB[0] - wB[0] * rB[2])
        V[b, 5] = vM2 + (wB[0] * rB[1] - wB[1] * rB[0])


def generalized_forces(tree: TreeKinematics, x, bodies, F_W, tau_out) -> None:
    """Fills ``tau_out`` (nv,) with the generalized forces ``sum_k J_k^T F_W[k]`` of the
    spatial forces ``F_W[k]`` (6,) ``[moment about Bo (N m), force (N)]`` in W, applied
    at the origin of body ``bodies[k]``, in the state ``x = [q, v]``: what Drake's
    MultibodyPlant applies for the same forces on its ``applied_spatial_force`` port.
    A revolute joint takes the moment about its origin along its axis; a floating
    joint the moment and force, expressed in its frame F. Raises ConfigError as
    :func:`body_kinematics` does, or for forces or an output of the wrong shape, or
    forces not finite."""
    x, bodies = _checked(tree, x, bodies)
    m = len(bodies)
    F_W = np.asarray(F_W, dtype=np.float64)
    if F_W.shape != (m, 6) or np.shape(tau_out) != (tree.nv,):
        raise ConfigError(
            f"forces of shape {F_W.shape} and output of shape {np.shape(tau_out)}; "
            f"{m} bodies need ({m}, 6) and ({tree.nv},)"
        )
    bad = int(np.count_nonzero(~np.isfinite(F_W)))
    if bad:
        raise ConfigError(f"forces have {bad} non-finite value(s); forces must be finite")
    generalized_forces_kernel(*kernel_args(tree), x, bodies, np.ascontiguousarray(F_W), tau_out)


@numba.njit(cache=True)
def generalized_forces_kernel(order, parent, kind, q_start, v_index, X_PF, X_MB, X_FM_weld,
                              axis_F, x, bodies, F_W, tau_out):  # pragma: no cover  # fmt: skip
    """:func:`generalized_forces` compiled: ``*kernel_args(tree), x, bodies, F_W,
    tau_out`` (no checks). Each force is carried down the path from its body to the
    world: at each joint, its moment about the joint's origin M, projected on what the
    joint lets move."""
    X, _, X_WF, X_WM = _all_frames(order, parent, kind, q_start, v_index, X_PF, X_MB,
                                   X_FM_weld, axis_F, x)  # fmt: skip
    v0 = x.shape[0] - tau_out.shape[0]  # v_index is into x = [q, v]
    tau_out[:] = 0.0
    for k in range(bodies.shape[0]):
        b = bodies[k]
        m0, m1, m2 = F_W[k, 0], F_W[k, 1], F_W[k, 2]
        f0, f1, f2 = F_W[k, 3], F_W[k, 4], F_W[k, 5]
        j = b
        while parent[j] >= 0:
            kj = kind[j]
            if kj != WELD:
                # the moment about M's origin: m + (p_WBo - p_WM) x f
                r0 = X[b, 0, 3] - X_WM[j, 0, 3]
                r1 = X[b, 1, 3] - X_WM[j, 1, 3]
                r2 = X[b, 2, 3] - X_WM[j, 2, 3]
                a0 = m0 + (r1 * f2 - r2 * f1)
                a1 = m1 + (r2 * f0 - r0 * f2)
                a2 = m2 + (r0 * f1 - r1 * f0)
                iv = v_index[j] - v0
                R = X_WF[j]
                if kj == REVOLUTE:  # (R_WF axis_F) . moment = axis_F . (R_WF^T moment)
                    for i in range(3):
                        tau_out[iv] += axis_F[j, i] * (R[0, i] * a0 + R[1, i] * a1 + R[2, i] * a2)
                else:  # QUATERNION_FLOATING: [w_FM, v_FM] in F, so R_WF^T (moment, force)
                    for i in range(3):
                        tau_out[iv + i] += R[0, i] * a0 + R[1, i] * a1 + R[2, i] * a2
                        tau_out[iv + 3 + i] += R[0, i] * f0 + R[1, i] * f1 + R[2, i] * f2
            j = parent[j]
