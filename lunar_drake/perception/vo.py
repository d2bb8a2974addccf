"""Visual odometry by ICP: align the point cloud of one stereo pair to the previous
one, judge the alignment, reject bad ones. Pure (numpy, scipy + Open3D).

:func:`align` runs ICP coarse to fine (``levels`` voxel sizes, ``voxel_m`` the finest,
each twice the next; correspondences within ``correspondence_voxels`` voxels) from an
initial guess (the downlinked on-board estimate's motion), point-to-plane with a Huber
robust kernel.

**Attitude from the prior** (``rotation: prior``, the default): the on-board rotation
between frames comes from the star tracker (measured 0.001-0.02 deg over the turns of
``vo-study``), a 6-DoF ICP's from a few metres of noisy stereo (0.07-0.36 deg, 2 deg in
a wrong basin), and a rotation error swings the camera about the matched terrain 5-8 m
away by 1-4 cm. So the rotation is held at the guess's and ICP solves for the
translation alone (:func:`translation_icp`: Gauss-Newton on the point-to-plane
residuals, a direction the geometry does not fix left at the guess). ``rotation: icp``
solves all six with Open3D (a rover without an attitude sensor), ``method``:

* ``point_to_plane`` (default): Open3D ``registration_icp``;
* ``colored`` (when the points' image intensities are given; ``rotation: icp`` only):
  Open3D ``registration_colored_icp`` (Park, Zhou & Koltun 2017), point-to-plane plus a
  photometric term weighted ``1 - lambda_geometric``. It pins clouds that would slide
  on smooth terrain, but the image of the ground changes as the rover moves (Hapke's
  phase and emission angles, the rover's own shadow): on the rendered 20 m straight
  drive it biased every 1 m link 2-6 cm sideways (2.1 % of the distance where
  point-to-plane with the prior made 0.3 %).

**Overlap.** Given the camera's :class:`ViewFrustum`, each cloud is first cropped to
what the other camera saw under the guess (its frustum shrunk by
``overlap_margin_deg``): points the other view cannot contain only find false
correspondences at its edges, which pulled large turns off, and the fitness then
measures the overlap, not the turn.

Quality is judged on the finest clouds with correspondences within
``max_correspondence_m``: the **fitness** (fraction of source points with a
correspondence), the **inlier RMSE** and the **conditioning** of the point-to-plane
information matrix (:func:`point_to_plane_information`: ``sum J^T J`` with ``J = [(p x
n)^T, n^T]`` over the correspondences, rotations about their centroid in units of their
RMS radius; with the attitude prior only its translation block ``sum n n^T``; infinite
when the geometry leaves a motion unconstrained -- a flat plane cannot fix a slide
along it; Open3D's own ``get_information_matrix_from_point_clouds`` is point-to-point
and would not see it). An alignment is rejected when one of them is out of bounds or
when it moved the guess further than ``max_correction_m`` / ``max_correction_deg`` (ICP
caught in a wrong basin).

Frames: ``T_prev_curr`` (4 x 4) maps points of the current camera frame into the
previous one (the camera's motion between the two, expressed in the previous frame).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import ConfigError, check_range

METHODS = ("colored", "point_to_plane")
ROTATIONS = ("prior", "icp")


@dc.dataclass(frozen=True)
class ViewFrustum:
    """What a camera sees, in its frame (x right, y down, z forward): ``|x / z| <=
    tan_half_x``, ``|y / z| <= tan_half_y`` and ``min_range_m <= z <= max_range_m``."""

    tan_half_x: float
    tan_half_y: float
    max_range_m: float
    min_range_m: float = 0.1

    @classmethod
    def from_calibration(cls, calib, *, max_range_m: float) -> "ViewFrustum":
        """The left camera of a :class:`~lunar_drake.perception.calibration.
        StereoCalibration` (its pixel grid through ``K_left``), out to ``max_range_m``."""
        K = np.asarray(calib.K_left, np.float64)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        return cls(
            tan_half_x=float(max(cx + 0.5, calib.width - 0.5 - cx) / fx),
            tan_half_y=float(max(cy + 0.5, calib.height - 0.5 - cy) / fy),
            max_range_m=float(max_range_m),
        )

    def contains(self, points, *, margin_deg: float = 0.0) -> np.ndarray:
        """(N,) bool: which of ``points`` (N, 3; m, camera frame) lie inside, with the
        half-angles shrunk by ``margin_deg``."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        m = math.radians(margin_deg)
        tx = math.tan(max(math.atan(self.tan_half_x) - m, 0.0))
        ty = math.tan(max(math.atan(self.tan_half_y) - m, 0.0))
        z = p[:, 2]
        zs = np.where(z > 0.0, z, 1.0)
        return ((z >= self.min_range_m) & (z <= self.max_range_m)
                & (np.abs(p[:, 0]) <= tx * zs) & (np.abs(p[:, 1]) <= ty * zs))  # fmt: skip


