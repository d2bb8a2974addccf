"""The ground's perception step (perception/ground_pipeline.py) on stereo pairs rendered
here in closed form (a plane and a hemispherical boulder, a world-anchored seeded
texture seen by both cameras), and the operator's use of it (pose correction, replanning
around a new hazard). References: scipy's rotations, hand-made transforms, the scene's
own geometry."""

import dataclasses as dc
import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lunar_drake.autonomy.costmap import HazardConfig, RoverEnvelope, build_costmap
from lunar_drake.autonomy.operations import corrected_pose
from lunar_drake.autonomy.planner import path_blocked
from lunar_drake.comms.images import ImageDownlinkConfig, StereoFrame, decode_frame, encode_frame
from lunar_drake.errors import OutOfRangeError
from lunar_drake.models.rover_description import krex2_rp
from lunar_drake.perception.calibration import StereoCalibration
from lunar_drake.perception.elevation_map import ElevationMap, PriorDem
from lunar_drake.perception.ground_pipeline import (
    PerceptionConfig,
    PerceptionState,
    _recentred,
    fuse_translation,
    innovation,
    perception_step,
    planar_correction,
    pose_matrix,
    voxel_downsample,
)
from lunar_drake.render.camera import CameraConfig

W, H = 480, 360
BOULDER = (6.0, 0.0, 0.35)  # centre x, y and radius of a hemisphere on z = 0 (m)
ROVER = RoverEnvelope.of(krex2_rp())
HAZ = HazardConfig(resolution_m=0.25)


