"""Stereo elevation map and hazards (perception/elevation_map.py) on synthetic clouds:
planes and a boulder sampled by rays cast here (a pinhole on a mast, hits solved in
closed form, depth noise of a stereo rig), references computed by hand."""

import dataclasses as dc
import math

import numpy as np
import pytest

from lunar_drake.autonomy.costmap import (
    HazardConfig,
    RoverEnvelope,
    build_costmap,
    orbital_dem,
)
from lunar_drake.autonomy.planner import PlanningError, plan_path
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.perception.elevation_map import (
    ElevationMap,
    ElevationMapConfig,
    PriorDem,
    fuse,
    merge_into_costmap,
    points_to_world,
    stereo_hazards,
)

ROVER = RoverEnvelope.of(rover_preset("krex2_rp"))
RES = 0.1
N = 400  # the site DEM: 40 m x 40 m at 0.1 m, origin at the centre
HALF = N / 2 * RES
BOULDER_R = 0.3  # a hemisphere 0.3 m tall (0.6 m across) at the origin


def _dem_grid():
    x = (np.arange(N) + 0.5 - N / 2) * RES
    y = (N / 2 - np.arange(N) - 0.5) * RES  # row 0 north
    return np.meshgrid(x, y)


def _boulder_dem():
    X, Y = _dem_grid()
    return np.sqrt(np.maximum(BOULDER_R**2 - X**2 - Y**2, 0.0))


def _camera(pitch_deg=24.0, origin=(-3.0, 0.0, 1.5), width=640, height=480, fov_y_deg=45.0):
    """(R_WC, p_WC, focal px, ray directions in C (H*W, 3)) of a camera looking +x,
    pitched down (OpenCV axes: x right, y down, z forward)."""
    p = math.radians(pitch_deg)
    z = np.array([math.cos(p), 0.0, -math.sin(p)])
    x = np.array([0.0, -1.0, 0.0])
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    f = 0.5 * height / math.tan(math.radians(fov_y_deg / 2))
    v, u = np.mgrid[0:height, 0:width].astype(float)
    d_C = np.stack([(u - (width - 1) / 2) / f, (v - (height - 1) / 2) / f, np.ones_like(u)], -1)
    return R, np.array(origin), f, d_C.reshape(-1, 3)


def _cast(R, o, d_C):
    """Depth along the optical axis (d_C has z = 1) of each ray's first hit with the
    plane z = 0 and the hemisphere of radius BOULDER_R at the origin (inf: no hit)."""
    d = d_C @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
        a = np.sum(d * d, axis=1)
        b = 2.0 * d @ o
        c = o @ o - BOULDER_R**2
        disc = b * b - 4 * a * c
        t_sph = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
    t_sph = np.where(t_sph > 0, t_sph, np.inf)
    return np.minimum(t_plane, t_sph)  # the sphere's lower half is below the plane


def _stereo_cloud(seed=0, **camera):
    """(points in C, X_WC, config for the rig): the rays' hits with depth noise
    sigma_d Z^2 / (f B) (sigma_d 0.25 px, B 0.3 m)."""
    R, o, f, d_C = _camera(**camera)
    t = _cast(R, o, d_C)
    ok = np.isfinite(t)
    t, d_C = t[ok], d_C[ok]
    g = np.random.default_rng(seed)
    t = t + g.normal(size=t.shape) * 0.25 * t * t / (f * 0.3)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, o
    return t[:, None] * d_C, X, ElevationMapConfig(focal_px=f, baseline_m=0.3)


def _sigma(r, *, f, B, sd, s0):
    return math.sqrt((sd * r * r / (f * B)) ** 2 + s0**2)


