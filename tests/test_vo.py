"""ICP visual odometry (perception/vo.py) on synthetic terrain clouds with a known
motion: recovery, rejection of degenerate, wrong-basin and empty alignments, cropping to
the overlap of two views, the rotation kept from an attitude prior."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lunar_drake.errors import OutOfRangeError
from lunar_drake.perception.vo import (
    ViewFrustum,
    VoConfig,
    align,
    correction,
    overlap_masks,
    point_to_plane_information,
    translation_icp,
)


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
    """6-DoF ICP (``rotation: icp``, no attitude sensor) from a guess 0.14 m, 3 deg off."""
    P = _terrain()
    T = _T([8, 2, -1], [0.4, -0.2, 0.05])
    C = _seen_from(T, P, noise_m=0.005)
    guess = _T([5, 0, 0], [0.3, -0.1, 0.0])  # the odometry's, 0.14 m and 3 deg off
    a = align(P, C, init_T=guess, config=VoConfig(rotation="icp"))
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


# ---------------------------------------------------------------------------------------
# the overlap of two views and the attitude prior, in camera frames (x right, y down,
# z forward): a bumpy ground 1.5 m below a camera, seen 2-8 m ahead
# ---------------------------------------------------------------------------------------
def _ground_view(seed=5, n=60000):
    g = np.random.default_rng(seed)
    z = g.uniform(1.0, 9.0, n)
    x = g.uniform(-9.0, 9.0, n)
    bumps = 0.12 * np.sin(1.7 * x) * np.cos(1.1 * z) + 0.05 * np.sin(4.3 * x + 2.0 * z)
    for cx, cz, r in g.uniform([-8, 2, 0.2], [8, 8, 0.45], (40, 3)):
        d = np.hypot(x - cx, z - cz)
        bumps -= np.where(d < r, 0.7 * np.sqrt(np.maximum(r * r - d * d, 0.0)), 0.0)
    return np.column_stack([x, 1.5 + bumps, z])  # y down: rocks have smaller y


def _turned(deg, xyz=(0.0, 0.0, 0.0)):
    """T_prev_curr of a camera turned ``deg`` about its own y axis (a yaw to the right
    for positive deg) and moved by ``xyz`` (previous frame)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", deg, degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T


def _view(world, X_prev_cam, frustum, *, depth_noise=0.0, seed=0):
    """What a camera at ``X_prev_cam`` (4 x 4, in the first camera's frame) sees of
    ``world``: the points in its frustum, with range noise along the ray growing as
    Z^2 (stereo)."""
    Xi = np.linalg.inv(X_prev_cam)
    c = world @ Xi[:3, :3].T + Xi[:3, 3]
    c = c[frustum.contains(c)]
    if depth_noise:
        g = np.random.default_rng(seed)
        c = c * (1.0 + depth_noise * c[:, 2:3] * g.standard_normal((len(c), 1)))
    return c


def test_the_view_frustum_of_a_calibration_is_the_camera_field_of_view():
    from lunar_drake.models.rover_description import krex2_rp
    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.render.camera import CameraConfig

    cam = CameraConfig(width=640, height=480, fov_y_deg=45.0)
    f = ViewFrustum.from_calibration(StereoCalibration.from_camera(
        camera=cam, description=krex2_rp()), max_range_m=7.0)  # fmt: skip
    assert f.tan_half_y == pytest.approx(math.tan(math.radians(22.5)), rel=1e-9)
    assert f.tan_half_x == pytest.approx(4 / 3 * math.tan(math.radians(22.5)), rel=1e-9)
    # a point 1 deg inside the edge is in, 1 deg outside is out; 2 deg margin drops both
    edge = math.atan(f.tan_half_x)
    pts = np.array([[math.tan(edge + s * math.radians(1)) * 5, 0, 5] for s in (-1, 1)])
    assert list(f.contains(pts)) == [True, False]
    assert not f.contains(pts, margin_deg=2.0).any()
    assert not f.contains(np.array([[0, 0, 7.5], [0, 0, -3]])).any()


def test_overlap_masks_keep_what_the_other_camera_saw():
    """After a 40 deg turn, each cloud keeps exactly the points whose bearing, from the
    other camera, lies inside its field of view (checked by angles computed here)."""
    fr = ViewFrustum(tan_half_x=math.tan(math.radians(29)), tan_half_y=math.tan(
        math.radians(22.5)), max_range_m=8.0)  # fmt: skip
    world = _ground_view()
    T = _turned(40.0, (0.1, 0.0, 0.05))
    prev, curr = _view(world, np.eye(4), fr), _view(world, T, fr)
    m_prev, m_curr = overlap_masks(prev, curr, init_T=T, frustum=fr, margin_deg=0.0)
    q = curr @ T[:3, :3].T + T[:3, 3]  # current points in the previous camera
    az = np.degrees(np.arctan2(q[:, 0], q[:, 2]))
    el = np.degrees(np.arctan2(q[:, 1], q[:, 2]))
    ref = (np.abs(az) <= 29) & (np.abs(el) <= 22.5) & (q[:, 2] <= 8.0) & (q[:, 2] >= 0.1)
    assert (m_curr == ref).mean() > 0.999 and 0.05 < m_curr.mean() < 0.6
    assert 0.05 < m_prev.mean() < 0.6


