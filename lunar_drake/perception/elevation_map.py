"""Local elevation map from stereo, and the hazards it adds to the a-priori costmap.
Pure numpy/scipy; no Drake.

Orbital maps average rover-scale rocks away (:func:`~lunar_drake.autonomy.costmap.
orbital_dem`), so the ground fuses the downlinked stereo clouds, placed in its
*estimated* world frame W, into a grid of heights and plans on the a-priori costmap
with the hazards seen in it merged in.

**Fusion** (:func:`fuse`). A point P of a cloud (``p_WP``, m) falls in the cell of its
(x, y) (row 0 north, as the costmap). Points nearer than ``min_range_m`` to the camera
(the rover itself) or farther than ``max_range_m``, and off the grid, are dropped. A
point's height error (m, 1 sigma) is the stereo error along its ray plus a floor::

    sigma(r) = sqrt((sigma_d r^2 / (f B))^2 + sigma_0^2)

with ``r`` the camera-to-point distance (m), ``sigma_d`` the disparity error (px), ``f``
the focal length (px), ``B`` the baseline (m) and ``sigma_0`` (``min_sigma_m``) the
calibration, pose and in-cell relief. The depth error ``sigma_d Z^2 / (f B)`` taken
with the range for the depth ``Z`` bounds the error along the ray (which is ``cos``
of the off-axis angle times smaller). It is used whole, not projected on the vertical:
at grazing incidence the error is mostly horizontal, but it moves the point into a
neighbour cell whose height differs by the slope times that error. **Outliers**:
within one cloud, a point further than ``max(outlier_min_m, outlier_sigmas sigma)``
from the median height of its cell's points is dropped (a mismatch; or the minority of
a cell straddling a rock edge, whose neighbours hold the rock). Each cell keeps the
sufficient statistics of the accepted points: ``W = sum 1/sigma^2``, ``sum z/sigma^2``,
``sum z^2/sigma^2``, the count, the highest point and the time of the last update, so
fusing clouds one by one equals fusing them at once (to rounding; the gate aside, which
sees one cloud at a time) and the fused height is the inverse-variance weighted mean
``h = sum(z/sigma^2) / W``. Its variance is ``1/W`` scaled by the reduced chi-square of
the points about it when that exceeds 1 (points that disagree more than their sigmas
say: relief within the cell, frames misregistered by the pose estimate). A cell is
**known** when it holds ``min_points`` points and its height sigma is at most
``max_sigma_m``.

**Hazards** (:func:`stereo_hazards`): the costmap's own definitions
(:func:`~lunar_drake.autonomy.costmap.hazard_layers`, the rover's limits) on the fused
heights, the unknown cells first filled -- from a prior DEM shifted by the median
stereo-minus-prior height of the known cells (the two maps' vertical offset: datum,
pose drift), or else by the nearest known cell -- and the layers kept on known cells
only. A known cell is *lethal* when its slope or step is over the limit. With
``tall_views`` set, a cell seen in fewer than ``min_views`` clouds (but at least
``tall_views``) counts too when its step, on the surface with it included, is over
``tall_factor`` times the limit: a rock that stands out that much is believed sooner.

**Merging** (:func:`merge_into_costmap`): each known cell goes to the planning cell
holding its centre. A planning cell takes the larger of the prior's and stereo's slope,
step and roughness, and is lethal when lethal in the prior or holding a lethal stereo
cell; lethal cells are inflated and free ones costed as in
:func:`~lunar_drake.autonomy.costmap.build_costmap`. **Stereo never clears** by default:
an orbital hazard stays lethal whatever the cameras saw. The stereo map sits in the
ground's estimated frame, which drifts from the site frame the orbital map is in (about
1 % of the distance driven), so a patch seen flat may be the ground beside the orbital
hazard; and orbital hazards are mostly real (averaging hides rocks but does not invent
slopes; its noise rarely makes one). ``stereo_clears=True`` opts in: planning cells at
least ``clear_coverage`` covered by known cells take stereo's layers and lethality alone.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np
from scipy import ndimage

from lunar_drake.autonomy.costmap import (
    Costmap,
    HazardConfig,
    RoverEnvelope,
    costmap_from_layers,
    hazard_layers,
    hazard_limits,
)
from lunar_drake.errors import ConfigError, OutOfRangeError, check_range

# The default camera (640 x 480 px, 45 deg vertical field of view) on the KREX2 mast.
_DEFAULT_FOCAL_PX = 0.5 * 480 / math.tan(math.radians(22.5))


@dc.dataclass
class ElevationMapConfig:
    """How stereo clouds are fused (see the module docstring).

    Attributes:
        cell_m: grid cell (m), (0, 10]; 0.1 = the site DEM's.
        min_range_m, max_range_m: accepted camera-to-point distances (m).
        focal_px, baseline_m: the rig's focal length (px) and baseline (m); default the
            default camera (640 x 480, 45 deg) on the KREX2 mast (0.3 m).
            :meth:`for_rig` takes them from a calibration.
        disparity_sigma_px: disparity error (px, 1 sigma), > 0.
        min_sigma_m: height error floor (m, 1 sigma), > 0: calibration, pose, relief.
        outlier_sigmas: a point further than this many sigmas (or ``outlier_min_m``)
            from its cell's median height in one cloud is dropped, > 0.
        outlier_min_m: the smallest such distance (m), >= 0.
        min_points: points a known cell holds at least, >= 1.
        min_views: clouds a known cell was seen in at least, >= 1 (wrong stereo matches
            come in patches that move with the view; rocks stay put).
        max_sigma_m: the largest height sigma of a known cell (m), > 0.
        tall_views: clouds enough for a cell whose step is over ``tall_factor`` times the
            rover's limit to count, >= 0 (0: no exception to ``min_views``): a rock that
            stands out that much is believed sooner than a low bump (one seen in shadow,
            or at the edge of the view, may be seen only once or twice).
        tall_factor: how far over the step limit such a cell must be, >= 1.
    """

    cell_m: float = 0.1
    min_range_m: float = 1.0
    max_range_m: float = 10.0
    focal_px: float = _DEFAULT_FOCAL_PX
    baseline_m: float = 0.3
    disparity_sigma_px: float = 0.25
    min_sigma_m: float = 0.01
    outlier_sigmas: float = 3.0
    outlier_min_m: float = 0.05
    min_points: int = 3
    min_views: int = 1
    max_sigma_m: float = 0.05
    tall_views: int = 0
    tall_factor: float = 1.5

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("cell_m", self.cell_m, 0.0, 10.0, lo_open=True, unit=" m")
        check_range("min_range_m", self.min_range_m, 0.0, 1000.0, unit=" m")
        check_range("max_range_m", self.max_range_m, self.min_range_m, 1000.0, lo_open=True,
                    unit=" m (above min_range_m)")  # fmt: skip
        check_range("focal_px", self.focal_px, 0.0, 1e6, lo_open=True, unit=" px")
        check_range("baseline_m", self.baseline_m, 0.0, 100.0, lo_open=True, unit=" m")
        check_range("disparity_sigma_px", self.disparity_sigma_px, 0.0, 100.0, lo_open=True,
                    unit=" px")  # fmt: skip
        check_range("min_sigma_m", self.min_sigma_m, 0.0, 10.0, lo_open=True, unit=" m")
        check_range("outlier_sigmas", self.outlier_sigmas, 0.0, 1000.0, lo_open=True)
        check_range("outlier_min_m", self.outlier_min_m, 0.0, 100.0, unit=" m")
        if isinstance(self.min_points, bool) or not isinstance(self.min_points, int | np.integer):
            raise ConfigError(f"min_points = {self.min_points!r} must be an integer")
        check_range("min_points", self.min_points, 1, 1_000_000)
        if isinstance(self.min_views, bool) or not isinstance(self.min_views, int | np.integer):
            raise ConfigError(f"min_views = {self.min_views!r} must be an integer")
        check_range("min_views", self.min_views, 1, 1_000_000)
        check_range("max_sigma_m", self.max_sigma_m, 0.0, 100.0, lo_open=True, unit=" m")
        if isinstance(self.tall_views, bool) or not isinstance(self.tall_views, int | np.integer):
            raise ConfigError(f"tall_views = {self.tall_views!r} must be an integer")
        check_range("tall_views", self.tall_views, 0, 1_000_000)
        check_range("tall_factor", self.tall_factor, 1.0, 100.0)

    @classmethod
    def for_rig(cls, calib, **overrides) -> "ElevationMapConfig":
        """With the focal length and baseline of a
        :class:`~lunar_drake.perception.calibration.StereoCalibration`."""
        return cls(focal_px=calib.focal_px, baseline_m=calib.baseline_m, **overrides)

    def height_sigma_m(self, range_m):
        """Height error (m, 1 sigma) of points ``range_m`` (m) from the camera."""
        r = np.asarray(range_m, np.float64)
        s = self.disparity_sigma_px * r * r / (self.focal_px * self.baseline_m)
        return np.sqrt(s * s + self.min_sigma_m**2)


@dc.dataclass(frozen=True)
class ElevationMap:
    """A fused elevation grid, plain arrays (an abstract state value as it is; fusing
    returns a new one). Row 0 north; ``x0_m``, ``y1_m``: site coordinates of the west
    and north edges; ``cell_m``. Per cell (rows, cols), of the accepted points: ``weight``
    ``sum 1/sigma^2`` (1/m^2), ``weighted_z`` ``sum z/sigma^2`` (1/m), ``weighted_z2``
    ``sum z^2/sigma^2`` (-), ``count``, ``z_max_m`` the highest (m; -inf if none),
    ``t_last_s`` the time of the last update (s; NaN if never), ``views`` the clouds
    that added points. 52 bytes a cell: a 100 m x 100 m window at 0.1 m is 52 MB."""

    weight: np.ndarray
    weighted_z: np.ndarray
    weighted_z2: np.ndarray
    count: np.ndarray
    z_max_m: np.ndarray
    t_last_s: np.ndarray
    views: np.ndarray
    x0_m: float
    y1_m: float
    cell_m: float

    @classmethod
    def empty(cls, *, x0_m: float, y1_m: float, cell_m: float, shape) -> "ElevationMap":
        """An empty map of ``shape`` (rows, cols) cells of ``cell_m`` (m)."""
        check_range("cell_m", cell_m, 0.0, 10.0, lo_open=True, unit=" m")
        rows, cols = (int(v) for v in shape)
        if rows < 1 or cols < 1:
            raise OutOfRangeError(f"shape = {tuple(shape)!r} must have at least one cell")
        if not (math.isfinite(x0_m) and math.isfinite(y1_m)):
            raise OutOfRangeError(f"(x0_m, y1_m) = ({x0_m!r}, {y1_m!r}) m must be finite")
        z = np.zeros((rows, cols))
        return cls(
            weight=z, weighted_z=z.copy(), weighted_z2=z.copy(),
            count=np.zeros((rows, cols), np.int64), z_max_m=np.full((rows, cols), -np.inf),
            t_last_s=np.full((rows, cols), np.nan), views=np.zeros((rows, cols), np.int32),
            x0_m=float(x0_m), y1_m=float(y1_m), cell_m=float(cell_m),
        )  # fmt: skip

    @classmethod
    def covering(cls, costmap: Costmap, *, cell_m: float = 0.1) -> "ElevationMap":
        """An empty map over ``costmap``'s window (its west and north edges; the last
        row and column may overhang)."""
        check_range("cell_m", cell_m, 0.0, 10.0, lo_open=True, unit=" m")
        rows, cols = costmap.shape
        res = costmap.resolution_m
        shape = (math.ceil(rows * res / cell_m - 1e-9), math.ceil(cols * res / cell_m - 1e-9))
        return cls.empty(x0_m=costmap.x0_m, y1_m=costmap.y1_m, cell_m=cell_m, shape=shape)

    @property
    def shape(self) -> tuple:
        return self.weight.shape

    def cell_of(self, x_m: float, y_m: float) -> tuple:
        """(row, col) of a site point; may lie outside the grid."""
        return (math.floor((self.y1_m - y_m) / self.cell_m),
                math.floor((x_m - self.x0_m) / self.cell_m))  # fmt: skip

    def centre_of(self, row, col) -> tuple:
        """Site (x, y) (m) of cell centres."""
        x = self.x0_m + (np.asarray(col) + 0.5) * self.cell_m
        y = self.y1_m - (np.asarray(row) + 0.5) * self.cell_m
        return x, y

    @property
    def height_m(self) -> np.ndarray:
        """Fused height (m; NaN where no point)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.weight > 0, self.weighted_z / self.weight, np.nan)

    @property
    def variance_m2(self) -> np.ndarray:
        """Variance of the fused height (m^2; inf where no point): ``1/W`` times the
        reduced chi-square of the points about it where that exceeds 1."""
        w = self.weight
        with np.errstate(divide="ignore", invalid="ignore"):
            h = self.weighted_z / w
            chi2 = np.maximum(self.weighted_z2 - w * h * h, 0.0)
            red = np.where(self.count > 1, chi2 / np.maximum(self.count - 1, 1), 1.0)
            return np.where(w > 0, np.maximum(red, 1.0) / w, np.inf)

    def known(self, config: ElevationMapConfig) -> np.ndarray:
        """Cells with ``min_points`` points from ``min_views`` clouds and a height sigma
        <= ``max_sigma_m``."""
        return (
            (self.count >= config.min_points)
            & (self.views >= config.min_views)
            & (self.variance_m2 <= config.max_sigma_m**2)
        )