def test_fusing_a_plane_gives_its_heights_within_the_noise():
    a, b, c = 0.1, -0.05, 2.0
    plane = lambda x, y: a * x + b * y + c  # noqa: E731
    cfg = ElevationMapConfig(min_range_m=0.0)
    g = np.random.default_rng(1)
    xy = g.uniform(-2.0, 2.0, (40_000, 2))
    origin = np.array([-4.0, 0.0, 3.5])
    pts = np.column_stack([xy, plane(xy[:, 0], xy[:, 1])])
    r = np.linalg.norm(pts - origin, axis=1)
    sig = np.sqrt((0.25 * r * r / (cfg.focal_px * 0.3)) ** 2 + 0.01**2)
    pts[:, 2] += g.normal(size=len(r)) * sig
    em = fuse(ElevationMap.empty(x0_m=-2.0, y1_m=2.0, cell_m=0.1, shape=(40, 40)),
              points_W=pts, sensor_origin_W=origin, config=cfg, time_s=5.0)  # fmt: skip
    known = em.known(cfg)
    assert known.all()
    # The 3-sigma gate drops Gaussian tails only (0.3 %).
    assert 0.99 * len(pts) < em.count.sum() < len(pts)
    rr, cc = np.mgrid[0:40, 0:40]
    x, y = em.centre_of(rr, cc)
    err = em.height_m - plane(x, y)
    # Within 4 sigma of the fused height, plus the slope over the points' scatter about
    # the cell centre (0.11 x 0.1 m / sqrt(12 n) < 0.6 mm).
    assert np.all(np.abs(err) < 4 * np.sqrt(em.variance_m2) + 6e-4)
    assert abs(err.mean()) < 1e-3
    assert np.all(em.t_last_s == 5.0)
    assert np.all(em.z_max_m >= em.height_m)


def test_inverse_variance_weighting_matches_a_hand_computation():
    cfg = ElevationMapConfig(cell_m=0.5, min_range_m=0.0, focal_px=500.0, baseline_m=0.25,
                             disparity_sigma_px=0.5, min_sigma_m=0.01,
                             outlier_min_m=10.0)  # fmt: skip
    em = ElevationMap.empty(x0_m=0.0, y1_m=1.0, cell_m=0.5, shape=(2, 2))
    o = np.array([-3.0, 0.75, 1.0])
    # Cell (0, 0): x, y in [0, 0.5] x [0.5, 1]; cell (1, 1): [0.5, 1] x [0, 0.5].
    a = [(0.1, 0.9, 0.00), (0.4, 0.6, 0.04), (0.2, 0.7, 0.02)]
    b = [(0.6, 0.1, 0.30), (0.9, 0.4, 0.10)]
    out = fuse(em, points_W=np.array(a + b), sensor_origin_W=o, config=cfg)
    for cell, pts in (((0, 0), a), ((1, 1), b)):
        w = [1 / _sigma(math.dist(p, o), f=500.0, B=0.25, sd=0.5, s0=0.01) ** 2 for p in pts]
        W = sum(w)
        h = sum(wi * p[2] for wi, p in zip(w, pts, strict=True)) / W
        chi2 = sum(wi * (p[2] - h) ** 2 for wi, p in zip(w, pts, strict=True)) / (len(pts) - 1)
        assert out.height_m[cell] == pytest.approx(h, rel=1e-12)
        assert out.variance_m2[cell] == pytest.approx(max(1.0, chi2) / W, rel=1e-9)
        assert out.count[cell] == len(pts)
        assert out.z_max_m[cell] == max(p[2] for p in pts)
    # Cell b's two points disagree beyond their sigmas: the variance is scaled up; cell
    # a's agree within them: 1 / W.
    wb = [1 / _sigma(math.dist(p, o), f=500.0, B=0.25, sd=0.5, s0=0.01) ** 2 for p in b]
    assert out.variance_m2[1, 1] > 3 / sum(wb)
    wa = [1 / _sigma(math.dist(p, o), f=500.0, B=0.25, sd=0.5, s0=0.01) ** 2 for p in a]
    assert out.variance_m2[0, 0] == pytest.approx(1 / sum(wa), rel=1e-9)
    assert out.count[0, 1] == out.count[1, 0] == 0
    assert np.isnan(out.height_m[0, 1]) and np.isinf(out.variance_m2[0, 1])
    assert em.count.sum() == 0  # the input map is untouched


