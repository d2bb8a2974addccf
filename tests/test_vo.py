"""ICP visual odometry (perception/vo.py) on synthetic terrain clouds with a known
motion: recovery, rejection of degenerate, wrong-basin and empty alignments."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lunar_drake.errors import OutOfRangeError
from lunar_drake.perception.vo import VoConfig, align, correction, point_to_plane_information


def _terrain(n=40000, seed=0):
    """A bumpy patch 8 m square (undulations and rocks), in a camera-like frame."""
    g = np.random.default_rng(seed)
    x = g.uniform(-4, 4, n)
    y = g.uniform(-4, 4, n)
    z = 0.15 * np.sin(1.3 * x) * np.cos(0.9 * y) + 0.08 * np.sin(3.1 * x + 1) * np.sin(2.3 * y)
    for cx, cy, r in g.uniform([-3, -3, 0.2], [3, 3, 0.5], (12, 3)):
        d = np.hypot(x - cx, y - cy)
        z += np.where(d < r, 0.6 * np.sqrt(np.maximum(r * r - d * d, 0.0)), 0.0)
    return np.column_stack([x, y, z])


def _T(rpy_deg, xyz):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", rpy_deg, degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T


def _seen_from(T_prev_curr, P, *, noise_m=0.0, seed=1):
    Ti = np.linalg.inv(T_prev_curr)
    C = P @ Ti[:3, :3].T + Ti[:3, 3]
    C = C[np.abs(C[:, 0]) < 3.5]  # partial overlap
    return C + np.random.default_rng(seed).normal(0.0, noise_m, C.shape)


def test_icp_recovers_a_known_motion_from_the_on_board_guess():
    P = _terrain()
    T = _T([8, 2, -1], [0.4, -0.2, 0.05])
    C = _seen_from(T, P, noise_m=0.005)
    guess = _T([5, 0, 0], [0.3, -0.1, 0.0])  # the odometry's, 0.14 m and 3 deg off
    a = align(P, C, init_T=guess)
    dt, dr = correction(T, a.T_prev_curr)
    assert dt < 0.005 and dr < 0.05, (dt, dr)
    assert not a.rejected and a.fitness > 0.9 and a.inlier_rmse_m < 0.02
    assert math.isfinite(a.condition) and a.condition < 1e4


def test_a_flat_plane_is_rejected_as_degenerate():
    g = np.random.default_rng(2)
    F = np.column_stack([g.uniform(-4, 4, 20000), g.uniform(-4, 4, 20000), np.zeros(20000)])
    a = align(F, F + np.array([0.3, 0.0, 0.0]))
    assert a.rejected and "degenerate" in a.reason


def test_a_wrong_basin_and_an_empty_cloud_are_rejected():
    P = _terrain()
    T = _T([0, 0, 0], [0.3, 0.0, 0.0])
    C = _seen_from(T, P)
    far = _T([40, 0, 0], [2.5, 2.0, 0.0])
    a = align(P, C, init_T=far)
    assert a.rejected, a
    b = align(P, C[:5])
    assert b.rejected and "too few points" in b.reason


def test_point_to_plane_information_sees_which_motions_the_geometry_fixes():
    """A plane fixes 3 of 6 motions (rank 3); three orthogonal planes fix all 6."""
    g = np.random.default_rng(3)
    p = np.column_stack([g.uniform(-2, 2, 500), g.uniform(-2, 2, 500), np.zeros(500)])
    n = np.tile([0.0, 0.0, 1.0], (500, 1))
    H = point_to_plane_information(p, p, n, 0.01)
    assert np.linalg.matrix_rank(H, tol=1e-8 * np.abs(H).max()) == 3
    pts, nrm = [], []
    for axis in range(3):
        q = g.uniform(0.1, 2, (500, 3))
        q[:, axis] = 0.0
        pts.append(q)
        nrm.append(np.eye(3)[np.full(500, axis)])
    P, N = np.vstack(pts), np.vstack(nrm)
    H = point_to_plane_information(P, P, N, 0.01)
    assert np.linalg.matrix_rank(H) == 6
    # Against the definition, summed here point by point.
    ref = sum(np.outer(j, j) for j in (np.r_[np.cross(a, b), b] for a, b in zip(P, N, strict=True)))
    np.testing.assert_allclose(H, ref, rtol=1e-10, atol=1e-9)


def test_vo_config_errors_name_the_field():
    with pytest.raises(OutOfRangeError, match="min_fitness"):
        align(np.zeros((20, 3)), np.zeros((20, 3)), config=VoConfig(min_fitness=2.0))


def test_the_conditioning_does_not_grow_with_the_range_of_the_cloud():
    """The same patch 2 m or 30 m in front of the camera: the same condition number
    (rotations are taken about the matched points' centroid, in units of their spread)."""
    P = _terrain(seed=4)
    T = _T([3, 0, 0], [0.2, 0.0, 0.0])
    C = _seen_from(T, P)
    conds = []
    for far in (2.0, 30.0):
        shift = np.array([0.0, 0.0, far])
        a = align(P + shift, C + shift, init_T=np.linalg.inv(_T([0, 0, 0], -shift)) @ T
                  @ _T([0, 0, 0], -shift))  # fmt: skip
        assert not a.rejected, a.reason
        conds.append(a.condition)
    assert conds[1] == pytest.approx(conds[0], rel=0.05)
