"""Visual odometry against fused odometry (paper Fig. 21), on rendered stereo pairs.

**Rotation** (``angles``): for each angle A and seed, the mission's rover (the
scenario's, its full plant, flight software and link) stands still, takes a stereo pair,
turns in place by A (an uplinked drive command, yaw rate ``turn_rate_dps``, lengthened
by the rover's measured turn efficiency: ``calibrate_turns``), stops and takes a second
pair. Seeds change the spawn point (within ``spawn_radius_m`` of the scenario's), the
heading and every noise stream.

**Straight** (``straight_m``): the rover drives straight that far at ``speed_mps`` (the
ground stops it when the on-board estimate has it there, slip included; the seeded
spawn and heading are redrawn until that straight is clear of hazards on the true
costmap: the study measures VO on drivable ground, not a rover stuck on a rock); VO
chains keyframes ``keyframe_m`` apart (by the on-board estimate): each pair is aligned
to the previous keyframe's, a rejected alignment is replaced by the on-board motion for
that link (counted).

For each motion the camera's relative pose ``T_C0_C1`` (left camera, 4 x 4) is known
three ways:

* **truth**: from the plant's left-camera frame at the two capture instants (scoring
  only);
* **odometry**: the flight EKF's estimate (wheel odometry, IMU, star tracker) at the
  two instants, with the camera mounted on the chassis as the kinematic chain says
  (chassis-to-camera from the gimbal's measured angles: taken from the plant, exact);
* **VO**: ICP (:func:`lunar_drake.perception.vo.align`) of the two stereo clouds
  (:func:`lunar_drake.perception.stereo.match`, points within ``max_range_m``) from the
  odometry motion as the initial guess.

``vo_error_m`` and ``odom_error_m``: the norm of the difference between the estimated
and true camera translation (m, in the first camera frame). The frames are the raw
12-bit frames the camera produces; the image downlink's PNG is lossless, so the ground
would receive the same bytes.

``lights``: the ``night`` scenario's epoch (Sun below the horizon) with the rover's
headlights (its exposure and gain), in place of the scenario's lighting.
"""

from __future__ import annotations

import copy
import dataclasses as dc
import json
import math
from pathlib import Path

import numpy as np

from lunar_drake import rng
from lunar_drake.errors import ConfigError, SimulationError, check_range
from lunar_drake.files import atomic_path, atomic_write_text, ensure_output_dir

CSV_COLUMNS = (
    "angle_deg",
    "seed",
    "vo_error_m",
    "odom_error_m",
    "rejected",
    "used_error_m",
    "reason",
    "true_rotation_deg",
    "true_translation_m",
    "fitness",
    "inlier_rmse_m",
    "condition",
    "n_points_0",
    "n_points_1",
    "lights",
    "turn_efficiency",
    "fov_y_deg",
    "baseline_m",
    "mast_height_m",
)