def test_points_beyond_range_off_the_grid_or_not_finite_are_ignored():
    cfg = ElevationMapConfig()
    em = ElevationMap.empty(x0_m=0.0, y1_m=20.0, cell_m=0.1, shape=(200, 200))
    o = np.array([0.05, 10.05, 1.5])
    far = [(12.0, 10.0, 0.0), (0.0, 0.0, 0.0)]  # 12.0 m and 10.2 m from the camera
    near = [(0.1, 10.1, 1.0)]  # 0.5 m: the rover itself
    off = [(-1.0, 10.0, 0.0), (5.0, 25.0, 0.0), (20.0, 5.0, 0.0)]
    bad = [(math.nan, 5.0, 0.0), (5.0, 5.0, math.inf)]
    none = fuse(em, points_W=np.array(far + near + off + bad), sensor_origin_W=o, config=cfg)
    assert none.count.sum() == 0 and np.isnan(none.t_last_s).all()
    good = [(9.0, 10.0, 0.0), (5.0, 5.0, 0.1)]
    some = fuse(em, points_W=np.array(far + near + off + bad + good), sensor_origin_W=o,
                config=cfg)  # fmt: skip
    assert some.count.sum() == 2
    for x, y, z in good:
        assert some.count[em.cell_of(x, y)] == 1
        assert some.height_m[em.cell_of(x, y)] == pytest.approx(z)
    with pytest.raises(OutOfRangeError, match="sensor_origin_W"):
        fuse(em, points_W=np.array(good), sensor_origin_W=(0.0, math.nan, 1.0), config=cfg)
    with pytest.raises(ConfigError, match="differs from the map"):
        fuse(em, points_W=np.array(good), sensor_origin_W=o,
             config=ElevationMapConfig(cell_m=0.2))  # fmt: skip


def test_an_outlier_is_gated_out_of_the_mean_and_the_max():
    cfg = ElevationMapConfig(min_range_m=0.0)
    em = ElevationMap.empty(x0_m=0.0, y1_m=1.0, cell_m=0.1, shape=(10, 10))
    g = np.random.default_rng(2)
    pts = np.column_stack([g.uniform(0.3, 0.4, 30), g.uniform(0.6, 0.7, 30),
                           g.normal(0.0, 0.005, 30)])  # fmt: skip
    spike = np.array([[0.35, 0.65, 1.0]])  # a mismatch 1 m up, in the same cell
    out = fuse(em, points_W=np.vstack([pts, spike]), sensor_origin_W=(0.0, 0.0, 2.0), config=cfg)
    cell = em.cell_of(0.35, 0.65)
    assert out.count[cell] == 30
    assert out.z_max_m[cell] == pts[:, 2].max()
    assert abs(out.height_m[cell]) < 0.005


def test_fusion_is_deterministic_order_invariant_and_incremental():
    p_C, X, cfg = _stereo_cloud(seed=3, width=320, height=240)
    p_W = points_to_world(p_C, X)
    em = ElevationMap.empty(x0_m=-HALF, y1_m=HALF, cell_m=0.1, shape=(N, N))
    kw = {"sensor_origin_W": X[:3, 3], "config": cfg}
    a = fuse(em, points_W=p_W, **kw)
    b = fuse(em, points_W=p_W.copy(), **kw)
    perm = np.random.default_rng(0).permutation(len(p_W))
    c = fuse(em, points_W=p_W[perm], **kw)
    names = ("weight", "weighted_z", "weighted_z2", "count", "z_max_m", "t_last_s")
    for name in names:
        u, v, w = getattr(a, name), getattr(b, name), getattr(c, name)
        assert u.tobytes() == v.tobytes()
        np.testing.assert_allclose(w, u, rtol=1e-12, atol=0)
    assert np.array_equal(a.count, c.count) and np.array_equal(a.z_max_m, c.z_max_m)
    assert a.count.sum() > 10_000
    # Two halves one after the other: the sums of the whole (the gate aside, which sees
    # one cloud at a time: compare the cells where it dropped nothing).
    half = len(p_W) // 2
    d = fuse(fuse(em, points_W=p_W[:half], **kw), points_W=p_W[half:], **kw)
    same = d.count == a.count
    assert same.mean() > 0.99
    np.testing.assert_allclose(d.height_m[same & (a.count > 0)],
                               a.height_m[same & (a.count > 0)], rtol=1e-9, atol=1e-12)  # fmt: skip


def test_points_to_world_against_a_drake_style_pose():
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, (1.0, 2.0, 3.0)

    class Pose:  # what a pydrake RigidTransform offers
        def GetAsMatrix4(self):
            return X

    p = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.5], [0.0, 2.0, math.nan]])
    want = np.array([[1.0, 3.0, 3.0], [-1.0, 2.0, 3.5], [math.nan] * 3])  # NaN: whole point
    np.testing.assert_allclose(points_to_world(p, X), want)
    np.testing.assert_allclose(points_to_world(p.reshape(1, 3, 3), Pose()), want[None])
    with pytest.raises(ConfigError, match="4 x 4"):
        points_to_world(p, np.eye(3))