@dc.dataclass
class VoConfig:
    """ICP visual odometry settings.

    Attributes:
        method: ``colored`` or ``point_to_plane`` (module docstring).
        voxel_m: voxel size of the finest downsampling (m).
        levels: coarse-to-fine levels (voxel sizes ``voxel_m * 2**k``).
        correspondence_voxels: correspondence distance at each level (voxels).
        lambda_geometric: weight of the geometric term in ``colored`` (0..1].
        max_correspondence_m: correspondence distance of the quality measures (m).
        iterations: ICP iterations at most, per level.
        huber_m: Huber kernel width (m).
        normal_radius_m: neighbourhood for the normals (m).
        min_fitness: reject below this fitness.
        max_rmse_m: reject above this inlier RMSE (m).
        max_condition: reject above this information-matrix condition number (the
            geometric one, its translation block with ``rotation: prior``; not with
            ``colored``, whose texture constrains what the geometry leaves free,
            measured: 5 mm on a textured plane whose geometric condition is 1e6).
        max_correction_m, max_correction_deg: reject when ICP moved the initial guess
            further (m, deg).
        overlap_margin_deg: with a :class:`ViewFrustum`, each cloud is cropped to the
            other camera's view shrunk by this much (deg; module docstring).
        rotation: ``prior`` (the guess's rotation kept, ICP for the translation alone)
            or ``icp`` (all six; module docstring).
    """

    method: str = "point_to_plane"
    voxel_m: float = 0.025
    levels: int = 2
    correspondence_voxels: float = 2.0
    lambda_geometric: float = 0.968
    max_correspondence_m: float = 0.2
    iterations: int = 30
    huber_m: float = 0.05
    normal_radius_m: float = 0.15
    min_fitness: float = 0.3
    max_rmse_m: float = 0.05
    max_condition: float = 1.0e3
    max_correction_m: float = 1.0
    max_correction_deg: float = 10.0
    overlap_margin_deg: float = 3.0
    rotation: str = "prior"

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        if self.method not in METHODS:
            raise ConfigError(f"method = {self.method!r} is unknown; choose one of {METHODS}")
        check_range("voxel_m", self.voxel_m, 0.001, 10.0, unit=" m")
        check_range("levels", self.levels, 1, 8)
        check_range("correspondence_voxels", self.correspondence_voxels, 0.5, 100.0)
        check_range("lambda_geometric", self.lambda_geometric, 0.0, 1.0, lo_open=True)
        check_range("max_correspondence_m", self.max_correspondence_m, 0.001, 100.0, unit=" m")
        check_range("iterations", self.iterations, 1, 10000)
        check_range("huber_m", self.huber_m, 0.0001, 10.0, unit=" m")
        check_range("normal_radius_m", self.normal_radius_m, 0.001, 100.0, unit=" m")
        check_range("min_fitness", self.min_fitness, 0.0, 1.0)
        check_range("max_rmse_m", self.max_rmse_m, 0.0, 100.0, lo_open=True, unit=" m")
        check_range("max_condition", self.max_condition, 1.0, 1.0e30)
        check_range("max_correction_m", self.max_correction_m, 0.0, 1000.0, lo_open=True,
                    unit=" m")  # fmt: skip
        check_range("max_correction_deg", self.max_correction_deg, 0.0, 180.0, lo_open=True,
                    unit=" deg")  # fmt: skip
        check_range("overlap_margin_deg", self.overlap_margin_deg, 0.0, 45.0, unit=" deg")
        if self.rotation not in ROTATIONS:
            raise ConfigError(f"rotation = {self.rotation!r} is unknown; choose one of {ROTATIONS}")
        if self.method == "colored" and self.rotation == "prior":
            raise ConfigError("method = 'colored' estimates the rotation too; use it with "
                              "rotation: icp")  # fmt: skip