def _X_BC() -> np.ndarray:
    """Left camera in the chassis: 1.3 m up, 0.4 m forward, looking +x pitched 20 deg
    down (OpenCV axes: x right, y down, z forward)."""
    p = math.radians(20.0)
    z = np.array([math.cos(p), 0.0, -math.sin(p)])
    x = np.array([0.0, -1.0, 0.0])
    X = np.eye(4)
    X[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    X[:3, 3] = (0.4, 0.15, 1.3)
    return X


def _texture():
    g = np.random.default_rng(11)
    grid = g.uniform(0.0, 1.0, (400, 400))  # 2.5 cm cells over 10 m, tiled

    def tex(x, y):
        u, v = (x / 0.025) % 400, (y / 0.025) % 400
        i, j = np.floor(u).astype(int), np.floor(v).astype(int)
        fu, fv = u - i, v - j
        i1, j1 = (i + 1) % 400, (j + 1) % 400
        return (grid[i, j] * (1 - fu) * (1 - fv) + grid[i1, j] * fu * (1 - fv)
                + grid[i, j1] * (1 - fu) * fv + grid[i1, j1] * fu * fv)  # fmt: skip

    return tex


TEX = _texture()


def _render(X_WC, calib) -> np.ndarray:
    """12-bit frame of the scene from camera pose X_WC: the texture at each ray's first
    hit (plane z = 0 or the boulder), sky 0."""
    K = calib.K_left
    v, u = np.mgrid[0:H, 0:W].astype(float)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    d = d.reshape(-1, 3) @ X_WC[:3, :3].T
    o = X_WC[:3, 3]
    c = np.array((*BOULDER[:2], 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
        a = np.sum(d * d, axis=1)
        b = 2.0 * d @ (o - c)
        cc = (o - c) @ (o - c) - BOULDER[2] ** 2
        disc = b * b - 4 * a * cc
        t_s = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
    t = np.minimum(t_plane, np.where(t_s > 0, t_s, np.inf))
    hit = np.isfinite(t)
    p = o + np.where(hit, t, 0.0)[:, None] * d
    img = np.where(hit, 400.0 + 3000.0 * TEX(p[:, 0], p[:, 1]), 0.0)
    return np.clip(img, 0, 4095).reshape(H, W).astype(np.uint16)


@pytest.fixture(scope="module")
def scene():
    calib = StereoCalibration.from_camera(
        camera=CameraConfig(width=W, height=H, fov_y_deg=45.0), description=krex2_rp()
    )
    X_BC = _X_BC()
    cfg = ImageDownlinkConfig(codec="png")
    X_CR = np.eye(4)
    X_CR[0, 3] = calib.baseline_m  # the right camera, +x of the left one

    def frame(k, X_WB_true, pose_est, steady=10.0):
        X_WC = X_WB_true @ X_BC
        return StereoFrame(
            frame_index=k, t_capture_s=float(k), codec="png",
            left=encode_frame(_render(X_WC, calib), config=cfg),
            right=encode_frame(_render(X_WC @ X_CR, calib), config=cfg),
            pose_estimate=tuple(pose_est), pan_tilt_rad=(0.0, 0.0), gimbal_steady_s=steady,
        )  # fmt: skip

    z0 = np.zeros((160, 160))  # a flat 40 m prior at 0.25 m: the boulder is not on it
    prior = build_costmap(z0, resolution_m=0.25, x0_m=-20.0, y1_m=20.0, rover=ROVER, config=HAZ)
    return {
        "calib": calib,
        "frame": frame,
        "prior": prior,
        "dem": PriorDem(z=z0, resolution_m=0.25, x0_m=-20.0, y1_m=20.0),
        "kw": dict(
            calib=calib,
            camera_in_chassis=lambda pan, tilt: X_BC,
            decode=lambda buf: decode_frame(buf, codec="png"),
            rover=ROVER,
            hazards=HAZ,
        ),
    }


def _pose6(x, y, yaw, z=0.3):
    return (x, y, z, 0.0, 0.0, yaw)


def test_pose_matrix_matches_scipy_zyx_euler():
    pose = (1.0, -2.0, 0.5, 0.1, -0.2, 2.5)
    X = pose_matrix(pose)
    R = Rotation.from_euler("ZYX", [pose[5], pose[4], pose[3]]).as_matrix()
    np.testing.assert_allclose(X[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(X[:3, 3], pose[:3])


def test_planar_correction_applied_to_a_pose_equals_the_matrix_product():
    C = pose_matrix((0.7, -0.3, 0.0, 0.0, 0.0, 0.2))
    pose = (3.0, 4.0, 0.1, 0.0, 0.0, 1.0)
    out = corrected_pose(pose, planar_correction(C))
    X = C @ pose_matrix(pose)
    np.testing.assert_allclose(out[:2], X[:2, 3], atol=1e-12)
    assert math.isclose(out[5], 1.2, abs_tol=1e-12)
    assert tuple(corrected_pose(pose, (0.0, 0.0, 0.0))) == pose


def test_the_innovation_lets_slip_through_and_nothing_else():
    """VO shorter than the wheels along their direction, down to standing still, is slip
    (no innovation); longer, backwards past standing still, or sideways is innovation."""
    odom = np.array([0.6, 0.8, 0.0])  # 1 m along (0.6, 0.8)
    u, v = odom, np.array([-0.8, 0.6, 0.0])  # along, across
    for vo, excess, slip in [
        (0.7 * u, 0.0, 0.3),  # 30 % slip
        (1.2 * u, 0.2, 0.0),  # 0.2 m further than the wheels
        (u + 0.1 * v, 0.1, 0.0),  # sideways
        (0.7 * u + 0.1 * v, 0.1, 0.3),
        (-0.2 * u, 0.2, 1.0),  # stuck, and 0.2 m backwards on top
    ]:
        e, sl = innovation(odom, vo)
        assert e == pytest.approx(excess, abs=1e-12) and sl == pytest.approx(slip, abs=1e-12)
    assert innovation(np.zeros(3), np.array([0.0, 0.3, 0.4])) == pytest.approx((0.5, 0.0))


def test_fuse_translation_is_the_inverse_variance_mean():
    t = fuse_translation([1.0, 0.0, 0.0], [1.3, 0.3, 0.0], sigma_odom_m=0.2, sigma_vo_m=0.1)
    # weights 25 and 100: (25 * 1 + 100 * 1.3) / 125 = 1.24; (100 * 0.3) / 125 = 0.24
    np.testing.assert_allclose(t, [1.24, 0.24, 0.0])


def test_recentring_keeps_the_cells_of_the_overlap_in_place():
    em = ElevationMap.empty(x0_m=0.0, y1_m=10.0, cell_m=0.1, shape=(100, 100))
    r, c = em.cell_of(6.05, 4.05)
    count = em.count.copy()
    count[r, c] = 7
    em = dc.replace(em, count=count)
    assert _recentred(em, (5.0, 5.0), window_m=10.0, cell_m=0.1) is em
    moved = _recentred(em, (8.0, 5.0), window_m=10.0, cell_m=0.1)
    assert moved.x0_m == pytest.approx(3.0)
    assert moved.count[moved.cell_of(6.05, 4.05)] == 7 and moved.count.sum() == 7


def test_voxel_downsample_keeps_one_centroid_per_voxel_in_voxel_order():
    pts = np.array([[0.01, 0.02, 0.03], [0.25, 0.05, 0.05], [0.09, 0.08, 0.07],
                    [0.15, 0.0, 0.0], [math.nan, 0.0, 0.0], [-0.05, 0.0, 0.0]])  # fmt: skip
    out = voxel_downsample(pts, voxel_m=0.1)
    expected = np.array([[-0.05, 0.0, 0.0], [0.05, 0.05, 0.05], [0.15, 0.0, 0.0],
                         [0.25, 0.05, 0.05]], np.float32)  # fmt: skip
    assert out.dtype == np.float32 and out.shape == (4, 3)
    np.testing.assert_allclose(out, expected, atol=1e-7)
    # the same bytes again, and from the points in another order (sorted by voxel)
    assert voxel_downsample(pts, voxel_m=0.1).tobytes() == out.tobytes()
    assert voxel_downsample(pts[::-1], voxel_m=0.1).tobytes() == out.tobytes()
    assert voxel_downsample(pts, voxel_m=0.0).shape == (0, 3)
    assert voxel_downsample(np.empty((0, 3)), voxel_m=0.1).shape == (0, 3)
    # many points: as many as the occupied voxels, each one inside its voxel's cube
    g = np.random.default_rng(3).uniform(-1.0, 1.0, (5000, 3))
    keys = np.unique(np.floor(g / 0.25), axis=0)
    out = voxel_downsample(g, voxel_m=0.25)
    assert len(out) == len(keys)
    np.testing.assert_array_equal(np.floor(out / 0.25), keys)


def test_the_ground_keeps_the_points_it_mapped_per_keyframe_and_decides_the_same(scene):
    """Each keyframe's mapped points, one per ``cloud_voxel_m`` voxel, lie on the scene
    (the plane z = 0, the boulder) within the map's range of the camera; with
    ``cloud_voxel_m`` 0 none are kept and the ground's records and costmap are the same."""
    p0 = _pose6(0.0, 0.0, 0.0)
    f0 = scene["frame"](0, pose_matrix(p0), p0)
    runs = {}
    for voxel in (0.1, 0.0):
        cfg = PerceptionConfig(cloud_voxel_m=voxel)
        runs[voxel] = perception_step(PerceptionState(costmap=scene["prior"]), [(0, f0)],
                                      prior=scene["dem"], config=cfg, **scene["kw"])  # fmt: skip
    st = runs[0.1]
    (cloud,) = st.clouds.items()
    assert cloud.frame_index == 0 and cloud.t_capture_s == f0.t_capture_s
    p = cloud.points_W
    assert p.dtype == np.float32 and 500 < len(p) < st.records.items()[0].points
    assert not p.flags.writeable and np.isfinite(p).all()
    # one per voxel, on the ground or the boulder (0.35 m), ahead of the camera
    assert len(np.unique(np.floor(p / 0.1), axis=0)) == len(p)
    assert np.abs(p[:, 2]).min() < 0.02 and -0.1 < np.median(p[:, 2]) < 0.1
    assert (p[:, 2] < BOULDER[2] + 0.1).all()
    r = np.linalg.norm(p - (_X_BC()[:3, 3] + (0.0, 0.0, 0.3)), axis=1)
    cfg = PerceptionConfig().map
    assert r.min() >= cfg.min_range_m - 0.1 and r.max() <= cfg.max_range_m + 0.1
    assert not runs[0.0].clouds.items()
    assert [repr(r) for r in runs[0.0].records.items()] == [repr(r) for r in st.records.items()]
    assert np.array_equal(runs[0.0].costmap.lethal_raw, st.costmap.lethal_raw)


def test_a_boulder_seen_in_stereo_becomes_lethal_and_blocks_the_path(scene):
    st = PerceptionState(costmap=scene["prior"])
    path = [(0.0, 0.0), (12.0, 0.0)]
    assert not path_blocked(costmap=st.costmap, path_xy=path, from_xy=(0.0, 0.0))
    p0, p1 = _pose6(0.0, 0.0, 0.0), _pose6(1.2, 0.0, 0.0)
    f0 = scene["frame"](0, pose_matrix(p0), p0)
    st = perception_step(st, [(0, f0)], prior=scene["dem"], config=PerceptionConfig(),
                         **scene["kw"])  # fmt: skip
    (rec,) = st.records.items()
    assert rec.vo == "none" and rec.points > 10000
    assert rec.new_lethal == 0 and st.version == 0  # seen once: not trusted yet (min_views)
    f1 = scene["frame"](1, pose_matrix(p1), p1)
    st = perception_step(st, [(1, f1)], prior=scene["dem"], config=PerceptionConfig(),
                         **scene["kw"])  # fmt: skip
    assert st.version == 0  # twice: still not (min_views = 3)
    p2 = _pose6(2.4, 0.0, 0.0)
    f2 = scene["frame"](2, pose_matrix(p2), p2)
    st = perception_step(st, [(2, f2)], prior=scene["dem"], config=PerceptionConfig(),
                         **scene["kw"])  # fmt: skip
    rec = st.records.items()[-1]
    assert rec.vo == "accepted", rec.reason
    assert rec.new_lethal > 0 and st.version == 1
    # when each cell first became lethal: this keyframe's capture time, nowhere else
    seen = np.isfinite(st.first_lethal_s)
    assert seen.sum() == rec.new_lethal and (st.first_lethal_s[seen] == f2.t_capture_s).all()
    assert 0.0 < rec.valid_fraction <= 1.0 and np.isfinite(rec.vo_tx_m)
    lethal = np.argwhere(st.costmap.lethal_raw)
    x, y = st.costmap.centre_of(lethal[:, 0], lethal[:, 1])
    d = np.hypot(x - BOULDER[0], y - BOULDER[1])
    assert d.min() < BOULDER[2] and d.max() < BOULDER[2] + 0.5  # on the rock, not beside
    assert path_blocked(costmap=st.costmap, path_xy=path, from_xy=(0.0, 0.0))
    # the same path, seen from beyond the rock, is clear ahead
    assert not path_blocked(costmap=st.costmap, path_xy=path, from_xy=(7.5, 0.0))


def test_vo_pulls_the_ground_pose_toward_the_truth_when_the_onboard_estimate_slips(scene):
    """The rover really moved 0.8 m and turned 3 deg; the on-board estimate says 1.0 m
    (slip it did not see). Fused with VO, the ground's pose lies much nearer the truth."""
    true0, true1 = _pose6(0.0, 0.0, 0.0), _pose6(0.8, 0.0, math.radians(3.0))
    est1 = _pose6(1.0, 0.0, math.radians(3.0))
    frames = [
        (0, scene["frame"](0, pose_matrix(true0), true0)),
        (1, scene["frame"](1, pose_matrix(true1), est1)),
    ]
    cfg = PerceptionConfig(odom_sigma_fraction=0.1, vo_sigma_m=0.01, keyframe_m=0.5,
                           vo_scale_sigma=0.0, odom_sigma_per_rad_m=0.0)  # fmt: skip
    st = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                         config=cfg, **scene["kw"])  # fmt: skip
    first, rec = st.records.items()
    assert rec.vo == "accepted", rec.reason
    # the ground's position sigma: 0 at the first keyframe, then the fused link's
    # (independent estimates: information adds), the odometry's sigma grown by the
    # ~0.2 m of slip VO saw
    sig_o = 0.1 * rec.odom_step_m + cfg.odom_sigma_min_m
    assert first.sigma_m == 0.0
    lo, hi = ((math.hypot(sig_o, slip) ** -2 + 0.01**-2) ** -0.5 for slip in (0.15, 0.25))
    assert lo < rec.sigma_m < hi
    # VO's scale error adds linearly: vo_scale_sigma of the fused step
    st_s = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                           config=dc.replace(cfg, vo_scale_sigma=0.05), **scene["kw"])  # fmt: skip
    step = math.hypot(rec.x_m - first.x_m, rec.y_m - first.y_m)
    assert st_s.records.items()[-1].sigma_m == pytest.approx(
        math.hypot(rec.sigma_m, 0.05 * step), rel=0.02)
    assert st_s.sigma_m == st_s.records.items()[-1].sigma_m
    ground = corrected_pose(est1, planar_correction(st.correction))
    err_ground = math.hypot(ground[0] - 0.8, ground[1])
    assert err_ground < 0.05 < 0.2 == pytest.approx(math.hypot(est1[0] - 0.8, est1[1]))
    # Each record carries the correction from then on; the ground pose it lists is the
    # on-board one moved by it.
    assert (first.correction_x_m, first.correction_y_m, first.correction_yaw_rad) == (0, 0, 0)
    corr = (rec.correction_x_m, rec.correction_y_m, rec.correction_yaw_rad)
    assert corr == planar_correction(st.correction)
    moved = corrected_pose(est1, corr)
    assert moved[[0, 1, 5]] == pytest.approx([rec.x_m, rec.y_m, rec.yaw_rad], abs=1e-9)
    # with a tight on-board sigma the 0.2 m shortfall is still fused (slip: wheels
    # over-read), but 0.2 m sideways, which slip cannot explain, is beyond the gate
    tight = dc.replace(cfg, odom_sigma_fraction=0.02)
    st_t = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                           config=tight, **scene["kw"])  # fmt: skip
    assert st_t.records.items()[-1].vo == "accepted"
    side = _pose6(0.8, 0.2, math.radians(3.0))
    frames_side = [frames[0], (1, scene["frame"](1, pose_matrix(true1), side))]
    st_s = perception_step(PerceptionState(costmap=scene["prior"]), frames_side,
                           prior=scene["dem"], config=tight, **scene["kw"])  # fmt: skip
    assert st_s.records.items()[-1].vo == "gated"
    np.testing.assert_allclose(planar_correction(st_s.correction), 0.0, atol=1e-9)
    # without VO the ground keeps the on-board estimate
    st2 = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                          config=dc.replace(cfg, use_vo=False), **scene["kw"])  # fmt: skip
    assert st2.records.items()[-1].vo == "off"
    np.testing.assert_allclose(planar_correction(st2.correction), 0.0, atol=1e-9)
    assert st2.records.items()[-1].sigma_m == pytest.approx(sig_o, rel=1e-12)  # odometry's
    # the odometry's sigma grows with the turn (3 deg here) by odom_sigma_per_rad_m
    st3 = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                          config=dc.replace(cfg, use_vo=False, odom_sigma_per_rad_m=0.5),
                          **scene["kw"])  # fmt: skip
    assert st3.records.items()[-1].sigma_m == pytest.approx(sig_o + 0.5 * math.radians(3.0),
                                                            rel=1e-9)  # fmt: skip