@pytest.mark.parametrize(
    ("field", "value"),
    [("cell_m", 0.0), ("min_range_m", -1.0), ("max_range_m", 0.5), ("focal_px", 0.0),
     ("baseline_m", -0.3), ("disparity_sigma_px", 0.0), ("min_sigma_m", 0.0),
     ("outlier_sigmas", math.nan), ("outlier_min_m", -0.1), ("min_points", 0),
     ("max_sigma_m", 0.0)],
)  # fmt: skip
def test_config_errors_are_one_line_out_of_range_errors(field, value):
    with pytest.raises(OutOfRangeError) as e:
        ElevationMapConfig(**{field: value}).validate()
    msg = str(e.value)
    assert msg.startswith(f"{field} = ") and "allowed" in msg and "\n" not in msg
    ElevationMapConfig().validate()
    with pytest.raises(ConfigError, match="must be an integer"):
        ElevationMapConfig(min_points=2.5).validate()


@pytest.fixture(scope="module")
def boulder():
    """The boulder DEM's orbital costmap (1 m, seeded noise), the stereo map of the
    boulder seen from 3 m, and its hazards."""
    z = _boulder_dem()
    zo, res_o = orbital_dem(z, resolution_m=RES, orbital_resolution_m=1.0, noise_m=0.01, seed=3)
    hz = HazardConfig(resolution_m=1.0)
    prior = build_costmap(zo, resolution_m=res_o, x0_m=-HALF, y1_m=HALF, rover=ROVER, config=hz)
    p_C, X, cfg = _stereo_cloud(seed=0)
    em = fuse(ElevationMap.covering(prior, cell_m=0.1), points_W=points_to_world(p_C, X),
              sensor_origin_W=X[:3, 3], config=cfg)  # fmt: skip
    return {"z": z, "zo": zo, "prior": prior, "hazards": hz, "map": em, "config": cfg,
            "prior_dem": PriorDem(zo, res_o, -HALF, HALF)}  # fmt: skip


def _dist_to_boulder(emap_or_costmap, rows, cols):
    x, y = emap_or_costmap.centre_of(rows, cols)
    return np.hypot(x, y)


@pytest.mark.parametrize("use_prior", [False, True])
def test_a_boulder_is_lethal_in_stereo_where_the_orbital_map_lost_it(boulder, use_prior):
    prior, em, cfg = boulder["prior"], boulder["map"], boulder["config"]
    r, c = prior.cell_of(0.0, 0.0)
    assert not prior.lethal_raw.any() and np.isfinite(prior.cost[r, c])  # averaged away
    # The same DEM at full resolution would have it (the orbital map's loss, not ours).
    truth = build_costmap(boulder["z"], resolution_m=RES, x0_m=-HALF, y1_m=HALF, rover=ROVER,
                          config=boulder["hazards"])  # fmt: skip
    assert truth.lethal_raw[truth.cell_of(0.0, 0.0)]
    assert em.shape == (N, N)
    known = em.known(cfg)
    # The near side and top of the boulder and the ground around it are known.
    for x, y in ((0.0, 0.0), (-0.2, 0.0), (-1.0, 0.5), (2.0, -1.0)):
        assert known[em.cell_of(x, y)], (x, y)
    # The fused heights are the DEM's (1.5 cm: the ground, and the rock's flanks where a
    # cell spans a few cm of height).
    kr, kc = np.nonzero(known)
    x, y = em.centre_of(kr, kc)
    true = np.sqrt(np.maximum(BOULDER_R**2 - x**2 - y**2, 0.0))
    err = em.height_m[kr, kc] - true
    assert np.median(np.abs(err[np.hypot(x, y) > 0.4])) < 0.01
    assert np.abs(em.height_m[em.cell_of(0.0, 0.0)] - 0.3) < 0.03
    hz = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER, config=cfg,
                        prior=boulder["prior_dem"] if use_prior else None)  # fmt: skip
    assert np.array_equal(hz.known, known)
    lr, lc = np.nonzero(hz.lethal)
    assert len(lr) > 5
    # Lethal from the step (0.2 m for this rover), on and right around the rock only.
    d = _dist_to_boulder(em, lr, lc)
    assert d.max() < BOULDER_R + 0.5 * 2 * ROVER.wheel_radius_m + 0.15
    assert hz.step_m[em.cell_of(0.0, 0.0)] > 0.2
    assert np.all(hz.slope_deg[~known] == 0) and not hz.lethal[~known].any()
    # On each cell's highest point: the same rock, a little wider.
    top = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER, config=cfg,
                         prior=boulder["prior_dem"] if use_prior else None,
                         surface="max")  # fmt: skip
    assert top.lethal[hz.lethal].all()
    lr, lc = np.nonzero(top.lethal)
    assert len(lr) >= len(d) and _dist_to_boulder(em, lr, lc).max() < 0.8
    with pytest.raises(ConfigError, match="surface = 'top'"):
        stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER, config=cfg, surface="top")


