"""The ground's perception step: downlinked stereo frames -> stereo clouds -> ICP visual
odometry fused with the on-board estimate -> local elevation map -> hazards merged into
the costmap. Pure (numpy, OpenCV, Open3D); no Drake.

Per received frame (:class:`~lunar_drake.comms.images.StereoFrame`, its header carrying
the on-board pose estimate and the gimbal angles at capture):

* **keyframes**: a frame is processed when the on-board estimate has moved at least
  ``keyframe_m`` or turned ``keyframe_deg`` since the last keyframe (the first frame is
  one); the others are skipped (the ground's compute goes to keyframes).
* **stereo** (:func:`~lunar_drake.perception.stereo.match`): the left camera's cloud,
  points within ``max_range_m``.
* **VO** (:func:`~lunar_drake.perception.vo.align`): the cloud aligned to the previous
  keyframe's from the on-board motion between the two (``T_odom``).
* **fusion** (the ground's filter): the camera's motion between keyframes is the
  inverse-variance mean of the on-board translation (sigma ``odom_sigma_fraction`` x
  distance + ``odom_sigma_per_rad_m`` x turn + ``odom_sigma_min_m``, grown by the slip
  VO shows) and the VO translation
  (sigma ``vo_sigma_m``), the rotation the on-board one (star tracker: arcseconds). A
  rejected alignment leaves the on-board motion, as does one further from the
  on-board step than ``vo_gate_sigmas`` combined sigmas in a way slip cannot explain
  (:func:`innovation`: the innovation gate). The ground's keyframe pose is
  the previous one composed with the fused motion; ``correction`` (4 x 4) maps on-board
  poses to the ground's (``X_W_ground = correction @ X_W_onboard``), applied to
  telemetry between keyframes. This is a Kalman update of the relative motion with
  isotropic, constant-shape covariances (no cross-correlations, no attitude update): an
  approximation. The ground's position variance grows by each link's fused variance
  (``1 / (1 / sigma_odom^2 + 1 / sigma_vo^2)``, or the on-board one alone), and a
  systematic part, ``vo_scale_sigma`` of each fused step, adds up linearly (a scale
  error does not average out; it grows with the net displacement, as a vector), so
  ``sigma_m = sqrt(var + |sys|^2)`` says how far, one
  sigma per axis, the ground's pose may have wandered since the first keyframe.
* **mapping**: the cloud, in the ground's estimated frame, fused into a local
  elevation map (:mod:`~lunar_drake.perception.elevation_map`, a ``window_m`` square
  re-centred on the rover when it nears an edge; what leaves it stays in the costmap);
  its hazards merged into the ground's costmap (never clearing the a-priori hazards).
* **record**: the mapped points (``p_W``: in the site frame through the ground's pose
  ``X_WC_ground``, past the self-radius, prior-gate and the map's range limits), one per
  ``cloud_voxel_m`` voxel (:func:`voxel_downsample`), kept as a :class:`KeyframeCloud`
  in ``PerceptionState.clouds`` for the run's record; nothing the ground decides reads
  them.

Frames: ``X_WB`` chassis in the site frame, ``X_BC`` left camera in the chassis frame
(``camera_in_chassis(pan, tilt)``), camera axes x right, y down, z forward.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.comms.messages import Ledger
from lunar_drake.errors import check_range
from lunar_drake.perception.elevation_map import ElevationMapConfig
from lunar_drake.perception.stereo import StereoConfig
from lunar_drake.perception.vo import VoConfig


@dc.dataclass
class PerceptionConfig:
    """The ground's perception (``ground.perception`` in the scenario).

    Attributes:
        enabled: run it (needs downlinked frames: cameras on and ``flight.images``).
        keyframe_m, keyframe_deg: process a frame once the on-board estimate moved this
            far (m) or turned this much (deg) since the last keyframe.
        max_range_m: stereo points beyond this depth are not aligned (m); the map has
            its own range limits (``map``).
        gimbal_settle_s: frames taken less than this long after the gimbal command
            changed are skipped (the mast was still moving; s).
        prior_gate_m: with an a-priori DEM, points further than this above or below it
            (after the median offset between the two) are dropped (m): far terrain
            matched wrongly lands at camera height; rocks taller than this are not
            expected.
        self_radius_m: points within this horizontal distance of the chassis origin
            (m; 0: half the wheelbase + wheel radius + the footprint radius, the rover's
            own wheels and body) are left out of the map.
        window_m: side of the local elevation map (m).
        cloud_voxel_m: each keyframe's mapped points are kept for the run's record
            (``keyframe_points.npy``, ``/ground/points`` in ``run.mcap``), one per cube
            of this side (their centroid; m); 0: none kept. Recording only: nothing the
            ground decides reads them.
        processing_s: how long the ground's computers take over the frames of one tick
            (s): their results (pose correction, map, keyframe records) take effect this
            long after the tick that took the frames in; 0: in that tick. With a
            processing time the work runs on a worker thread meanwhile.
        use_vo: fuse VO into the ground's pose (else the on-board estimate alone).
        odom_sigma_fraction, odom_sigma_min_m: on-board translation sigma between
            keyframes: fraction of the distance, plus a floor (m). 5 %: on the
            autonomy benchmark's orbital-map runs VO and the on-board step differed by
            3.7 % of the step (median; 10 % at the 90th percentile) while VO's own link
            error is 1-2 cm (vo-study): the difference is the odometry's (slip).
        odom_sigma_per_rad_m: the on-board translation's sigma grows by this much per
            radian the camera turned between keyframes (m/rad): turning in place the
            wheels scrub and the odometry's camera step is poor (autonomy benchmark,
            orbital map: 0.315 m on board against 0.094 m true over a 0.28 rad turn,
            where VO's 0.149 m was gated as too far from the odometry).
        vo_sigma_m: VO translation sigma per keyframe link (m; vo-study's straight
            drives: 6-11 cm over 19 links of 1 m).
        vo_scale_sigma: VO's unmodelled scale error, a fraction of each fused step
            (fully correlated: it adds as a vector of the steps, so it grows with the
            net displacement; 0.007: on the default mission with the symmetric stereo
            matching VO's steps were 0.45 % (61 links) and 0.7 % (59 links, ``hh``)
            longer than the true camera steps, medians).
        vo_gate_sigmas: an accepted alignment whose translation differs from the
            on-board one by more than this many combined sigmas, in a way slip cannot
            explain (:func:`innovation`), is not fused (the innovation gate; recorded
            as ``vo: gated``).
        stereo, vo, map: :class:`StereoConfig`, :class:`VoConfig`,
            :class:`ElevationMapConfig` (its ``focal_px`` and ``baseline_m`` are not
            read: they come from the rig's calibration).
    """

    enabled: bool = True
    processing_s: float = 0.0
    keyframe_m: float = 1.0
    keyframe_deg: float = 10.0
    max_range_m: float = 6.0
    gimbal_settle_s: float = 2.0
    self_radius_m: float = 0.0
    prior_gate_m: float = 1.0
    window_m: float = 30.0
    cloud_voxel_m: float = 0.1
    use_vo: bool = True
    odom_sigma_fraction: float = 0.05
    odom_sigma_min_m: float = 0.005
    odom_sigma_per_rad_m: float = 0.5
    vo_sigma_m: float = 0.015
    vo_scale_sigma: float = 0.007
    vo_gate_sigmas: float = 3.0
    stereo: StereoConfig = dc.field(default_factory=StereoConfig)
    vo: VoConfig = dc.field(default_factory=lambda: VoConfig(max_rmse_m=0.08))
    map: ElevationMapConfig = dc.field(default_factory=lambda: ElevationMapConfig(min_views=3))

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("processing_s", self.processing_s, 0.0, 3600.0, unit=" s")
        check_range("keyframe_m", self.keyframe_m, 0.0, 100.0, unit=" m")
        check_range("keyframe_deg", self.keyframe_deg, 0.0, 180.0, unit=" deg")
        check_range("max_range_m", self.max_range_m, 1.0, 100.0, unit=" m")
        check_range("gimbal_settle_s", self.gimbal_settle_s, 0.0, 600.0, unit=" s")
        check_range("prior_gate_m", self.prior_gate_m, 0.01, 100.0, unit=" m")
        check_range("self_radius_m", self.self_radius_m, 0.0, 20.0, unit=" m")
        check_range("window_m", self.window_m, 2.0 * self.max_range_m, 1000.0, unit=" m")
        check_range("cloud_voxel_m", self.cloud_voxel_m, 0.0, 10.0, unit=" m")
        check_range("odom_sigma_fraction", self.odom_sigma_fraction, 0.0, 1.0)
        check_range("odom_sigma_min_m", self.odom_sigma_min_m, 1e-6, 10.0, unit=" m")
        check_range("odom_sigma_per_rad_m", self.odom_sigma_per_rad_m, 0.0, 100.0, unit=" m/rad")
        check_range("vo_sigma_m", self.vo_sigma_m, 1e-6, 10.0, unit=" m")
        check_range("vo_scale_sigma", self.vo_scale_sigma, 0.0, 1.0)
        check_range("vo_gate_sigmas", self.vo_gate_sigmas, 0.0, 1e6, lo_open=True)
        self.stereo.validate()
        self.vo.validate()
        self.map.validate()


@dc.dataclass(frozen=True)
class KeyframeRecord:
    """One processed keyframe: capture time ``t_capture_s``, ``frame_index``, stereo
    points kept, VO outcome (``vo``: ``none`` first keyframe / ``accepted`` /
    ``rejected`` (by its own quality) / ``gated`` (too far from the on-board step) /
    ``off``, ``reason``, ``fitness``, ``inlier_rmse_m``, ``condition``),
    the on-board and VO translations between keyframes (m) and how far they differ
    (``vo_minus_odom_m``), the ground's pose (x, y, yaw; m, rad), its position sigma
    since the first keyframe (``sigma_m``, per axis), the lethal cells the map added
    (``new_lethal``) and the correction from then on (on-board pose -> ground pose, a
    planar map ``p' = Rz(yaw) p + (x, y)``: ``correction_x_m``, ``correction_y_m``,
    ``correction_yaw_rad``); for scoring: the fraction of pixels with a valid disparity
    (``valid_fraction``), VO's translation from the previous keyframe's camera frame to
    this one's (``vo_tx_m``, ``vo_ty_m``, ``vo_tz_m``, in the previous camera frame;
    NaN without VO) and the mast's pan and tilt in the frame's header (rad)."""

    t_capture_s: float
    frame_index: int
    points: int
    vo: str
    reason: str
    fitness: float
    inlier_rmse_m: float
    condition: float
    odom_step_m: float
    vo_step_m: float
    vo_minus_odom_m: float
    x_m: float
    y_m: float
    yaw_rad: float
    sigma_m: float
    new_lethal: int
    correction_x_m: float = 0.0
    correction_y_m: float = 0.0
    correction_yaw_rad: float = 0.0
    valid_fraction: float = math.nan
    vo_tx_m: float = math.nan
    vo_ty_m: float = math.nan
    vo_tz_m: float = math.nan
    pan_rad: float = math.nan
    tilt_rad: float = math.nan


@dc.dataclass(frozen=True, eq=False)
class KeyframeCloud:
    """The stereo points the ground mapped from one keyframe (capture time
    ``t_capture_s``, ``frame_index``): ``points_W`` (N, 3) float32, m, in the site frame
    placed with the ground's camera pose ``X_WC_ground`` (never truth), one per
    ``cloud_voxel_m`` voxel (:func:`voxel_downsample`). Read-only (shared by state copies)."""

    t_capture_s: float
    frame_index: int
    points_W: np.ndarray


@dc.dataclass(frozen=True)
class PerceptionState:
    """What the ground's perception holds between frames (immutable; shared, not
    copied, by Drake's state copies)."""

    last_seq: int = -1
    key_cloud: np.ndarray | None = None
    key_intensity: np.ndarray | None = None
    key_X_WC_onboard: np.ndarray | None = None
    key_X_WC_ground: np.ndarray | None = None
    key_var_m2: float = 0.0
    key_sys_xy: tuple = (0.0, 0.0)
    correction: np.ndarray = dc.field(default_factory=lambda: np.eye(4))
    emap: object = None
    costmap: object = None
    version: int = 0
    records: Ledger = dc.field(default_factory=Ledger)
    #: The keyframes' mapped points (:class:`KeyframeCloud`; none with ``cloud_voxel_m``
    #: 0), for the run's record.
    clouds: Ledger = dc.field(default_factory=Ledger)
    #: Per costmap cell, the capture time (s) of the keyframe whose stereo first made it
    #: lethal (NaN: never); for scoring the hazard detection range.
    first_lethal_s: np.ndarray | None = None

    def __deepcopy__(self, memo):
        return self

    @property
    def sigma_m(self) -> float:
        """The ground's position sigma (m, per axis) since the first keyframe: the
        random and the systematic parts (:class:`PerceptionConfig` ``vo_scale_sigma``)."""
        return math.hypot(math.sqrt(self.key_var_m2), math.hypot(*self.key_sys_xy))