@dc.dataclass(frozen=True)
class VoStudyConfig:
    """What the study runs.

    Attributes:
        scenario_name: the named scenario whose site, rover and sensors are used.
        angles_deg: rotation angles (deg, >= 0) for the rotation study.
        seeds: runs per angle (seeds 0 .. seeds - 1).
        straight_m: drive this far straight instead (m; None: the rotation study).
        lights: in shadow with the rover's headlights (the ``night`` scenario's epoch).
        width, height: camera image size (px).
        turn_rate_dps: commanded yaw rate of the turns (deg/s).
        speed_mps: commanded speed of the straight drive (m/s).
        keyframe_m: VO keyframe spacing on the straight drive (m, by the estimate).
        spawn_radius_m: seeds move the spawn within this radius of the scenario's (m).
        max_range_m: stereo points beyond this depth are not aligned (m; None: the
            scenario's ``ground.perception.max_range_m``).
        fov_y_deg: the mast cameras' vertical field of view (deg; None: the
            scenario's), for the lens trade.
        baseline_m, mast_height_m: the stereo baseline and the gimbal's height over the
            chassis (m; None: the rover's), for the placement trade.
        images: write each rotation run's two pairs (the left image beside its
            disparity) to ``images/`` in the output directory.
        calibrate_turns: command each turn so that the rover turns the angle asked
            for: a 30 deg turn per seed measures how much of a commanded turn the rover
            makes on this soil, on its own estimate (the star tracker's attitude), and
            the turns are lengthened by it. False: the commanded angle.
    """

    scenario_name: str = "default"
    angles_deg: tuple = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
    seeds: int = 3
    straight_m: float | None = None
    lights: bool = False
    width: int = 1024
    height: int = 768
    turn_rate_dps: float = 5.0
    speed_mps: float = 0.2
    keyframe_m: float = 1.0
    spawn_radius_m: float = 10.0
    max_range_m: float | None = None
    fov_y_deg: float | None = None
    baseline_m: float | None = None
    mast_height_m: float | None = None
    calibrate_turns: bool = True
    images: bool = False

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        if not self.angles_deg and self.straight_m is None:
            raise ConfigError("no angles given; pass --angles A:B:STEP or --straight DIST_M")
        for a in self.angles_deg:
            check_range("angle", a, 0.0, 180.0, unit=" deg")
        check_range("seeds", self.seeds, 1, 1000)
        if self.straight_m is not None:
            check_range("straight distance", self.straight_m, 0.0, 500.0, lo_open=True,
                        unit=" m")  # fmt: skip
        check_range("turn_rate_dps", self.turn_rate_dps, 0.0, 45.0, lo_open=True, unit=" deg/s")
        check_range("speed_mps", self.speed_mps, 0.0, 2.0, lo_open=True, unit=" m/s")
        check_range("keyframe_m", self.keyframe_m, 0.05, 10.0, unit=" m")
        check_range("spawn_radius_m", self.spawn_radius_m, 0.0, 100.0, unit=" m")
        if self.max_range_m is not None:
            check_range("max_range_m", self.max_range_m, 1.0, 100.0, unit=" m")
        if self.fov_y_deg is not None:
            check_range("fov_y_deg", self.fov_y_deg, 5.0, 120.0, unit=" deg")
        if self.baseline_m is not None:
            check_range("baseline_m", self.baseline_m, 0.01, 5.0, unit=" m")
        if self.mast_height_m is not None:
            check_range("mast_height_m", self.mast_height_m, 0.0, 20.0, unit=" m")


def parse_angles(text: str) -> tuple:
    """'A:B:STEP' (inclusive) or a comma list -> angles in degrees."""
    try:
        if ":" in text:
            a, b, step = (float(v) for v in text.split(":"))
            if step <= 0 or b < a:
                raise ValueError
            n = math.floor((b - a) / step + 1e-9) + 1
            return tuple(round(a + k * step, 9) for k in range(n))
        return tuple(float(v) for v in text.split(","))
    except ValueError as exc:
        raise ConfigError(
            f"--angles {text!r} must be A:B:STEP with STEP > 0 and B >= A, or a comma list"
        ) from exc


# ----------------------------------------------------------------------------------------
# one run
# ----------------------------------------------------------------------------------------
@dc.dataclass
class _Capture:
    """One stereo pair and the poses at its capture instant."""

    t: float
    left: np.ndarray
    right: np.ndarray
    X_WC: np.ndarray  # truth, left camera (4 x 4)
    X_WC_est: np.ndarray  # on-board estimate of the same (4 x 4)


def _straight_is_clear(scenario, site, *, x_m: float, y_m: float, yaw_rad: float,
                       distance_m: float) -> bool:  # fmt: skip
    """Whether the straight from (x, y) along ``yaw_rad`` for ``distance_m`` (plus the
    rover's length) crosses no lethal cell of the true costmap (the ground's hazard
    rules, the rover's footprint inflation) and stays on the site."""
    from lunar_drake.autonomy.costmap import MapConfig, RoverEnvelope, costmap_for_site

    d = distance_m + scenario.rover.description.wheelbase_m + 1.0
    p0 = np.array([x_m, y_m])
    p1 = p0 + d * np.array([math.cos(yaw_rad), math.sin(yaw_rad)])
    b = site.heightfield.bounds
    if not all(b.left + 2 < x < b.right - 2 and b.bottom + 2 < y < b.top - 2 for x, y in (p0, p1)):
        return False
    cm = costmap_for_site(
        heightfield=site.heightfield,
        points_xy=[p0, p1],
        rover=RoverEnvelope.of(scenario.rover.description),
        hazards=scenario.ground.hazards,
        map_config=MapConfig(source="truth", margin_m=3.0),
        seed=scenario.random_seed,
    )
    for f in np.linspace(0.0, 1.0, max(2, int(d / (0.5 * cm.resolution_m)) + 1)):
        r, c = cm.cell_of(*(p0 + f * (p1 - p0)))
        if not cm.inside(r, c) or not np.isfinite(cm.cost[r, c]):
            return False
    return True