def test_after_merging_the_plan_goes_round_the_boulder(boulder):
    prior, em, cfg, hzc = boulder["prior"], boulder["map"], boulder["config"], boulder["hazards"]
    hz = stereo_hazards(em, hazards=hzc, rover=ROVER, config=cfg)
    start, goal = (-4.0, 0.0), (4.5, 0.0)
    before = plan_path(costmap=prior, start_xy=start, goal_xy=goal)
    # The prior's plan strikes it: the rover's centre passes within its radius plus the
    # footprint radius (the boulder sits on a corner of the 1 m cells).
    gap = _dist_to_boulder(prior, before.cells[:, 0], before.cells[:, 1]).min()
    assert gap < 0.75 < BOULDER_R + ROVER.footprint_radius_m
    merged = merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc)
    assert merged.shape == prior.shape and merged.resolution_m == prior.resolution_m
    r, c = merged.cell_of(0.0, 0.0)
    assert merged.lethal_raw[r, c] and not np.isfinite(merged.cost[r, c])
    # Conservative: nothing cheaper, nothing lethal lost, the new hazards local.
    assert np.all(merged.cost >= prior.cost)
    assert np.all(merged.lethal_raw >= prior.lethal_raw)
    mr, mc = np.nonzero(merged.lethal_raw)
    assert _dist_to_boulder(merged, mr, mc).max() < 1.0
    # On a finer grid the rover's clearance is resolved: its centre stays the footprint
    # radius off the rock's edge.
    fine = merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc, upsample=2)
    assert fine.resolution_m == pytest.approx(0.5) and fine.shape == (80, 80)
    for cm in (merged, fine):
        after = plan_path(costmap=cm, start_xy=start, goal_xy=goal)
        assert np.all(np.isfinite(cm.cost[after.cells[:, 0], after.cells[:, 1]]))
        gap = _dist_to_boulder(cm, after.cells[:, 0], after.cells[:, 1]).min()
        assert gap > BOULDER_R + ROVER.footprint_radius_m, cm.resolution_m
        assert after.length_m < before.length_m + 4.0


def test_stereo_does_not_clear_an_orbital_hazard_unless_asked():
    # The orbital map holds a 0.5 m spike one pixel wide at (5.5, 5.5) (a noise burst):
    # its 4 neighbours have lethal slopes. Stereo sees flat ground over x in [2.5, 6.5],
    # y in [2, 9]: the cells west, north and south of the spike whole, the east one
    # (x in [6, 7]) half.
    zo = np.zeros((20, 20))
    zo[4, 15] = 0.5
    hzc = HazardConfig(resolution_m=1.0)
    prior = build_costmap(zo, resolution_m=1.0, x0_m=-10.0, y1_m=10.0, rover=ROVER, config=hzc)
    whole = [prior.cell_of(x, y) for x, y in ((4.5, 5.5), (5.5, 6.5), (5.5, 4.5))]
    half = prior.cell_of(6.5, 5.5)
    assert prior.lethal_raw.sum() == 4 and all(prior.lethal_raw[c] for c in [*whole, half])
    g = np.random.default_rng(4)
    xy = np.column_stack([g.uniform(2.5, 6.5, 60_000), g.uniform(2.0, 9.0, 60_000)])
    pts = np.column_stack([xy, g.normal(0.0, 0.005, len(xy))])
    cfg = ElevationMapConfig(min_range_m=0.0)
    em = fuse(ElevationMap.covering(prior), points_W=pts, sensor_origin_W=(5.0, 5.0, 1.5),
              config=cfg)  # fmt: skip
    hz = stereo_hazards(em, hazards=hzc, rover=ROVER, config=cfg)
    assert not hz.lethal.any() and hz.known[em.cell_of(5.5, 5.5)]
    kept = merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc)
    assert np.array_equal(kept.lethal_raw, prior.lethal_raw)
    assert np.array_equal(np.isfinite(kept.cost), np.isfinite(prior.cost))
    cleared = merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc, stereo_clears=True)
    for c in whole:
        assert not cleared.lethal_raw[c] and np.isfinite(cleared.cost[c])
        assert cleared.slope_deg[c] < 1.0
    assert cleared.lethal_raw[half] and not np.isfinite(cleared.cost[half])  # 50 % < 90 %
    assert cleared.lethal_raw.sum() == 1
    with pytest.raises(OutOfRangeError, match="upsample"):
        merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc, upsample=0)
    with pytest.raises(OutOfRangeError, match="clear_coverage"):
        merge_into_costmap(prior, stereo=hz, rover=ROVER, hazards=hzc, clear_coverage=0.0)