def test_a_large_turn_aligns_on_its_overlap():
    """A 40 deg turn (18 deg of 58 deg overlap): cropped to the overlap, the fitness
    measures the overlap and the motion is recovered; uncropped, the fitness drops to the
    overlap's share."""
    fr = ViewFrustum(tan_half_x=math.tan(math.radians(29)), tan_half_y=math.tan(
        math.radians(22.5)), max_range_m=8.0)  # fmt: skip
    world = _ground_view()
    T = _turned(40.0, (0.15, 0.0, 0.1))
    prev, curr = _view(world, np.eye(4), fr), _view(world, T, fr)
    guess = T.copy()
    guess[:3, 3] += (0.04, 0.0, -0.03)
    cfg = VoConfig(min_fitness=0.5)
    a = align(prev, curr, init_T=guess, frustum=fr, config=cfg)
    b = align(prev, curr, init_T=guess, config=cfg)
    assert not a.rejected, a.reason
    assert a.fitness > 0.8 and b.fitness < 0.5 and b.rejected
    dt, dr = correction(T, a.T_prev_curr)
    assert dt < 0.01 and dr < 1e-9  # the prior's rotation kept


def test_the_attitude_prior_removes_the_rotation_error_of_noisy_far_points():
    """Stereo-like range noise (0.1 % of depth per metre: 0.25 px of disparity at f B =
    230 px m): with the guess's exact rotation (a star tracker) kept and ICP's translation
    re-anchored at its correspondences, the camera's position is better than 6-DoF
    ICP's, whose rotation error swings it about the terrain metres away."""
    fr = ViewFrustum(tan_half_x=math.tan(math.radians(29)), tan_half_y=math.tan(
        math.radians(22.5)), max_range_m=8.0)  # fmt: skip
    world = _ground_view(seed=6)
    T = _turned(35.0, (0.2, 0.0, 0.1))
    prev = _view(world, np.eye(4), fr, depth_noise=0.001, seed=1)
    curr = _view(world, T, fr, depth_noise=0.001, seed=2)
    guess = T.copy()
    guess[:3, 3] += (0.05, 0.0, 0.05)
    errs = {}
    for rot in ("prior", "icp"):
        a = align(prev, curr, init_T=guess, frustum=fr,
                  config=VoConfig(rotation=rot, max_rmse_m=0.2))  # fmt: skip
        errs[rot] = correction(T, a.T_prev_curr)
    assert errs["prior"][1] < 1e-9
    assert errs["prior"][0] < errs["icp"][0] and errs["prior"][0] < 0.02, errs


def test_translation_icp_moves_only_what_the_geometry_fixes():
    """On a plane the translation-only ICP corrects the normal offset and leaves the
    slide along the plane at the guess (no drift into unconstrained directions); on
    bumpy terrain it recovers the full offset. A coloured ICP needs all six degrees of
    freedom: asking for it with the attitude prior is a configuration error."""
    g = np.random.default_rng(8)
    plane = np.column_stack([g.uniform(-3, 3, 5000), g.uniform(-3, 3, 5000), np.zeros(5000)])
    normals = np.tile([0.0, 0.0, 1.0], (5000, 1))
    guess = _T([0, 0, 0], [0.02, -0.03, 0.04])
    T = translation_icp(plane, plane, normals, init_T=guess, max_dist_m=0.2, huber_m=0.05,
                        iterations=30)  # fmt: skip
    np.testing.assert_allclose(T[:3, 3], [0.02, -0.03, 0.0], atol=1e-9)
    P = _terrain()
    true = _T([4, 1, 0], [0.3, -0.1, 0.02])
    C = _seen_from(true, P)
    a = align(P, C, init_T=_T([4, 1, 0], [0.25, -0.06, 0.0]))
    assert not a.rejected, a.reason
    dt, dr = correction(true, a.T_prev_curr)
    assert dt < 0.003 and dr < 1e-9
    with pytest.raises(Exception, match="rotation: icp"):
        VoConfig(method="colored").validate()
    with pytest.raises(Exception, match="rotation"):
        VoConfig(rotation="gyro").validate()