def _scenario_for(config: VoStudyConfig, seed: int, site=None):
    """The study's scenario for ``seed``: the spawn moved within ``spawn_radius_m`` and a
    heading drawn, both seeded; for the straight drive (``site`` given) redrawn until the
    straight ahead is clear of hazards (:func:`_straight_is_clear`; 100 tries)."""
    from lunar_drake.scenario_files import load_scenario

    s = load_scenario(scenario_name=config.scenario_name)
    if config.lights:
        night = load_scenario(scenario_name="night")
        s.site.epoch_utc = night.site.epoch_utc
        s.rover.lights = copy.deepcopy(night.rover.lights)
        s.sensors.camera.exposure_s = night.sensors.camera.exposure_s
        s.sensors.camera.gain = night.sensors.camera.gain
        s.comms = copy.deepcopy(night.comms)
    s.random_seed = int(seed)
    g = rng.generator(int(seed), "vo_study.spawn")
    x0, y0 = s.rover.spawn_x_m, s.rover.spawn_y_m
    for _attempt in range(100):
        r = config.spawn_radius_m * math.sqrt(g.uniform())
        b = g.uniform(0.0, 2.0 * math.pi)
        s.rover.spawn_x_m = x0 + r * math.cos(b)
        s.rover.spawn_y_m = y0 + r * math.sin(b)
        s.rover.spawn_yaw_deg = float(g.uniform(0.0, 360.0))
        if site is None or config.straight_m is None or _straight_is_clear(
            s, site, x_m=s.rover.spawn_x_m, y_m=s.rover.spawn_y_m,
            yaw_rad=math.radians(s.rover.spawn_yaw_deg), distance_m=config.straight_m,
        ):  # fmt: skip
            break
    else:
        raise SimulationError(
            f"vo-study: no straight of {config.straight_m:g} m clear of hazards found within "
            f"{config.spawn_radius_m:g} m of the spawn on seed {seed}; try --spawn-radius"
        )
    cam = s.sensors.camera
    cam.enabled = True
    cam.width, cam.height = config.width, config.height
    cam.rate_hz = 1.0
    cam.delay_s = 0.0  # the study reads each frame at its capture instant
    if config.fov_y_deg is not None:
        cam.fov_y_deg = float(config.fov_y_deg)
    cam.validate()
    d = s.rover.description
    if config.baseline_m is not None:
        d.camera_baseline_m = float(config.baseline_m)
    if config.mast_height_m is not None:
        d.mast_height_m = float(config.mast_height_m)
    d.validate()
    s.flight.images.enabled = False
    s.ground.goals = []
    s.ground.actions = []
    return s


def _route(config: VoStudyConfig, angle_deg: float, turn_efficiency: float = 1.0):
    """The route: idle, the motion (a turn lengthened by ``1 / turn_efficiency``), idle."""
    from lunar_drake.scenario import RouteSegment

    idle = RouteSegment(duration_s=4.0)
    if config.straight_m is not None:  # long enough: the study stops it (run_straight)
        move = RouteSegment(duration_s=1.5 * config.straight_m / config.speed_mps,
                            vx_mps=config.speed_mps)  # fmt: skip
    else:
        w = math.radians(config.turn_rate_dps)
        turn_s = math.radians(angle_deg) / (w * turn_efficiency)
        move = RouteSegment(duration_s=max(turn_s, 1e-3), wz_radps=w)
    return [idle, move, RouteSegment(duration_s=30.0)]