def test_end_to_end_a_matched_stereo_pair_makes_the_boulder_lethal(boulder):
    """A pair of the boulder scene warped from a seeded texture by the disparity of the
    right camera's rays (right(u, v) = left(u + f B / Z_right(u, v), v)), matched by
    SGBM, placed by the true camera pose, fused: the boulder is lethal, the ground not."""
    import cv2

    from lunar_drake.models.rover_description import krex2_rp
    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.perception.stereo import StereoConfig, match
    from lunar_drake.render.camera import CameraConfig

    calib = StereoCalibration.from_camera(
        camera=CameraConfig(width=320, height=240, fov_y_deg=45.0), description=krex2_rp()
    )
    K, h, w, B = calib.K_left, calib.height, calib.width, calib.baseline_m
    R, o, _, _ = _camera()
    v, u = np.mgrid[0:h, 0:w].astype(float)
    d_C = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    Z_right = _cast(R, o + R[:, 0] * B, d_C.reshape(-1, 3)).reshape(h, w)
    disp = np.where(np.isfinite(Z_right), K[0, 0] * B / Z_right, 0.0).astype(np.float32)
    g = np.random.default_rng(5)
    tex = cv2.GaussianBlur(g.uniform(0, 4095, (h, w + 200)), (0, 0), 1.2).astype(np.float32)
    left = tex[:, :w]
    right = cv2.remap(tex, (u + disp).astype(np.float32), v.astype(np.float32),
                      cv2.INTER_LINEAR)  # fmt: skip
    res = match(left.astype(np.uint16), right.astype(np.uint16), calib=calib,
                config=StereoConfig())  # fmt: skip
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, o
    cfg = ElevationMapConfig.for_rig(calib)
    assert cfg.focal_px == K[0, 0] and cfg.baseline_m == B
    em = fuse(ElevationMap.covering(boulder["prior"]), points_W=points_to_world(res.cloud(), X),
              sensor_origin_W=o, config=cfg)  # fmt: skip
    hz = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER, config=cfg,
                        prior=boulder["prior_dem"])  # fmt: skip
    assert hz.known.sum() > 1000
    lr, lc = np.nonzero(hz.lethal)
    d = _dist_to_boulder(em, lr, lc)
    assert len(d) > 10 and d.min() < BOULDER_R  # on the rock
    assert d.max() < 0.8  # no false hazards on the ground
    merged = merge_into_costmap(boulder["prior"], stereo=hz, rover=ROVER,
                                hazards=boulder["hazards"], upsample=2)  # fmt: skip
    after = plan_path(costmap=merged, start_xy=(-4.0, 0.0), goal_xy=(4.5, 0.0))
    gap = _dist_to_boulder(merged, after.cells[:, 0], after.cells[:, 1]).min()
    assert gap > BOULDER_R + ROVER.footprint_radius_m