def test_frames_taken_while_the_gimbal_moved_or_without_a_header_are_skipped(scene):
    pose = _pose6(0.0, 0.0, 0.0)
    moving = scene["frame"](0, pose_matrix(pose), pose, steady=0.5)
    blind = dc.replace(moving, gimbal_steady_s=10.0, pose_estimate=(math.nan,) * 6)
    st = perception_step(PerceptionState(costmap=scene["prior"]), [(0, moving), (1, blind)],
                         prior=scene["dem"], config=PerceptionConfig(), **scene["kw"])  # fmt: skip
    assert st.last_seq == 1 and not st.records.items() and st.version == 0


def test_frames_between_keyframes_are_skipped(scene):
    p0, p1 = _pose6(0.0, 0.0, 0.0), _pose6(0.3, 0.0, 0.0)
    frames = [(0, scene["frame"](0, pose_matrix(p0), p0)),
              (1, scene["frame"](1, pose_matrix(p1), p1))]  # fmt: skip
    st = perception_step(PerceptionState(costmap=scene["prior"]), frames, prior=scene["dem"],
                         config=PerceptionConfig(keyframe_m=1.0), **scene["kw"])  # fmt: skip
    assert [r.frame_index for r in st.records.items()] == [0]


@pytest.mark.parametrize(
    "field, value",
    [("keyframe_m", -1.0), ("window_m", 5.0), ("vo_sigma_m", 0.0), ("gimbal_settle_s", -1.0),
     ("cloud_voxel_m", -0.1), ("processing_s", -1.0), ("processing_s", float("nan"))],
)
def test_perception_config_errors_name_the_field(field, value):
    with pytest.raises(OutOfRangeError, match=field):
        dc.replace(PerceptionConfig(), **{field: value}).validate()