class _Rig:
    """The mission diagram of one run and what the study reads from it."""

    def __init__(self, scenario, site):
        from pydrake.systems.analysis import Simulator

        from lunar_drake.diagrams.mission import MakeMissionDiagram

        self.mission = MakeMissionDiagram(scenario=scenario, site=site)
        self.sim = Simulator(self.mission)
        self.sim.Initialize()
        root = self.sim.get_context()
        plant = self.mission.GetSubsystemByName("plant")
        self.cam = plant.GetSubsystemByName("camera")
        self.mbp = plant.GetSubsystemByName("plant")
        est = self.mission.GetSubsystemByName("flight").GetSubsystemByName("flight.estimator")
        self.est = est
        self._cam_ctx = self.cam.GetMyContextFromRoot(root)
        self._mbp_ctx = self.mbp.GetMyContextFromRoot(root)
        self._est_ctx = est.GetMyContextFromRoot(root)
        self.period = 1.0 / scenario.sensors.camera.rate_hz

    def advance_to(self, t: float) -> None:
        self.sim.AdvanceTo(t)

    def X_WB(self) -> np.ndarray:
        return self.mbp.GetBodyByName("chassis").EvalPoseInWorld(self._mbp_ctx).GetAsMatrix4()

    def capture(self, k: int) -> _Capture:
        """Advances to camera frame ``k`` and returns it with the poses at that instant."""
        from pydrake.common.eigen_geometry import Quaternion

        t = k * self.period + 1e-6
        self.advance_to(t)
        X_WC = self.mbp.GetFrameByName("left_camera").CalcPoseInWorld(self._mbp_ctx).GetAsMatrix4()
        X_WB = self.X_WB()
        p = np.asarray(self.est.p_WB_output.Eval(self._est_ctx), float)
        q = np.asarray(self.est.q_WB_output.Eval(self._est_ctx), float)
        X_WB_est = np.eye(4)
        X_WB_est[:3, :3] = Quaternion(q / np.linalg.norm(q)).rotation()
        X_WB_est[:3, 3] = p
        X_WC_est = X_WB_est @ np.linalg.inv(X_WB) @ X_WC
        left = np.array(self.cam.frame(self._cam_ctx, "left").raw)
        right = np.array(self.cam.frame(self._cam_ctx, "right").raw)
        return _Capture(t, left, right, X_WC, X_WC_est)

    def yaw_rate(self) -> float:
        v = self.mbp.GetBodyByName("chassis").EvalSpatialVelocityInWorld(self._mbp_ctx)
        return float(abs(v.rotational()[2]))

    def speed(self) -> float:
        v = self.mbp.GetBodyByName("chassis").EvalSpatialVelocityInWorld(self._mbp_ctx)
        return float(np.linalg.norm(v.translational()[:2]))


def _relative(X0, X1) -> np.ndarray:
    return np.linalg.inv(X0) @ X1


def _translation_error(T_est, T_true) -> float:
    return float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_true)[:3, 3]))


def _max_range(config: VoStudyConfig, scenario) -> float:
    if config.max_range_m is not None:
        return float(config.max_range_m)
    return float(scenario.ground.perception.max_range_m)


def _cloud(capture: _Capture, *, calib, stereo_config, max_range_m: float) -> tuple:
    """(points (N, 3) m, left camera frame; their image intensities (N,) 0..1; the
    :class:`~lunar_drake.perception.stereo.StereoResult`)."""
    from lunar_drake.perception.stereo import match

    res = match(capture.left, capture.right, calib=calib, config=stereo_config)
    c, g = res.cloud(), res.cloud_intensity()
    near = c[:, 2] <= max_range_m
    return c[near], g[near], res


def write_pair_image(path: Path, res, *, max_range_m: float) -> None:
    """One PNG: the rectified left image the matcher saw beside its disparity (turbo,
    0 to the disparity range; black: no match; points beyond ``max_range_m``, which VO
    does not align, dimmed)."""
    import cv2

    from lunar_drake.files import atomic_write_bytes

    d = np.nan_to_num(res.disparity, nan=0.0)
    d8 = np.clip(255.0 * d / max(res.num_disparities, 1), 0, 255).astype(np.uint8)
    col = cv2.applyColorMap(d8, cv2.COLORMAP_TURBO)
    col[~res.valid] = 0
    far = res.valid & ~(res.depth_m <= max_range_m)
    col[far] = (col[far] * 0.35).astype(np.uint8)
    left = cv2.cvtColor(res.left_8bit, cv2.COLOR_GRAY2BGR)
    ok, png = cv2.imencode(".png", np.hstack([left, col]))
    if not ok:
        raise SimulationError(f"could not encode {path}")
    atomic_write_bytes(path, png.tobytes(), what=path.name)