def test_a_coarse_costmap_is_refined_with_its_lethal_cells_in_place():
    from lunar_drake.perception.elevation_map import refined_costmap

    z = np.zeros((20, 20))
    z[10, 10] = 1.0  # a 1 m spike: lethal at 1 m cells
    coarse = build_costmap(z, resolution_m=1.0, x0_m=0.0, y1_m=20.0, rover=ROVER,
                           config=HazardConfig(resolution_m=1.0))  # fmt: skip
    fine = refined_costmap(coarse, resolution_m=0.5, rover=ROVER, hazards=HazardConfig())
    assert fine.resolution_m == 0.5 and fine.shape == (40, 40)
    np.testing.assert_array_equal(fine.lethal_raw[::2, ::2], coarse.lethal_raw)
    # every cell whose centre is within the footprint radius + inflation of a lethal one
    lr, lc = np.nonzero(fine.lethal_raw)
    rr, cc = np.mgrid[0:40, 0:40]
    d = np.min(np.hypot(rr[..., None] - lr, cc[..., None] - lc), axis=-1) * 0.5
    np.testing.assert_array_equal(np.isinf(fine.cost), d <= ROVER.footprint_radius_m + 0.2)
    assert refined_costmap(fine, resolution_m=0.5, rover=ROVER, hazards=HazardConfig()) is fine


def test_a_rock_seen_once_counts_only_when_it_stands_far_over_the_limit(boulder):
    em, cfg = boulder["map"], boulder["config"]  # one cloud: every cell seen once
    twice = dc.replace(cfg, min_views=2)
    hz = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER, config=twice)
    assert not hz.known.any() and not hz.lethal.any()  # not trusted yet
    # The 0.3 m boulder is 1.5 times this rover's 0.2 m step limit.
    tall = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER,
                          config=dc.replace(twice, tall_views=1, tall_factor=1.2))  # fmt: skip
    lr, lc = np.nonzero(tall.lethal)
    assert tall.lethal[em.cell_of(0.0, 0.0)] and len(lr) >= 3
    assert _dist_to_boulder(em, lr, lc).max() < BOULDER_R + 0.3
    assert np.array_equal(tall.known, tall.lethal)  # only the tall cells were let in
    low = stereo_hazards(em, hazards=boulder["hazards"], rover=ROVER,
                         config=dc.replace(twice, tall_views=1, tall_factor=2.0))  # fmt: skip
    assert not low.lethal.any()


class _Heightfield:
    """The little a site heightfield the ground's map reads: bounds, pixel, windows."""

    def __init__(self, z, resolution_m):
        from types import SimpleNamespace

        self.z, self.resolution_m, self.shape = z, resolution_m, z.shape
        half = z.shape[0] * resolution_m / 2
        self.bounds = SimpleNamespace(left=-half, right=half, bottom=-half, top=half)

    def read_window(self, row0, col0, rows, cols):
        return self.z[row0 : row0 + rows, col0 : col0 + cols]