def pose_matrix(pose6) -> np.ndarray:
    """4 x 4 ``X_WB`` from (x, y, z, roll, pitch, yaw) (m, rad; R = Rz Ry Rx)."""
    x, y, z, r, p, w = (float(v) for v in pose6)
    cr, sr, cp, sp, cw, sw = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(w), \
        math.sin(w)  # fmt: skip
    X = np.eye(4)
    X[:3, :3] = np.array([
        [cw * cp, cw * sp * sr - sw * cr, cw * sp * cr + sw * sr],
        [sw * cp, sw * sp * sr + cw * cr, sw * sp * cr - cw * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip
    X[:3, 3] = (x, y, z)
    return X


def planar_correction(correction) -> tuple[float, float, float]:
    """(dx, dy, dyaw) of a correction matrix as a planar map: ``p' = Rz(dyaw) p + d``."""
    C = np.asarray(correction, np.float64)
    dyaw = math.atan2(C[1, 0], C[0, 0])
    return float(C[0, 3]), float(C[1, 3]), dyaw


def innovation(t_odom, t_vo) -> tuple[float, float]:
    """How far a VO translation ``t_vo`` is from the on-board one ``t_odom`` (3,; m) in
    the ways slip cannot explain, and the slip it shows: (excess m, slip m).

    Wheels that slip turn more than the rover moves, so the odometry over-reads along
    its own direction: VO shorter than it along that direction, down to standing still,
    is slip (``slip`` = the shortfall) and no innovation; VO longer, VO past standing
    still (backwards) or across the direction of travel is (``excess``: the norm of
    those parts). Measured on the orbital-map autonomy runs: a rover stuck on a crater
    rim read 0.93 / 0.86 / 0.72 m on its wheels where VO (and truth) said 0.67 / 0.56 /
    0.33 m; a symmetric gate threw those VO steps out and the ground ended 1.7 m off."""
    to = np.asarray(t_odom, np.float64)
    d = np.asarray(t_vo, np.float64) - to
    n = float(np.linalg.norm(to))
    if n < 1e-9:
        return float(np.linalg.norm(d)), 0.0
    u = to / n
    along = float(d @ u)
    perp = float(np.linalg.norm(d - along * u))
    slip = min(max(-along, 0.0), n)
    beyond = along if along > 0.0 else max(-along - n, 0.0)
    return math.hypot(beyond, perp), slip


def fuse_translation(t_odom, t_vo, *, sigma_odom_m: float, sigma_vo_m: float) -> np.ndarray:
    """Inverse-variance mean of two translation estimates (isotropic sigmas, m)."""
    wo, wv = 1.0 / sigma_odom_m**2, 1.0 / sigma_vo_m**2
    return (wo * np.asarray(t_odom, np.float64) + wv * np.asarray(t_vo, np.float64)) / (wo + wv)


def voxel_downsample(points, *, voxel_m: float) -> np.ndarray:
    """One point per occupied ``voxel_m`` cube (m; a grid aligned with the points'
    frame origin): the centroid of its points. ``points`` (N, 3; m), non-finite rows
    dropped; returns (M, 3) float32 sorted by voxel index (x, then y, then z), empty
    when ``voxel_m`` <= 0. Deterministic: the same points in the same order give the same
    bytes."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    if not voxel_m > 0.0 or not len(p):
        return np.empty((0, 3), np.float32)
    k = np.floor(p / voxel_m).astype(np.int64)
    k -= k.min(axis=0)
    span = k.max(axis=0) + 1
    # one key in (x, y, z) order; a stable sort keeps the input's order inside a voxel
    key = (k[:, 0] * span[1] + k[:, 1]) * span[2] + k[:, 2]
    order = np.argsort(key, kind="stable")
    key, p = key[order], p[order]
    new = np.ones(len(key), bool)
    new[1:] = key[1:] != key[:-1]
    group = np.cumsum(new) - 1
    n = np.bincount(group)
    sums = np.stack([np.bincount(group, p[:, i], len(n)) for i in range(3)], axis=1)
    return (sums / n[:, None]).astype(np.float32)


def _moved(X0, X1) -> tuple[float, float]:
    D = np.linalg.inv(X0) @ X1
    c = max(-1.0, min(1.0, 0.5 * (np.trace(D[:3, :3]) - 1.0)))
    return float(np.linalg.norm(D[:3, 3])), math.degrees(math.acos(c))


def _recentred(emap, centre_xy, *, window_m: float, cell_m: float):
    """``emap`` (or a new one) covering ``centre_xy``: re-centred when the point lies
    within a quarter window of an edge (the overlap copied over)."""
    from lunar_drake.perception.elevation_map import ElevationMap

    n = round(window_m / cell_m)
    x, y = float(centre_xy[0]), float(centre_xy[1])
    if emap is not None:
        half = 0.25 * window_m
        x0, y1 = emap.x0_m, emap.y1_m
        if x0 + half <= x <= x0 + window_m - half and y1 - window_m + half <= y <= y1 - half:
            return emap
    # snap the new origin to the cell grid so cells stay aligned
    x0 = math.floor((x - 0.5 * window_m) / cell_m) * cell_m
    y1 = math.floor((y + 0.5 * window_m) / cell_m) * cell_m
    new = ElevationMap.empty(x0_m=x0, y1_m=y1, cell_m=cell_m, shape=(n, n))
    if emap is None:
        return new
    dc_ = round((emap.x0_m - x0) / cell_m)
    dr = round((y1 - emap.y1_m) / cell_m)
    r0, r1 = max(0, dr), min(n, dr + emap.shape[0])
    c0, c1 = max(0, dc_), min(n, dc_ + emap.shape[1])
    if r0 >= r1 or c0 >= c1:
        return new
    fields = {}
    for f in dc.fields(new):
        a = getattr(new, f.name)
        if isinstance(a, np.ndarray) and a.shape[:2] == (n, n):
            a = a.copy()
            a[r0:r1, c0:c1] = getattr(emap, f.name)[r0 - dr : r1 - dr, c0 - dc_ : c1 - dc_]
            fields[f.name] = a
    return dc.replace(new, **fields)


def perception_step(
    state: PerceptionState, frames, *, calib, camera_in_chassis, decode, prior, rover,
    hazards, config: PerceptionConfig,
) -> PerceptionState:  # fmt: skip
    """Handles ``frames`` ((seq, StereoFrame), ...; those with seq <= ``last_seq`` are
    skipped) and returns the new state.

    ``calib``: the rig's :class:`~lunar_drake.perception.calibration.StereoCalibration`;
    ``camera_in_chassis(pan, tilt)`` -> ``X_BC`` (4 x 4); ``decode(encoded)`` -> raw
    frame; ``prior``: the a-priori DEM (:class:`~lunar_drake.perception.
    elevation_map.PriorDem`) or None; ``rover``, ``hazards``: as the costmap's.
    ``state.costmap`` must hold the a-priori costmap before the first frame.
    """
    from lunar_drake.perception.elevation_map import (
        fuse,
        merge_into_costmap,
        points_to_world,
        stereo_hazards,
    )
    from lunar_drake.perception.stereo import match
    from lunar_drake.perception.vo import ViewFrustum, align

    s = state
    frustum = ViewFrustum.from_calibration(calib, max_range_m=config.max_range_m)
    map_cfg = dc.replace(config.map, focal_px=calib.focal_px, baseline_m=calib.baseline_m)
    self_r = config.self_radius_m or (
        0.5 * rover.wheelbase_m + rover.wheel_radius_m + rover.footprint_radius_m
    )
    for seq, frame in frames:
        if seq <= s.last_seq:
            continue
        s = dc.replace(s, last_seq=seq)
        pose = np.asarray(frame.pose_estimate, np.float64)
        pan_tilt = np.asarray(frame.pan_tilt_rad, np.float64)
        if not (np.isfinite(pose).all() and np.isfinite(pan_tilt).all()):
            continue  # a frame without its header state cannot be placed
        if frame.gimbal_steady_s < config.gimbal_settle_s:
            continue  # the mast was moving: the camera pose is not known
        X_WC_onboard = pose_matrix(pose) @ camera_in_chassis(*pan_tilt)
        first = s.key_X_WC_onboard is None
        if not first:
            dist, turn = _moved(s.key_X_WC_onboard, X_WC_onboard)
            if dist < config.keyframe_m and turn < config.keyframe_deg:
                continue
        res = match(decode(frame.left), decode(frame.right), calib=calib, config=config.stereo)
        near = res.valid & (res.points[..., 2] <= config.max_range_m)
        cloud = res.points[near]
        intensity = res.left_8bit[near].astype(np.float64) / 255.0
        vo, reason, fit, rmse, cond = "none", "", math.nan, math.nan, math.nan
        odom_step = vo_step = diff = math.nan
        vo_t = (math.nan, math.nan, math.nan)
        var, sys_xy = s.key_var_m2, s.key_sys_xy
        if first:
            X_WC_ground = s.correction @ X_WC_onboard
        else:
            T_odom = np.linalg.inv(s.key_X_WC_onboard) @ X_WC_onboard
            T = T_odom.copy()
            odom_step = float(np.linalg.norm(T_odom[:3, 3]))
            turn_rad = math.radians(_moved(s.key_X_WC_onboard, X_WC_onboard)[1])
            sig_o = (config.odom_sigma_fraction * odom_step + config.odom_sigma_per_rad_m * turn_rad
                     + config.odom_sigma_min_m)  # fmt: skip
            step_var = sig_o**2
            if config.use_vo:
                al = align(s.key_cloud, cloud, init_T=T_odom, config=config.vo,
                           prev_intensity=s.key_intensity, curr_intensity=intensity,
                           frustum=frustum)  # fmt: skip
                fit, rmse, cond, reason = al.fitness, al.inlier_rmse_m, al.condition, al.reason
                vo_step = float(np.linalg.norm(al.T_prev_curr[:3, 3]))
                vo_t = tuple(float(v) for v in al.T_prev_curr[:3, 3])
                diff = float(np.linalg.norm(al.T_prev_curr[:3, 3] - T_odom[:3, 3]))
                gate = config.vo_gate_sigmas * math.hypot(sig_o, config.vo_sigma_m)
                excess, slip = innovation(T_odom[:3, 3], al.T_prev_curr[:3, 3])
                if al.rejected:
                    vo = "rejected"
                elif excess > gate:
                    vo, reason = "gated", f"{excess:.3f} m from the on-board step > {gate:.3f} m"
                else:
                    vo = "accepted"
                    sig_slip = math.hypot(sig_o, slip)  # the odometry missed that slip
                    T[:3, 3] = fuse_translation(T_odom[:3, 3], al.T_prev_curr[:3, 3],
                                                sigma_odom_m=sig_slip,
                                                sigma_vo_m=config.vo_sigma_m)  # fmt: skip
                    step_var = 1.0 / (1.0 / sig_slip**2 + 1.0 / config.vo_sigma_m**2)
                    # A scale error moves the pose along the net displacement: the
                    # systematic part adds as a vector (it cancels on a return leg).
                    d_W = s.key_X_WC_ground[:3, :3] @ T[:3, 3]
                    sys_xy = (sys_xy[0] + config.vo_scale_sigma * float(d_W[0]),
                              sys_xy[1] + config.vo_scale_sigma * float(d_W[1]))  # fmt: skip
            else:
                vo = "off"
            X_WC_ground = s.key_X_WC_ground @ T
            var = s.key_var_m2 + step_var  # independent steps: variances add
        correction = X_WC_ground @ np.linalg.inv(X_WC_onboard)
        # Mapping in the ground's frame.
        p_W = points_to_world(res.points[res.valid], X_WC_ground)  # the map: its own range
        X_WB_ground = correction @ pose_matrix(pose)
        p_W = p_W[np.hypot(p_W[:, 0] - X_WB_ground[0, 3], p_W[:, 1] - X_WB_ground[1, 3]) > self_r]
        if prior is not None and len(p_W):
            dev = p_W[:, 2] - prior.sample(p_W[:, 0], p_W[:, 1])
            p_W = p_W[np.abs(dev - np.median(dev)) <= config.prior_gate_m]
        clouds = s.clouds
        if config.cloud_voxel_m > 0.0:  # the record: what fuse() takes (its range limits)
            r = np.linalg.norm(p_W - X_WC_ground[:3, 3], axis=1)
            pts = voxel_downsample(p_W[(r >= map_cfg.min_range_m) & (r <= map_cfg.max_range_m)],
                                   voxel_m=config.cloud_voxel_m)  # fmt: skip
            pts.flags.writeable = False  # shared by the state's copies
            clouds = clouds.append(KeyframeCloud(t_capture_s=float(frame.t_capture_s),
                                                 frame_index=int(frame.frame_index),
                                                 points_W=pts))  # fmt: skip
        emap = _recentred(s.emap, X_WC_ground[:2, 3], window_m=config.window_m,
                          cell_m=map_cfg.cell_m)  # fmt: skip
        emap = fuse(emap, points_W=p_W, sensor_origin_W=X_WC_ground[:3, 3], config=map_cfg,
                    time_s=frame.t_capture_s)  # fmt: skip
        # Unknown cells filled from the nearest known one, not the prior: the orbital
        # DEM differs from stereo by more than a step at the edges of what was seen.
        haz = stereo_hazards(emap, hazards=hazards, rover=rover, config=map_cfg)
        costmap = merge_into_costmap(s.costmap, stereo=haz, rover=rover, hazards=hazards)
        # Cells stereo made lethal (confirming steep orbital cells may clear others).
        newly = costmap.lethal_raw & ~s.costmap.lethal_raw
        new_lethal = int(np.count_nonzero(newly))
        first_lethal = s.first_lethal_s
        if first_lethal is None or first_lethal.shape != newly.shape:
            first_lethal = np.full(newly.shape, np.nan)
        if new_lethal and np.isnan(first_lethal[newly]).any():
            first_lethal = first_lethal.copy()  # the state's array is shared: copy on write
            first_lethal[newly & np.isnan(first_lethal)] = float(frame.t_capture_s)
        rec = KeyframeRecord(
            t_capture_s=float(frame.t_capture_s), frame_index=int(frame.frame_index),
            points=len(cloud), vo=vo, reason=reason, fitness=float(fit),
            inlier_rmse_m=float(rmse), condition=float(cond), odom_step_m=odom_step,
            vo_step_m=vo_step, vo_minus_odom_m=diff, x_m=float(X_WB_ground[0, 3]),
            y_m=float(X_WB_ground[1, 3]),
            yaw_rad=math.atan2(X_WB_ground[1, 0], X_WB_ground[0, 0]),
            sigma_m=math.hypot(math.sqrt(var), math.hypot(*sys_xy)), new_lethal=new_lethal,
            **dict(zip(("correction_x_m", "correction_y_m", "correction_yaw_rad"),
                       planar_correction(correction), strict=True)),
            valid_fraction=float(np.mean(res.valid)), vo_tx_m=vo_t[0], vo_ty_m=vo_t[1],
            vo_tz_m=vo_t[2], pan_rad=float(pan_tilt[0]), tilt_rad=float(pan_tilt[1]),
        )  # fmt: skip
        s = dc.replace(
            s, key_cloud=cloud, key_intensity=intensity, key_X_WC_onboard=X_WC_onboard,
            key_X_WC_ground=X_WC_ground, key_var_m2=var, key_sys_xy=sys_xy, correction=correction,
            emap=emap,
            costmap=costmap,
            version=s.version + (1 if new_lethal else 0), records=s.records.append(rec),
            clouds=clouds, first_lethal_s=first_lethal,
        )  # fmt: skip
    return s


__all__ = [
    "KeyframeCloud",
    "KeyframeRecord",
    "PerceptionConfig",
    "PerceptionState",
    "fuse_translation",
    "innovation",
    "perception_step",
    "planar_correction",
    "pose_matrix",
    "voxel_downsample",
]
