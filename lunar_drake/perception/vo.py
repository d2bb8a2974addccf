"""Visual odometry by ICP: align the point cloud of one stereo pair to the previous
one with Open3D, judge the alignment, reject bad ones. Pure (numpy + Open3D).

:func:`align` runs ICP coarse to fine (``levels`` voxel sizes, ``voxel_m`` the finest,
each twice the next; correspondences within ``correspondence_voxels`` voxels) from an
initial guess (the downlinked on-board estimate's motion), with a Huber robust kernel:

* ``method: point_to_plane``: Open3D ``registration_icp``, point-to-plane;
* ``method: colored`` (default, when the points' image intensities are given): Open3D
  ``registration_colored_icp`` (Park, Zhou & Koltun 2017): point-to-plane plus a
  photometric term, the intensity gradient on each point's tangent plane, weighted
  ``1 - lambda_geometric``. On smooth terrain the geometric term alone lets the clouds
  slide along the ground (measured: errors of metres at 30-40 deg turns); the
  regolith's texture pins them. Without intensities, point-to-plane.

Quality is then judged on the finest clouds with correspondences within
``max_correspondence_m``, whatever the method: the **fitness**
(fraction of source points with a correspondence), the **inlier RMSE** and the
**conditioning** of the 6 x 6 point-to-plane information matrix of the alignment
(:func:`point_to_plane_information`: ``sum J^T J`` with ``J = [(p x n)^T, n^T]`` over
the correspondences, rotations about their centroid in units of their RMS radius;
infinite when the geometry leaves a motion unconstrained -- a flat plane cannot fix a
slide along it nor a turn about its normal; Open3D's own
``get_information_matrix_from_point_clouds`` is point-to-point and would not see it).
An alignment is rejected when one of them is out of bounds or when it moved the guess
further than ``max_correction_m`` / ``max_correction_deg`` (ICP caught in a wrong
basin).

Frames: ``T_prev_curr`` (4 x 4) maps points of the current camera frame into the
previous one (the camera's motion between the two, expressed in the previous frame).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import ConfigError, check_range

METHODS = ("colored", "point_to_plane")


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
            geometric one: point-to-plane only; with ``colored`` the texture constrains
            what the geometry leaves free, measured: 5 mm on a textured plane whose
            geometric condition is 1e6).
        max_correction_m, max_correction_deg: reject when ICP moved the initial guess
            further (m, deg).
    """

    method: str = "colored"
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


def _cloud(points, intensity=None):
    import open3d as o3d

    p = np.asarray(points, np.float64).reshape(-1, 3)
    ok = np.isfinite(p).all(axis=1)
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
    d, k = cKDTree(np.asarray(target_points, np.float64)).query(p, distance_upper_bound=max_dist_m)
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


def align(prev_points, curr_points, *, init_T=None, config: VoConfig | None = None,
          prev_intensity=None, curr_intensity=None) -> Alignment:  # fmt: skip
    """Aligns ``curr_points`` (N, 3; m, current camera frame) to ``prev_points`` (M, 3;
    previous frame) from ``init_T`` (4 x 4 guess of ``T_prev_curr``; identity if None).
    ``prev_intensity`` / ``curr_intensity`` (M,) / (N,): the points' image values (0..1)
    for the ``colored`` method."""
    import open3d as o3d

    cfg = config or VoConfig()
    cfg.validate()
    reg = o3d.pipelines.registration
    init = np.eye(4) if init_T is None else np.asarray(init_T, np.float64)
    colored = cfg.method == "colored" and prev_intensity is not None and curr_intensity is not None
    src_full = _cloud(curr_points, curr_intensity if colored else None)
    tgt_full = _cloud(prev_points, prev_intensity if colored else None)
    src = src_full.voxel_down_sample(cfg.voxel_m)
    tgt = tgt_full.voxel_down_sample(cfg.voxel_m)
    ns, nt = len(src.points), len(tgt.points)
    if ns < 10 or nt < 10:
        return Alignment(init, 0.0, math.inf, math.inf, np.zeros((6, 6)), True,
                         f"too few points ({ns}, {nt})", ns, nt)  # fmt: skip
    T = init
    for level in reversed(range(cfg.levels)):
        vox = cfg.voxel_m * 2**level
        s_ = src if level == 0 else src_full.voxel_down_sample(vox)
        t_ = tgt if level == 0 else tgt_full.voxel_down_sample(vox)
        if len(s_.points) < 10 or len(t_.points) < 10:
            continue
        radius = max(cfg.normal_radius_m, 3.0 * vox)
        search = o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30)
        t_.estimate_normals(search)
        crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6,
                                          max_iteration=cfg.iterations)  # fmt: skip
        dist = cfg.correspondence_voxels * vox
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
    ev = np.linalg.eigvalsh(info)
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


__all__ = ["METHODS", "Alignment", "VoConfig", "align", "correction", "point_to_plane_information"]