def test_steep_orbital_cells_are_lethal_until_stereo_has_seen_them():
    from lunar_drake.autonomy.costmap import MapConfig, costmap_for_site

    # A 12.5 deg ramp for x in [0, 8] m between flat ground: under the 14 deg limit,
    # over the 11 deg at which an orbital cell is not trusted.
    X, _ = _dem_grid()
    t = math.tan(math.radians(12.5))
    z = t * np.clip(X, 0.0, 8.0)
    hf = _Heightfield(z, RES)
    hzc = HazardConfig(resolution_m=1.0)
    kw = {"heightfield": hf, "points_xy": [(-12.0, 0.0), (12.0, 0.0)], "rover": ROVER,
          "hazards": hzc, "seed": 0}  # fmt: skip
    orbital = MapConfig(source="orbital", orbital_noise_m=0.0, margin_m=5.0)
    cm = costmap_for_site(map_config=orbital, **kw)
    steep = cm.slope_deg > 11.0
    assert steep.sum() >= 5 * 10 and np.all(cm.slope_deg < 14.0)  # the ramp's interior
    np.testing.assert_array_equal(cm.unconfirmed, steep)
    assert cm.lethal_raw[steep].all() and np.isinf(cm.cost[steep]).all()
    with pytest.raises(PlanningError, match="no hazard-free path"):
        plan_path(costmap=cm, start_xy=(-10.0, 0.0), goal_xy=(10.0, 0.0))
    with pytest.raises(PlanningError, match=r"orbital map, over ground.map.confirm_slope_deg"):
        plan_path(costmap=cm, start_xy=(-10.0, 0.0), goal_xy=(4.0, 0.0))
    trusting = (dc.replace(orbital, confirm_slope_deg=0.0), MapConfig(source="truth", margin_m=5.0))
    for off in trusting:
        trusted = costmap_for_site(map_config=off, **kw)
        assert trusted.unconfirmed is None and not trusted.lethal_raw.any()
    # Stereo sees the ramp for x in [1, 5.5] m, |y| <= 3 m: the cells within x in [1, 5]
    # are confirmed (stereo's slope, under the limit, judges them); the half-seen ones
    # (x in [5, 6]) and the rest stay unconfirmed.
    g = np.random.default_rng(7)
    xy = np.column_stack([g.uniform(1.0, 5.5, 90_000), g.uniform(-3.0, 3.0, 90_000)])
    pts = np.column_stack([xy, t * xy[:, 0] + g.normal(0.0, 0.005, len(xy))])
    cfg = ElevationMapConfig(min_range_m=0.0)
    em = fuse(ElevationMap.covering(cm), points_W=pts, sensor_origin_W=(0.0, 0.0, 1.5),
              config=cfg)  # fmt: skip
    hz = stereo_hazards(em, hazards=hzc, rover=ROVER, config=cfg)
    assert not hz.lethal.any()
    merged = merge_into_costmap(cm, stereo=hz, rover=ROVER, hazards=hzc)
    rr, cc = np.mgrid[0 : cm.shape[0], 0 : cm.shape[1]]
    x, y = cm.centre_of(rr, cc)
    seen = (x > 1.0) & (x < 5.0) & (np.abs(y) < 3.0)
    assert (steep & seen).sum() >= 4 * 6
    assert not merged.unconfirmed[seen].any() and not merged.lethal_raw[seen].any()
    np.testing.assert_array_equal(merged.unconfirmed, steep & ~seen)
    np.testing.assert_array_equal(merged.lethal_raw, steep & ~seen)
    half = (x == 5.5) & (np.abs(y) < 3.0) & steep
    assert half.sum() == 6 and merged.unconfirmed[half].all()
    # A rock stereo finds in a cell it has seen only a corner of makes that cell an
    # ordinary hazard at once: a later, fuller view without the rock does not clear it.
    cell = cm.cell_of(6.5, 0.5)
    assert merged.unconfirmed[cell]
    xa = np.column_stack([g.uniform(6.0, 6.5, 20_000), g.uniform(0.0, 0.5, 20_000)])
    za = t * xa[:, 0] + np.where(np.hypot(xa[:, 0] - 6.25, xa[:, 1] - 0.25) < 0.15, 0.4, 0.0)
    ema = fuse(ElevationMap.covering(cm), points_W=np.column_stack([xa, za]),
               sensor_origin_W=(3.0, 0.0, 1.5), config=cfg)  # fmt: skip
    hza = stereo_hazards(ema, hazards=hzc, rover=ROVER, config=cfg)
    ma = merge_into_costmap(merged, stereo=hza, rover=ROVER, hazards=hzc)
    assert hza.lethal.any() and ma.lethal_raw[cell] and not ma.unconfirmed[cell]
    xb = np.column_stack([g.uniform(6.0, 7.0, 40_000), g.uniform(0.0, 1.0, 40_000)])
    emb = fuse(ElevationMap.covering(cm), points_W=np.column_stack([xb, t * xb[:, 0]]),
               sensor_origin_W=(3.0, 0.0, 1.5), config=cfg)  # fmt: skip
    hzb = stereo_hazards(emb, hazards=hzc, rover=ROVER, config=cfg)
    mb = merge_into_costmap(ma, stereo=hzb, rover=ROVER, hazards=hzc)
    assert not hzb.lethal.any() and mb.lethal_raw[cell] and np.isinf(mb.cost[cell])
    # A steeper ramp seen by stereo (20 deg) is confirmed lethal: stereo's word.
    pts20 = np.column_stack([xy, math.tan(math.radians(20.0)) * xy[:, 0]])
    em20 = fuse(ElevationMap.covering(cm), points_W=pts20, sensor_origin_W=(0.0, 0.0, 1.5),
                config=cfg)  # fmt: skip
    hz20 = stereo_hazards(em20, hazards=hzc, rover=ROVER, config=cfg)
    m20 = merge_into_costmap(cm, stereo=hz20, rover=ROVER, hazards=hzc)
    assert not m20.unconfirmed[seen].any() and m20.lethal_raw[seen & steep].all()
    with pytest.raises(OutOfRangeError, match="confirm_slope_deg"):
        dc.replace(orbital, confirm_slope_deg=95.0).validate()