def _wait_still(rig: _Rig, k: int, *, moving_from_k: int, max_k: int) -> int:
    """The first frame index after the rover started and then came to rest (yaw rate and
    speed ~0 over one frame period)."""
    started = False
    for kk in range(k, max_k):
        rig.advance_to(kk * rig.period + 1e-6)
        still = rig.yaw_rate() < math.radians(0.05) and rig.speed() < 0.002
        if not still:
            started = True
        elif started or kk >= moving_from_k + 30:
            rig.advance_to((kk + 1) * rig.period + 1e-6)
            if rig.yaw_rate() < math.radians(0.05) and rig.speed() < 0.002:
                return kk + 1
    raise SimulationError(f"vo-study: the rover did not come to rest by t = {max_k * rig.period} s")


def _turn_pair(config: VoStudyConfig, site, *, angle_deg: float, seed: int,
               turn_efficiency: float):  # fmt: skip
    """(scenario, rig, first capture, second capture) of one turn in place."""
    s = _scenario_for(config, seed)
    s.ground.route = _route(config, angle_deg, turn_efficiency)
    s.simulation_duration = 1e6
    rig = _Rig(s, site)
    c0 = rig.capture(3)  # the gimbal settled, before the first command arrives
    if rig.yaw_rate() > math.radians(0.05) or rig.speed() > 0.002:
        raise SimulationError("vo-study: the rover moved before the first pair")
    turn_s = math.radians(angle_deg) / math.radians(config.turn_rate_dps) / turn_efficiency
    if angle_deg > 0:
        k1 = _wait_still(rig, 4, moving_from_k=4, max_k=int(40 + 3 * turn_s))
    else:
        k1 = 5
    return s, rig, c0, rig.capture(k1)


def turn_efficiency(*, config: VoStudyConfig, site, seed: int, angle_deg: float = 30.0) -> float:
    """The fraction of a commanded turn in place the rover makes (its estimate's rotation
    over the commanded angle, in (0.2, 1.5]) on this seed's spawn."""
    from lunar_drake.perception.vo import correction

    *_, c0, c1 = _turn_pair(config, site, angle_deg=angle_deg, seed=seed, turn_efficiency=1.0)
    _, est = correction(c0.X_WC_est, c1.X_WC_est)
    e = est / angle_deg
    if not 0.2 < e <= 1.5:
        raise SimulationError(
            f"vo-study: the rover turned {est:.1f} deg of a commanded "
            f"{angle_deg:g} deg on seed {seed}; it cannot turn in place here"
        )
    return e


def run_rotation(*, config: VoStudyConfig, site, angle_deg: float, seed: int,
                 turn_efficiency: float = 1.0, images_dir=None) -> dict:  # fmt: skip
    """One rotation run: a pair at rest, a turn in place by ``angle_deg`` (commanded for
    ``angle_deg / turn_efficiency``), a pair at rest. ``images_dir``: write both pairs
    there (:func:`write_pair_image`, ``a{angle}_s{seed}_{0,1}.png``)."""
    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.perception.vo import ViewFrustum, align, correction

    s, _, c0, c1 = _turn_pair(config, site, angle_deg=angle_deg, seed=seed,
                              turn_efficiency=turn_efficiency)  # fmt: skip
    calib = StereoCalibration.from_camera(camera=s.sensors.camera,
                                          description=s.rover.description)  # fmt: skip
    perception = s.ground.perception
    max_range = _max_range(config, s)
    T_true = _relative(c0.X_WC, c1.X_WC)
    T_odom = _relative(c0.X_WC_est, c1.X_WC_est)
    p0 = _cloud(c0, calib=calib, stereo_config=perception.stereo, max_range_m=max_range)
    p1 = _cloud(c1, calib=calib, stereo_config=perception.stereo, max_range_m=max_range)
    al = align(p0[0], p1[0], init_T=T_odom, prev_intensity=p0[1], curr_intensity=p1[1],
               config=perception.vo,
               frustum=ViewFrustum.from_calibration(calib, max_range_m=max_range))  # fmt: skip
    _, rot = correction(np.eye(4), T_true)
    if images_dir is not None:
        for k, p in enumerate((p0, p1)):
            write_pair_image(Path(images_dir) / f"a{angle_deg:g}_s{seed}_{k}.png", p[2],
                             max_range_m=max_range)  # fmt: skip
    vo_err = _translation_error(al.T_prev_curr, T_true)
    odom_err = _translation_error(T_odom, T_true)
    return {
        "angle_deg": float(angle_deg),
        "seed": int(seed),
        "vo_error_m": vo_err,
        "odom_error_m": odom_err,
        "rejected": bool(al.rejected),
        "used_error_m": odom_err if al.rejected else vo_err,
        "reason": al.reason,
        "true_rotation_deg": rot,
        "true_translation_m": float(np.linalg.norm(T_true[:3, 3])),
        "fitness": al.fitness,
        "inlier_rmse_m": al.inlier_rmse_m,
        "condition": al.condition,
        "n_points_0": len(p0[0]),
        "n_points_1": len(p1[0]),
        "lights": bool(config.lights),
        "turn_efficiency": float(turn_efficiency),
        "fov_y_deg": float(s.sensors.camera.fov_y_deg),
        "baseline_m": float(s.rover.description.camera_baseline_m),
        "mast_height_m": float(s.rover.description.mast_height_m),
    }