def test_a_mission_with_ground_perception_writes_its_keyframes_and_map(cache, tmp_path):
    """The `goto` mission with the mast cameras on (320 x 240, 1 Hz), every frame sent
    down and the ground's perception running: keyframes are processed from the
    downlinked frames with VO fused, and the run directory holds keyframes.csv (with the
    ground's position sigma growing from 0) and ground_map.png; the rover still reaches
    its goal."""
    import csv

    from lunar_drake import metrics, outputs
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name="goto", scenario_text=(
        "{sensors: {camera: {enabled: true, width: 320, height: 240, rate_hz: 1.0}},"
        " flight: {images: {enabled: true}}, ground: {perception: {enabled: true}}}"))  # fmt: skip
    site = load_site(scenario, progress=False)
    logs = simulate(scenario=scenario, site=site, progress=False, stop_after_goals_s=2.0)
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    assert summary["goals"][0]["reached"], summary["goals"]
    gp = summary["perception"]
    assert gp["keyframes"] >= 5 and gp["vo"].get("accepted", 0) >= 3, gp
    # scored on truth: VO's steps within a few percent of the true camera motion
    assert 0.0 < gp["vo_error_per_m"] < 0.05 and 0.0 < gp["vo_acceptance"] <= 1.0, gp
    assert 0.1 < gp["stereo_valid_fraction"] < 1.0, gp
    assert gp["hazards_detected"] + gp["hazards_missed"] == gp["hazards_near_path"], gp
    outputs.write_run(tmp_path, scenario=scenario, logs=logs, summary=summary,
                      timing=logs.wall)  # fmt: skip
    rows = list(csv.DictReader(open(tmp_path / "keyframes.csv")))
    sig = [float(r["sigma_m"]) for r in rows]
    assert sig[0] == 0.0 and all(b >= a for a, b in itertools.pairwise(sig)) and sig[-1] > 0
    assert gp["final_sigma_m"] == pytest.approx(sig[-1], rel=1e-5)
    # the points it mapped: keyframe after keyframe, as many as it kept
    pts = np.load(tmp_path / "keyframe_points.npy", allow_pickle=False)
    order = list(dict.fromkeys(pts["frame_index"].tolist()))
    assert order == [int(r["frame_index"]) for r in rows if int(float(r["points"])) > 0]
    assert len(pts) == sum(len(c.points_W) for c in logs.keyframe_clouds) > 100 * len(order)
    png = (tmp_path / "ground_map.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_a_processing_time_delays_the_result_on_the_worker_thread_not_changes_it(scene):
    """GroundPerception with ``processing_s``: a tick's frames are processed on the
    worker thread and take effect at the first tick at or after ``t + processing_s``,
    batches chained in order; the state is the one processing in the tick gives."""
    import threading

    from pydrake.systems.analysis import Simulator

    from lunar_drake.comms.messages import Delivery, Message
    from lunar_drake.systems import ground_perception as gp_mod
    from lunar_drake.systems.ground_perception import GroundPerception

    poses = [_pose6(0.0, 0.0, 0.0), _pose6(1.2, 0.0, 0.0), _pose6(2.4, 0.1, 0.05)]
    frames = [scene["frame"](k, pose_matrix(p), p) for k, p in enumerate(poses)]
    inbox = [
        Delivery(message=Message(topic="images", seq=k, t_sent_s=float(k), payload=f,
                                 size_bytes=f.size_bytes()), t_received_s=float(k))
        for k, f in enumerate(frames)
    ]  # fmt: skip
    threads = set()
    step = gp_mod.perception_step

    def recording_step(*a, **kw):
        threads.add(threading.current_thread().name)
        return step(*a, **kw)

    def run(processing_s):
        system = GroundPerception(
            config=PerceptionConfig(processing_s=processing_s), rate_hz=1.0,
            calib=scene["calib"], description=krex2_rp(), prior_costmap=scene["prior"],
            prior_dem=scene["dem"], rover=ROVER, hazards=HAZ,
        )  # fmt: skip
        sim = Simulator(system)
        ctx = sim.get_mutable_context()
        seen = []
        # frames 0 and 1 arrive by t = 0, frame 2 by t = 1
        for t_end, upto in ((0.5, 2), (1.5, 3), (2.5, 3), (3.5, 3)):
            system.images_input.FixValue(ctx, tuple(inbox[:upto]))
            sim.AdvanceTo(t_end)
            seen.append(len(system.perception_state(ctx).records))
        return system.perception_state(ctx), seen

    gp_mod.perception_step = recording_step
    try:
        now, seen_now = run(0.0)
        assert threads == {threading.current_thread().name}
        threads.clear()
        later, seen_later = run(1.5)
        assert threads and all(t.startswith("lunar_drake.ground") for t in threads), threads
    finally:
        gp_mod.perception_step = step
    # in the tick: 2 keyframe records at t = 0, 3 at t = 1; 1.5 s later: at t = 2 and 3
    assert seen_now == [2, 3, 3, 3] and seen_later == [0, 0, 2, 3], (seen_now, seen_later)
    assert [repr(r) for r in later.records.items()] == [repr(r) for r in now.records.items()]
    assert np.array_equal(later.correction, now.correction) and later.last_seq == 2
    assert np.array_equal(later.costmap.lethal_raw, now.costmap.lethal_raw)
    assert later.version == now.version