@dc.dataclass(frozen=True)
class Alignment:
    """One ICP alignment: ``T_prev_curr`` (4 x 4), ``fitness``, ``inlier_rmse_m``,
    ``condition`` (of the information matrix), ``information`` (6 x 6), ``rejected``
    and why (``reason``, "" when accepted), the points used (``n_source``,
    ``n_target``)."""

    T_prev_curr: np.ndarray
    fitness: float
    inlier_rmse_m: float
    condition: float
    information: np.ndarray
    rejected: bool
    reason: str
    n_source: int
    n_target: int


def _cloud(points, intensity=None, keep=None):
    import open3d as o3d

    p = np.asarray(points, np.float64).reshape(-1, 3)
    ok = np.isfinite(p).all(axis=1)
    if keep is not None:
        ok &= keep
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p[ok]))
    if intensity is not None:
        g = np.asarray(intensity, np.float64).reshape(-1)
        if g.shape[0] != p.shape[0]:
            raise ConfigError(f"{g.shape[0]} intensities for {p.shape[0]} points")
        pc.colors = o3d.utility.Vector3dVector(np.repeat(np.clip(g[ok], 0.0, 1.0)[:, None], 3, 1))
    return pc


def point_to_plane_information(points, target_points, target_normals, max_dist_m: float,
                               *, normalized: bool = False):  # fmt: skip
    """The 6 x 6 information matrix ``sum J^T J`` of a point-to-plane alignment, with
    ``J = [(p x n)^T, n^T]`` (rotation first) for each of ``points`` (N, 3) whose
    nearest target point lies within ``max_dist_m``, ``n`` that point's normal.
    ``normalized``: rotations about the matched points' centroid, in units of their RMS
    radius about it (so the conditioning compares metres with metres and does not grow
    with the range of the cloud)."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float64)
    tree = cKDTree(np.asarray(target_points, np.float64))
    d, k = tree.query(p, distance_upper_bound=max_dist_m, workers=-1)  # same answer, 2 cores
    ok = np.isfinite(d)
    if not ok.any():
        return np.zeros((6, 6))
    n = np.asarray(target_normals, np.float64)[k[ok]]
    q = p[ok]
    if normalized:
        q = q - q.mean(axis=0)
        q = q / max(float(np.sqrt(np.mean(np.sum(q * q, axis=1)))), 1e-9)
    J = np.hstack([np.cross(q, n), n])
    return J.T @ J


def correction(T_a, T_b) -> tuple[float, float]:
    """(translation m, rotation deg) between two rigid transforms (4 x 4)."""
    D = np.linalg.inv(np.asarray(T_a)) @ np.asarray(T_b)
    c = max(-1.0, min(1.0, 0.5 * (np.trace(D[:3, :3]) - 1.0)))
    return float(np.linalg.norm(D[:3, 3])), math.degrees(math.acos(c))


def translation_icp(src, tgt, tgt_normals, *, init_T, max_dist_m: float, huber_m: float,
                    iterations: int):  # fmt: skip
    """Point-to-plane ICP for the translation alone, the rotation held at ``init_T``'s:
    ``src`` (N, 3) in the current frame onto ``tgt`` (M, 3) with ``tgt_normals``, nearest
    neighbours within ``max_dist_m``, Huber weights (``huber_m``), Gauss-Newton steps
    ``(sum w n n^T) dt = -sum w r n`` solved by least squares (a direction the geometry
    does not fix is not moved: a plane corrects only its normal). Returns the 4 x 4
    ``T_prev_curr``, or None with fewer than 6 correspondences."""
    from scipy.spatial import cKDTree

    T = np.array(init_T, np.float64)
    tgt = np.asarray(tgt, np.float64)
    n_all = np.asarray(tgt_normals, np.float64)
    p = np.asarray(src, np.float64) @ T[:3, :3].T
    t = T[:3, 3].copy()
    tree = cKDTree(tgt)
    for _ in range(iterations):
        d, k = tree.query(p + t, distance_upper_bound=max_dist_m, workers=-1)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            return None
        n = n_all[k[ok]]
        r = np.einsum("ij,ij->i", n, p[ok] + t - tgt[k[ok]])
        a = np.abs(r)
        w = np.where(a <= huber_m, 1.0, huber_m / np.maximum(a, 1e-300))
        nw = n * w[:, None]
        step = np.linalg.lstsq(nw.T @ n, -(nw.T @ r), rcond=1e-6)[0]
        t += step
        if float(np.linalg.norm(step)) < 1e-6:
            break
    T[:3, 3] = t
    return T


def overlap_masks(prev_points, curr_points, *, init_T, frustum: ViewFrustum,
                  margin_deg: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(prev mask, curr mask): the points of each cloud that the other camera saw under
    ``init_T`` (``T_prev_curr``), its ``frustum`` shrunk by ``margin_deg``."""
    T = np.asarray(init_T, np.float64)
    prev = np.asarray(prev_points, np.float64).reshape(-1, 3)
    curr = np.asarray(curr_points, np.float64).reshape(-1, 3)
    Ti = np.linalg.inv(T)
    in_curr = frustum.contains(prev @ Ti[:3, :3].T + Ti[:3, 3], margin_deg=margin_deg)
    in_prev = frustum.contains(curr @ T[:3, :3].T + T[:3, 3], margin_deg=margin_deg)
    return in_curr, in_prev