STOP_LEAD_S = 1.5  # the uplink's light time and processing (~1.3 s), rounded up


def run_straight(*, config: VoStudyConfig, site, seed: int, progress=None) -> dict:
    """One straight drive of ``config.straight_m`` with keyframe VO chained along it: the
    ground sends a stop when the on-board estimate says the rover, ``STOP_LEAD_S`` of
    driving later, will have gone the distance (so the rover drives it, slip included)."""
    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.perception.vo import ViewFrustum, align

    s = _scenario_for(config, seed, site)
    s.ground.route = _route(config, 0.0)
    s.simulation_duration = 1e6
    calib = StereoCalibration.from_camera(camera=s.sensors.camera,
                                          description=s.rover.description)  # fmt: skip
    stereo, vo_config = s.ground.perception.stereo, s.ground.perception.vo
    max_range = _max_range(config, s)
    frustum = ViewFrustum.from_calibration(calib, max_range_m=max_range)
    rig = _Rig(s, site)
    from lunar_drake.diagrams.mission import ground_operator

    ops = ground_operator(rig.mission)
    k = 3
    start = rig.capture(k)
    stop_sent = False
    key, key_cloud = start, _cloud(start, calib=calib, stereo_config=stereo,
                                   max_range_m=max_range)  # fmt: skip
    T_vo = np.eye(4)
    links = rejected = 0
    drive_s = config.straight_m / config.speed_mps
    max_k = int(k + 40 + 3 * drive_s)
    started = done = False
    while not done:
        k += 1
        if k > max_k:
            raise SimulationError(f"vo-study: the drive did not end by t = {max_k} s")
        c = rig.capture(k)
        moving = rig.speed() > 0.002
        started = started or moving
        done = started and not moving
        est = float(np.linalg.norm(_relative(start.X_WC_est, c.X_WC_est)[:3, 3]))
        if not stop_sent and est >= config.straight_m - config.speed_mps * STOP_LEAD_S:
            ops.stop(rig.sim.get_mutable_context())
            stop_sent = True
        step = np.linalg.norm(_relative(key.X_WC_est, c.X_WC_est)[:3, 3])
        if step < config.keyframe_m and not done:
            continue
        cloud = _cloud(c, calib=calib, stereo_config=stereo, max_range_m=max_range)
        T_odom = _relative(key.X_WC_est, c.X_WC_est)
        al = align(key_cloud[0], cloud[0], init_T=T_odom, prev_intensity=key_cloud[1],
                   curr_intensity=cloud[1], config=vo_config, frustum=frustum)  # fmt: skip
        links += 1
        if al.rejected:
            rejected += 1
        T_vo = T_vo @ (T_odom if al.rejected else al.T_prev_curr)
        key, key_cloud = c, cloud
        if progress is not None:
            progress(float(np.linalg.norm(_relative(start.X_WC, c.X_WC)[:3, 3])))
    T_true = _relative(start.X_WC, key.X_WC)
    T_odom = _relative(start.X_WC_est, key.X_WC_est)
    dist = float(np.linalg.norm(T_true[:3, 3]))
    return {
        "seed": int(seed),
        "distance_m": dist,
        "vo_error_m": _translation_error(T_vo, T_true),
        "odom_error_m": _translation_error(T_odom, T_true),
        "links": links,
        "rejected": rejected,
        "lights": bool(config.lights),
    }