def points_to_world(points_C, X_WC) -> np.ndarray:
    """``p_WP`` (..., 3; m) of points ``points_C`` (..., 3; m) in the camera frame C
    (OpenCV axes: x right, y down, z forward, as :class:`~lunar_drake.perception.stereo.
    StereoResult` gives them) with ``X_WC`` the camera's pose in W (4 x 4, or anything
    with ``GetAsMatrix4()`` such as a Drake ``RigidTransform``). NaN stays NaN."""
    T = X_WC.GetAsMatrix4() if hasattr(X_WC, "GetAsMatrix4") else X_WC
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4):
        raise ConfigError(f"X_WC has shape {T.shape}; a 4 x 4 pose is needed")
    p = np.asarray(points_C, np.float64)
    if p.shape[-1] != 3:
        raise ConfigError(f"points_C has shape {p.shape}; (..., 3) points are needed")
    return p @ T[:3, :3].T + T[:3, 3]


def fuse(emap: ElevationMap, *, points_W, sensor_origin_W, config: ElevationMapConfig,
         time_s: float = 0.0) -> ElevationMap:  # fmt: skip
    """``emap`` with one cloud fused in (module docstring): ``points_W`` (N, 3; m) in the
    world frame (already through the estimated camera pose; non-finite rows ignored),
    ``sensor_origin_W`` (3,; m) the camera centre they were seen from, ``time_s`` the
    capture time (s). ``emap`` is not modified."""
    config.validate()
    if not math.isclose(config.cell_m, emap.cell_m, rel_tol=1e-9):
        raise ConfigError(f"config cell_m = {config.cell_m:g} m differs from the map's "
                          f"{emap.cell_m:g} m")  # fmt: skip
    o = np.asarray(sensor_origin_W, np.float64).reshape(-1)
    if o.shape != (3,) or not np.isfinite(o).all():
        raise OutOfRangeError(f"sensor_origin_W = {o.tolist()!r} m must be 3 finite numbers")
    p = np.asarray(points_W, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ConfigError(f"points_W has shape {p.shape}; (N, 3) points are needed")
    rows, cols = emap.shape
    with np.errstate(invalid="ignore"):
        r = np.sqrt(np.sum((p - o) ** 2, axis=1))
        ok = np.isfinite(r) & (r >= config.min_range_m) & (r <= config.max_range_m)
        col = np.floor((p[:, 0] - emap.x0_m) / emap.cell_m)
        row = np.floor((emap.y1_m - p[:, 1]) / emap.cell_m)
    ok &= (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    out = dc.replace(
        emap, weight=emap.weight.copy(), weighted_z=emap.weighted_z.copy(),
        weighted_z2=emap.weighted_z2.copy(), count=emap.count.copy(),
        z_max_m=emap.z_max_m.copy(), t_last_s=emap.t_last_s.copy(), views=emap.views.copy(),
    )  # fmt: skip
    if not ok.any():
        return out
    idx = row[ok].astype(np.int64) * cols + col[ok].astype(np.int64)
    z = p[ok, 2]
    sig = config.height_sigma_m(r[ok])
    # Sorted by cell, then height: the cells' medians, and sums in an order that does
    # not depend on the order of the points.
    order = np.lexsort((sig, z, idx))
    idx, z, sig = idx[order], z[order], sig[order]
    cells, start, n = np.unique(idx, return_index=True, return_counts=True)
    group = np.repeat(np.arange(len(cells)), n)
    median = 0.5 * (z[start + (n - 1) // 2] + z[start + n // 2])
    keep = np.abs(z - median[group]) <= np.maximum(config.outlier_min_m,
                                                   config.outlier_sigmas * sig)  # fmt: skip
    w = np.where(keep, 1.0 / (sig * sig), 0.0)
    m = len(cells)
    sw = np.bincount(group, w, m)
    swz = np.bincount(group, w * z, m)
    swz2 = np.bincount(group, w * z * z, m)
    cnt = np.bincount(group, keep, m).astype(np.int64)
    zmax = np.full(m, -np.inf)
    np.maximum.at(zmax, group[keep], z[keep])
    hit = cnt > 0
    cells = cells[hit]
    out.weight.reshape(-1)[cells] += sw[hit]
    out.weighted_z.reshape(-1)[cells] += swz[hit]
    out.weighted_z2.reshape(-1)[cells] += swz2[hit]
    out.count.reshape(-1)[cells] += cnt[hit]
    flat = out.z_max_m.reshape(-1)
    flat[cells] = np.maximum(flat[cells], zmax[hit])
    out.t_last_s.reshape(-1)[cells] = float(time_s)
    out.views.reshape(-1)[cells] += 1
    return out


@dc.dataclass(frozen=True)
class PriorDem:
    """An a-priori DEM ``z`` (m; row 0 north, pixel ``resolution_m``; west edge
    ``x0_m``, north edge ``y1_m``), such as :func:`~lunar_drake.autonomy.costmap.
    orbital_dem` gives."""

    z: np.ndarray
    resolution_m: float
    x0_m: float
    y1_m: float

    def sample(self, x_m, y_m) -> np.ndarray:
        """Bilinear heights (m) at site points, the edge pixels extended outward."""
        z = np.asarray(self.z, np.float64)
        col = (np.asarray(x_m, np.float64) - self.x0_m) / self.resolution_m - 0.5
        row = (self.y1_m - np.asarray(y_m, np.float64)) / self.resolution_m - 0.5
        return ndimage.map_coordinates(z, [row, col], order=1, mode="nearest")


@dc.dataclass(frozen=True)
class StereoHazards:
    """Hazard layers of an elevation map, on its grid (``x0_m``, ``y1_m``, ``cell_m``):
    ``slope_deg``, ``step_m``, ``roughness_m`` (0 where not ``known``), ``lethal`` (known
    cells over a limit), ``known`` and ``surface_m`` (the fused heights, unknown cells
    filled, the layers came from)."""

    slope_deg: np.ndarray
    step_m: np.ndarray
    roughness_m: np.ndarray
    lethal: np.ndarray
    known: np.ndarray
    surface_m: np.ndarray
    x0_m: float
    y1_m: float
    cell_m: float


def stereo_hazards(emap: ElevationMap, *, hazards: HazardConfig, rover: RoverEnvelope,
                   config: ElevationMapConfig, prior: PriorDem | None = None,
                   surface: str = "mean") -> StereoHazards:  # fmt: skip
    """Slope, step and roughness of the known cells of ``emap`` (module docstring), with
    ``hazards``' definitions and limits for ``rover``. Unknown cells are filled from
    ``prior`` (offset to the stereo heights) or, without one, from the nearest known
    cell. ``surface``: ``mean`` (the fused heights) or ``max`` (each known cell's
    highest accepted point: rocks sharing a cell with the ground count whole; noisier)."""
    hazards.validate()
    config.validate()
    if surface not in ("mean", "max"):
        raise ConfigError(f"surface = {surface!r} is unknown; choose one of ('mean', 'max')")
    known = emap.known(config)
    few = np.zeros(emap.shape, bool)
    if 0 < config.tall_views < config.min_views:  # seen too few times, unless tall
        few = emap.known(dc.replace(config, min_views=config.tall_views)) & ~known
    h = emap.height_m if surface == "mean" else emap.z_max_m
    geo = {"x0_m": emap.x0_m, "y1_m": emap.y1_m, "cell_m": emap.cell_m}
    zeros = np.zeros(emap.shape)
    if not known.any() and not few.any():
        filled = zeros if prior is None else _prior_on(emap, prior)
        return StereoHazards(zeros, zeros.copy(), zeros.copy(), np.zeros(emap.shape, bool),
                             known, filled, **geo)  # fmt: skip
    base = None if prior is None else _prior_on(emap, prior)

    def fill(cells):
        if base is not None:
            offset = float(np.median(h[cells] - base[cells]))
            return np.where(cells, h, base + offset)
        _, (ri, ci) = ndimage.distance_transform_edt(~cells, return_indices=True)
        return h[ri, ci]

    baseline, window, max_step = hazard_limits(hazards, rover)

    def layers(surface_m):
        return hazard_layers(surface_m, resolution_m=emap.cell_m, baseline_m=baseline,
                             step_window_m=window)  # fmt: skip

    filled = fill(known if known.any() else few)
    slope, step, rough = (np.where(known, a, 0.0) for a in layers(filled))
    lethal = known & ((slope > hazards.max_slope_deg) | (step > max_step))
    if few.any():
        slope2, step2, rough2 = layers(fill(known | few))
        tall = few & (step2 > config.tall_factor * max_step)
        known, lethal = known | tall, lethal | tall
        slope, step, rough = (np.where(tall, b, a) for a, b in
                              ((slope, slope2), (step, step2), (rough, rough2)))  # fmt: skip
    return StereoHazards(slope, step, rough, lethal, known, filled, **geo)


def _prior_on(emap: ElevationMap, prior: PriorDem) -> np.ndarray:
    rr, cc = np.mgrid[0 : emap.shape[0], 0 : emap.shape[1]]
    x, y = emap.centre_of(rr, cc)
    return prior.sample(x, y)


def refined_costmap(
    costmap: Costmap, *, resolution_m: float, rover: RoverEnvelope, hazards: HazardConfig
) -> Costmap:
    """``costmap`` on a grid refined by the whole factor that brings its cells to at most
    ``resolution_m`` (its layers repeated, lethal cells re-inflated at the finer
    resolution): a 1 m orbital grid cannot place a rover-scale rock found by stereo
    without blocking a metre round it. Unchanged if already fine enough."""
    k = max(1, math.ceil(costmap.resolution_m / resolution_m - 1e-9))
    if k == 1:
        return costmap
    none = np.zeros((1, 1))
    empty = StereoHazards(none, none, none, np.zeros((1, 1), bool), np.zeros((1, 1), bool),
                          none, costmap.x0_m, costmap.y1_m, costmap.resolution_m)  # fmt: skip
    return merge_into_costmap(costmap, stereo=empty, rover=rover, hazards=hazards, upsample=k)


def merge_into_costmap(costmap: Costmap, *, stereo: StereoHazards, rover: RoverEnvelope,
                       hazards: HazardConfig, upsample: int = 1, stereo_clears: bool = False,
                       clear_coverage: float = 0.9) -> Costmap:  # fmt: skip
    """The a-priori ``costmap`` (built with ``hazards`` for ``rover``) with ``stereo``'s
    known cells merged in (module docstring): the larger layers, lethal in either,
    re-inflated and re-costed. ``upsample``: planning cells split into ``upsample`` x
    ``upsample`` (a finer grid for rover-scale rocks; the prior's layers repeated).
    ``stereo_clears``: planning cells at least ``clear_coverage`` (fraction of their area)
    covered by known cells take stereo's layers and lethality alone, clearing the
    prior's hazards there (off by default: see the module docstring). The prior's
    *unconfirmed* cells (``costmap.unconfirmed``: steep on the orbital map, lethal
    until seen) are settled by stereo always: once ``clear_coverage`` of one is known,
    stereo's lethality alone judges it; a stereo hazard in one makes it an ordinary
    hazard at once (never cleared later). Either way it is no longer unconfirmed."""
    hazards.validate()
    if isinstance(upsample, bool) or not isinstance(upsample, int | np.integer):
        raise ConfigError(f"upsample = {upsample!r} must be an integer")
    check_range("upsample", upsample, 1, 64)
    check_range("clear_coverage", clear_coverage, 0.0, 1.0, lo_open=True)
    k = int(upsample)

    def up(a):
        return np.repeat(np.repeat(np.asarray(a), k, axis=0), k, axis=1)

    slope, step, rough = up(costmap.slope_deg), up(costmap.step_m), up(costmap.roughness_m)
    lethal = up(costmap.lethal_raw).astype(bool)
    unconfirmed = None if costmap.unconfirmed is None else up(costmap.unconfirmed).astype(bool)
    res = costmap.resolution_m / k
    rows, cols = lethal.shape
    # Known stereo cells -> the planning cell holding their centre.
    kr, kc = np.nonzero(stereo.known)
    x = stereo.x0_m + (kc + 0.5) * stereo.cell_m
    y = stereo.y1_m - (kr + 0.5) * stereo.cell_m
    pr = np.floor((costmap.y1_m - y) / res).astype(np.int64)
    pc = np.floor((x - costmap.x0_m) / res).astype(np.int64)
    inside = (pr >= 0) & (pr < rows) & (pc >= 0) & (pc < cols)
    kr, kc, idx = kr[inside], kc[inside], pr[inside] * cols + pc[inside]
    n = rows * cols
    s_layers = []
    for a in (stereo.slope_deg, stereo.step_m, stereo.roughness_m):
        m = np.full(n, -np.inf)
        np.maximum.at(m, idx, a[kr, kc])
        s_layers.append(m.reshape(rows, cols))
    s_lethal = (np.bincount(idx, stereo.lethal[kr, kc], n) > 0).reshape(rows, cols)
    coverage = (np.bincount(idx, minlength=n) * (stereo.cell_m / res) ** 2).reshape(rows, cols)
    seen = coverage > 0
    layers = [np.where(seen, np.maximum(p, s), p)
              for p, s in zip((slope, step, rough), s_layers, strict=True)]  # fmt: skip
    lethal = lethal | s_lethal
    clear = coverage >= clear_coverage
    if stereo_clears:
        layers = [np.where(clear, s, p) for p, s in zip(layers, s_layers, strict=True)]
        lethal = np.where(clear, s_lethal, lethal)
    if unconfirmed is not None:
        # Seen well enough, or found lethal by stereo (then a hazard like any other).
        confirmed = unconfirmed & (clear | s_lethal)
        lethal = np.where(confirmed, s_lethal, lethal)
        unconfirmed = unconfirmed & ~confirmed
    slope, step, rough = layers
    return costmap_from_layers(
        slope_deg=slope, step_m=step, roughness_m=rough, lethal_raw=lethal, resolution_m=res,
        x0_m=costmap.x0_m, y1_m=costmap.y1_m, rover=rover, config=hazards,
        unconfirmed=unconfirmed,
    )  # fmt: skip


__all__ = [
    "ElevationMap",
    "ElevationMapConfig",
    "PriorDem",
    "StereoHazards",
    "fuse",
    "merge_into_costmap",
    "points_to_world",
    "refined_costmap",
    "stereo_hazards",
]