def align(prev_points, curr_points, *, init_T=None, config: VoConfig | None = None,
          prev_intensity=None, curr_intensity=None,
          frustum: ViewFrustum | None = None) -> Alignment:  # fmt: skip
    """Aligns ``curr_points`` (N, 3; m, current camera frame) to ``prev_points`` (M, 3;
    previous frame) from ``init_T`` (4 x 4 guess of ``T_prev_curr``; identity if None).
    ``prev_intensity`` / ``curr_intensity`` (M,) / (N,): the points' image values (0..1)
    for the ``colored`` method. ``frustum``: the camera's view, to crop both clouds to
    their overlap under the guess (None: no cropping)."""
    import open3d as o3d

    cfg = config or VoConfig()
    cfg.validate()
    reg = o3d.pipelines.registration
    init = np.eye(4) if init_T is None else np.asarray(init_T, np.float64)
    colored = cfg.method == "colored" and prev_intensity is not None and curr_intensity is not None
    keep_prev = keep_curr = None
    if frustum is not None:
        keep_prev, keep_curr = overlap_masks(prev_points, curr_points, init_T=init,
                                             frustum=frustum,
                                             margin_deg=cfg.overlap_margin_deg)  # fmt: skip
    src_full = _cloud(curr_points, curr_intensity if colored else None, keep_curr)
    tgt_full = _cloud(prev_points, prev_intensity if colored else None, keep_prev)
    src = src_full.voxel_down_sample(cfg.voxel_m)
    tgt = tgt_full.voxel_down_sample(cfg.voxel_m)
    ns, nt = len(src.points), len(tgt.points)
    if ns < 10 or nt < 10:
        where = " in the overlap" if frustum is not None else ""
        return Alignment(init, 0.0, math.inf, math.inf, np.zeros((6, 6)), True,
                         f"too few points{where} ({ns}, {nt})", ns, nt)  # fmt: skip
    T = init
    prior = cfg.rotation == "prior"
    for level in reversed(range(cfg.levels)):
        vox = cfg.voxel_m * 2**level
        s_ = src if level == 0 else src_full.voxel_down_sample(vox)
        t_ = tgt if level == 0 else tgt_full.voxel_down_sample(vox)
        if len(s_.points) < 10 or len(t_.points) < 10:
            continue
        radius = max(cfg.normal_radius_m, 3.0 * vox)
        search = o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30)
        t_.estimate_normals(search)
        dist = cfg.correspondence_voxels * vox
        if prior:
            T_new = translation_icp(np.asarray(s_.points), np.asarray(t_.points),
                                    np.asarray(t_.normals), init_T=T, max_dist_m=dist,
                                    huber_m=cfg.huber_m, iterations=cfg.iterations)  # fmt: skip
            if T_new is None:
                return Alignment(T, 0.0, math.inf, math.inf, np.zeros((6, 6)), True,
                                 "ICP failed: too few correspondences", ns, nt)  # fmt: skip
            T = T_new
            continue
        crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6,
                                          max_iteration=cfg.iterations)  # fmt: skip
        try:
            if colored:
                s_.estimate_normals(search)
                est = reg.TransformationEstimationForColoredICP(
                    lambda_geometric=cfg.lambda_geometric, kernel=reg.HuberLoss(k=cfg.huber_m)
                )
                r = reg.registration_colored_icp(s_, t_, dist, T, est, crit)
            else:
                est = reg.TransformationEstimationPointToPlane(reg.HuberLoss(k=cfg.huber_m))
                r = reg.registration_icp(s_, t_, dist, T, est, crit)
        except RuntimeError as exc:  # Open3D: no correspondences at this level
            return Alignment(T, 0.0, math.inf, math.inf, np.zeros((6, 6)), True,
                             f"ICP failed: {str(exc).splitlines()[0][-80:]}", ns, nt)  # fmt: skip
        T = np.asarray(r.transformation)
    if not tgt.has_normals():
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.normal_radius_m,
                                                                  max_nn=30))  # fmt: skip
    result = reg.evaluate_registration(src, tgt, cfg.max_correspondence_m, T)
    moved = np.asarray(src.points) @ T[:3, :3].T + T[:3, 3]
    info = point_to_plane_information(
        moved,
        np.asarray(tgt.points),
        np.asarray(tgt.normals),
        cfg.max_correspondence_m,
        normalized=True,
    )
    # With the rotation given, only the translation block must be well posed.
    ev = np.linalg.eigvalsh(info[3:, 3:] if prior else info)
    cond = float(ev[-1] / ev[0]) if ev[0] > 1e-12 * max(ev[-1], 1e-300) else math.inf
    dt, dr = correction(init, T)
    reason = ""
    if result.fitness < cfg.min_fitness:
        reason = f"fitness {result.fitness:.2f} < {cfg.min_fitness:g}"
    elif result.inlier_rmse > cfg.max_rmse_m:
        reason = f"inlier RMSE {result.inlier_rmse:.3f} m > {cfg.max_rmse_m:g} m"
    elif cond > cfg.max_condition and not colored:
        reason = f"degenerate geometry (information condition {cond:.3g})"
    elif dt > cfg.max_correction_m or dr > cfg.max_correction_deg:
        reason = f"moved the guess {dt:.2f} m, {dr:.1f} deg"
    return Alignment(
        T_prev_curr=T,
        fitness=float(result.fitness),
        inlier_rmse_m=float(result.inlier_rmse),
        condition=cond,
        information=info,
        rejected=bool(reason),
        reason=reason,
        n_source=ns,
        n_target=nt,
    )


__all__ = ["METHODS", "ROTATIONS", "Alignment", "ViewFrustum", "VoConfig", "align", "correction",
           "overlap_masks", "point_to_plane_information", "translation_icp"]  # fmt: skip