# ----------------------------------------------------------------------------------------
# the study
# ----------------------------------------------------------------------------------------
_SITES: dict = {}


def _site_of(config: VoStudyConfig):
    """The study's site, loaded once per process (a worker loads its own from the
    cache rather than receiving the whole raster)."""
    from lunar_drake.site import load_site

    base = _scenario_for(config, 0)
    key = (config.scenario_name, config.lights)
    if key not in _SITES:
        _SITES[key] = load_site(base, progress=False)
    return _SITES[key]


def _efficiency_case(item) -> float:
    config, seed = item
    return turn_efficiency(config=config, site=_site_of(config), seed=seed)


def _rotation_case(item) -> dict:
    config, angle, seed, eff, images_dir = item
    return run_rotation(config=config, site=_site_of(config), angle_deg=angle, seed=seed,
                        turn_efficiency=eff, images_dir=images_dir)  # fmt: skip


def _straight_case(item) -> dict:
    config, seed = item
    return run_straight(config=config, site=_site_of(config), seed=seed)


def run_vo_study(*, config: VoStudyConfig, out_dir, progress: bool = True, workers: int = 1,
                 scheduler: str | None = None) -> dict:  # fmt: skip
    """Runs the study and writes ``vo.csv`` + ``vo.png`` (rotation) or ``straight.json``
    (straight) to ``out_dir``, with ``params.json``. Returns what was written.

    Runs (the turn calibrations, then the rotations; or the straight drives) go to the
    trade-study engine (dask.distributed) with ``workers > 1`` or a ``scheduler``
    address, else run here; the files do not depend on the worker count.
    """
    from lunar_drake.site import load_site

    config.validate()
    out_dir = ensure_output_dir(out_dir, what="--out directory")
    load_site(_scenario_for(config, 0), progress=progress)  # built (and cached) once, here
    from lunar_drake.trade.engine import map_cases

    params = {"config": dc.asdict(config), "method": __doc__.strip()}
    run = {"workers": workers, "scheduler": scheduler, "progress": progress}
    if config.straight_m is not None:
        runs = map_cases(_straight_case, [(config, seed) for seed in range(config.seeds)],
                    desc="straight drives", **run)  # fmt: skip
        doc = {
            "distance_m": float(np.mean([r["distance_m"] for r in runs])),
            "vo_error_m": float(np.mean([r["vo_error_m"] for r in runs])),
            "odom_error_m": float(np.mean([r["odom_error_m"] for r in runs])),
            "vo_error_pct": float(np.mean([100 * r["vo_error_m"] / r["distance_m"] for r in runs])),
            "odom_error_pct": float(
                np.mean([100 * r["odom_error_m"] / r["distance_m"] for r in runs])
            ),
            "links": int(sum(r["links"] for r in runs)),
            "rejected": int(sum(r["rejected"] for r in runs)),
            "runs": runs,
        }
        atomic_write_text(out_dir / "straight.json", json.dumps(doc, indent=2) + "\n",
                          what="straight.json")  # fmt: skip
        atomic_write_text(out_dir / "params.json", json.dumps(params, indent=2) + "\n")
        return doc
    seeds = list(range(config.seeds))
    eff = {s: 1.0 for s in seeds}
    if config.calibrate_turns and any(a > 0 for a in config.angles_deg):
        got = map_cases(_efficiency_case, [(config, s) for s in seeds], desc="turn calibration",
                   **run)  # fmt: skip
        eff = dict(zip(seeds, got, strict=True))
    images_dir = None
    if config.images:
        images_dir = str(ensure_output_dir(out_dir / "images", what="images directory"))
    cases = [(config, a, s, eff[s], images_dir) for a in config.angles_deg for s in seeds]
    rows = map_cases(_rotation_case, cases, desc="vo study", **run)
    write_csv(out_dir / "vo.csv", rows)
    plot_vo(rows, path=out_dir / "vo.png", lights=config.lights)
    atomic_write_text(out_dir / "params.json", json.dumps(params, indent=2) + "\n")
    return {"rows": rows, "summary": summarize(rows)}


def write_csv(path: Path, rows) -> None:
    """``vo.csv``: one row per run, :data:`CSV_COLUMNS`."""
    with atomic_path(path, what="vo.csv") as tmp, open(tmp, "w") as f:
        f.write(",".join(CSV_COLUMNS) + "\n")
        for r in rows:
            vals = []
            for c in CSV_COLUMNS:
                v = r[c]
                if isinstance(v, bool):
                    vals.append(str(int(v)))
                elif isinstance(v, float):
                    vals.append(f"{v:.6g}")
                else:
                    vals.append(str(v).replace(",", ";"))
            f.write(",".join(vals) + "\n")


def summarize(rows) -> list[dict]:
    """Per angle: mean VO error (all runs and accepted ones), mean odometry error, how
    many alignments were rejected, and how many bad ones (error above the odometry's)
    were let through."""
    out = []
    for a in sorted({r["angle_deg"] for r in rows}):
        rr = [r for r in rows if r["angle_deg"] == a]
        acc = [r["vo_error_m"] for r in rr if not r["rejected"]]
        used = [r.get("used_error_m", r["odom_error_m"] if r["rejected"] else r["vo_error_m"])
                for r in rr]  # fmt: skip
        bad = [r for r in rr if r["vo_error_m"] > r["odom_error_m"]]
        out.append({
            "angle_deg": a,
            "runs": len(rr),
            "vo_error_m": float(np.mean([r["vo_error_m"] for r in rr])),
            "vo_accepted_error_m": float(np.mean(acc)) if acc else math.nan,
            "used_error_m": float(np.mean(used)),
            "true_rotation_deg": float(np.mean([r.get("true_rotation_deg", a) for r in rr])),
            "odom_error_m": float(np.mean([r["odom_error_m"] for r in rr])),
            "rejected": sum(r["rejected"] for r in rr),
            "bad": len(bad),
            "bad_accepted": sum(not r["rejected"] for r in bad),
        })  # fmt: skip
    return out


def plot_vo(rows, *, path, lights: bool = False) -> None:
    """``vo.png``: position error vs the true camera rotation, VO (each run; rejected
    hollow) and fused odometry, with the per-angle means (VO over all runs, and as the
    ground uses it: a rejected alignment replaced by the odometry)."""
    from matplotlib.figure import Figure  # no pyplot: no backend forced on the caller

    summ = summarize(rows)
    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    a = np.array([r.get("true_rotation_deg", r["angle_deg"]) for r in rows])
    vo = np.array([r["vo_error_m"] for r in rows])
    od = np.array([r["odom_error_m"] for r in rows])
    rej = np.array([r["rejected"] for r in rows], bool)
    ax.scatter(a[~rej], 100 * vo[~rej], s=18, color="tab:blue", alpha=0.6, label="VO (run)")
    ax.scatter(a[rej], 100 * vo[rej], s=24, facecolors="none", edgecolors="tab:blue",
               label="VO (rejected)")  # fmt: skip
    ax.scatter(a, 100 * od, s=18, color="tab:orange", alpha=0.6, marker="s",
               label="wheel + IMU + star tracker (run)")  # fmt: skip
    sa = [s["true_rotation_deg"] for s in summ]
    ax.plot(sa, [100 * s["vo_error_m"] for s in summ], color="tab:blue", label="VO mean")
    ax.plot(sa, [100 * s["used_error_m"] for s in summ], color="tab:blue", ls="--",
            label="VO mean, rejected -> odometry")  # fmt: skip
    ax.plot(sa, [100 * s["odom_error_m"] for s in summ], color="tab:orange",
            label="odometry mean")  # fmt: skip
    ax.set_xlabel("camera rotation between frames (deg)")
    ax.set_ylabel("position error (cm)")
    ax.set_yscale("symlog", linthresh=1.0)
    fovs = sorted({float(r["fov_y_deg"]) for r in rows if "fov_y_deg" in r})
    lens = f", {fovs[0]:g} deg vertical lens" if len(fovs) == 1 else ""
    ax.set_title("VO vs fused odometry" + lens + (" (headlights, shadow)" if lights else ""),
                 fontsize=11)  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path, what="vo.png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")


__all__ = ["VoStudyConfig", "parse_angles", "plot_vo", "run_rotation", "run_straight",
           "run_vo_study", "summarize", "turn_efficiency", "write_csv"]  # fmt: skip
