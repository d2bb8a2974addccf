"""Hazard costmap for ground planning: slope, step height and roughness from a DEM,
lethal cells inflated by the rover's footprint. Pure numpy/scipy; no Drake.

From a DEM ``z`` (m, row 0 north, pixel ``res`` m):

* **slope** (deg): the gradient of the DEM smoothed over a box of ``baseline_m`` (about
  the wheelbase: what tilts the chassis);
* **step** (m): max - min, within ``step_window_m`` (about a wheel's footprint), of
  the DEM minus its smoothed surface: rocks and edges a wheel must climb, apart from the
  slope it is on (a plane has no steps);
* **roughness** (m): RMS of the DEM minus its smoothed surface within ``baseline_m``.

Each layer is reduced to the planning grid (``resolution_m``) by its maximum over the
block (conservative). A cell is *lethal* when slope > ``max_slope_deg`` or step >
``max_step_m``; lethal cells are inflated by the rover's footprint radius plus
``inflation_m`` (a cell within that distance of a lethal one is lethal: the rover's
centre must stay that far from hazards). Free cells cost ``1 + slope_weight (slope /
max_slope)^2 + roughness_weight (roughness / max_roughness)^2`` per metre; lethal ones
``inf``.

The ground's a-priori map is a pre-flight product
(:mod:`lunar_drake.autonomy.map_product`): by default ``orbital``, the terrain without the
rocks an orbital camera cannot resolve, averaged over blocks of ``orbital_resolution_m``
(craters stay) plus seeded noise; ``truth`` (the site DEM) is an oracle.
An orbital map's metre-scale slope hides rover-scale ones: on the default site, 1 m
cells at 10-12 deg are 51 % lethal at the planning grid, at 12-14 deg 73 %
(``benchmarks/orbital_trust.py``). So orbital cells steeper than
``MapConfig.confirm_slope_deg`` are *unconfirmed*: lethal (``Costmap.unconfirmed``)
until stereo covers them (:func:`~lunar_drake.perception.elevation_map.
merge_into_costmap`), when stereo's layers judge them.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np
from scipy import ndimage

from lunar_drake.autonomy.map_product import MapProduct, make_map_product, orbital_dem
from lunar_drake.errors import ConfigError, check_range


@dc.dataclass
class HazardConfig:
    """How the ground turns a map into a costmap (see the module docstring).

    Attributes:
        resolution_m: planning grid (m), (0, 50].
        max_slope_deg: steepest traversable slope (deg); default 14, what both rovers
            climb on lunar regolith in the slip study (the skid rover spins out at 16).
        max_step_m: tallest step the wheels may meet (m); 0 = 0.8 times the smaller of
            the wheel radius and the belly clearance.
        max_roughness_m: roughness that doubles a cell's cost (m), > 0.
        baseline_m: smoothing baseline of slope and roughness (m); 0 = the wheelbase.
        step_window_m: window of the step height (m); 0 = the wheel diameter.
        slope_weight, roughness_weight: cost weights (-), >= 0.
        inflation_m: extra margin added to the footprint radius (m), >= 0.
    """

    resolution_m: float = 0.5
    max_slope_deg: float = 14.0
    max_step_m: float = 0.0
    max_roughness_m: float = 0.05
    baseline_m: float = 0.0
    step_window_m: float = 0.0
    slope_weight: float = 2.0
    roughness_weight: float = 1.0
    inflation_m: float = 0.2

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("resolution_m", self.resolution_m, 0.0, 50.0, lo_open=True, unit=" m")
        check_range("max_slope_deg", self.max_slope_deg, 0.0, 60.0, lo_open=True, unit=" deg")
        check_range("max_step_m", self.max_step_m, 0.0, 5.0, unit=" m")
        check_range("max_roughness_m", self.max_roughness_m, 0.0, 5.0, lo_open=True, unit=" m")
        check_range("baseline_m", self.baseline_m, 0.0, 50.0, unit=" m")
        check_range("step_window_m", self.step_window_m, 0.0, 10.0, unit=" m")
        check_range("slope_weight", self.slope_weight, 0.0, 1e6)
        check_range("roughness_weight", self.roughness_weight, 0.0, 1e6)
        check_range("inflation_m", self.inflation_m, 0.0, 50.0, unit=" m")


MAP_SOURCES = ("truth", "orbital")


@dc.dataclass
class MapConfig:
    """The ground's a-priori map (:mod:`lunar_drake.autonomy.map_product`).

    Attributes:
        source: ``orbital`` (default: the terrain without the rocks narrower than
            ``resolved_rock_m``, averaged to ``orbital_resolution_m``, plus seeded noise:
            what an orbital camera gives) or ``truth`` (the site DEM, every rock in it:
            an oracle for testing control and the link; runs say so).
        orbital_resolution_m: orbital DEM pixel (m). orbital_noise_m: its noise (m).
        resolved_rock_m: the narrowest rock the orbital camera resolves (m; equivalent
            diameter); 0 = two orbital pixels. Narrower rocks are not in the product.
        margin_m: map margin around the start and the goal (m).
        confirm_slope_deg: orbital cells steeper than this (deg) are lethal until stereo
            has seen them (module docstring); 0: trust the orbital map; not used with
            ``truth``.
    """

    source: str = "orbital"
    orbital_resolution_m: float = 1.0
    orbital_noise_m: float = 0.05
    resolved_rock_m: float = 0.0
    margin_m: float = 20.0
    confirm_slope_deg: float = 11.0

    def validate(self) -> None:
        if self.source not in MAP_SOURCES:
            raise ConfigError(f"source = {self.source!r} is unknown; choose one of {MAP_SOURCES}")
        check_range("orbital_resolution_m", self.orbital_resolution_m, 0.01, 1e4, unit=" m")
        check_range("orbital_noise_m", self.orbital_noise_m, 0.0, 100.0, unit=" m")
        check_range("resolved_rock_m", self.resolved_rock_m, 0.0, 1e4, unit=" m")
        check_range("margin_m", self.margin_m, 0.0, 1e5, unit=" m")
        check_range("confirm_slope_deg", self.confirm_slope_deg, 0.0, 90.0, unit=" deg")


@dc.dataclass(frozen=True)
class RoverEnvelope:
    """What the costmap needs of a rover (m): footprint radius (the inscribed radius of
    the wheel footprint: half the track plus half a wheel width, or half the chassis
    width if wider; hazards are kept that far from the rover's centre line, so a rock
    may pass under the belly only if it is below the step limit), wheelbase, wheel
    radius and belly clearance."""

    footprint_radius_m: float
    wheelbase_m: float
    wheel_radius_m: float
    ground_clearance_m: float

    @classmethod
    def of(cls, description) -> "RoverEnvelope":
        """From a :class:`~lunar_drake.models.rover_description.RoverDescription`."""
        half_w = 0.5 * description.track_m + 0.5 * description.wheel_width_m
        half_w = max(half_w, 0.5 * description.chassis_width_m)
        return cls(
            footprint_radius_m=half_w,
            wheelbase_m=description.wheelbase_m,
            wheel_radius_m=description.wheel_radius_m,
            ground_clearance_m=description.ground_clearance_m,
        )


@dc.dataclass(frozen=True)
class Costmap:
    """A planning grid. ``cost`` (rows, cols): cost per metre (>= 1; ``inf`` lethal), row
    0 north; ``slope_deg``, ``step_m``, ``roughness_m`` the layers; ``lethal_raw`` the
    hazards before inflation, ``unconfirmed`` among them; ``x0_m``, ``y1_m``: site
    coordinates of the grid's west and north edges; ``resolution_m``; ``unconfirmed``
    (bool, or None): cells lethal only until stereo has seen them (module docstring);
    ``max_slope_deg``, ``max_step_m``: the limits a hazard breaks, and
    ``inflation_radius_m`` (the footprint radius plus the inflation, m) round each
    hazard (inf, inf, 0 when unknown), so errors can say why a cell is lethal."""

    cost: np.ndarray
    slope_deg: np.ndarray
    step_m: np.ndarray
    roughness_m: np.ndarray
    lethal_raw: np.ndarray
    x0_m: float
    y1_m: float
    resolution_m: float
    unconfirmed: np.ndarray | None = None
    max_slope_deg: float = math.inf
    max_step_m: float = math.inf
    inflation_radius_m: float = 0.0

    @property
    def shape(self) -> tuple:
        return self.cost.shape

    def cell_of(self, x_m: float, y_m: float) -> tuple:
        """(row, col) of a site point; may lie outside the grid."""
        col = math.floor((x_m - self.x0_m) / self.resolution_m)
        row = math.floor((self.y1_m - y_m) / self.resolution_m)
        return row, col

    def centre_of(self, row, col) -> tuple:
        """Site (x, y) (m) of cell centres."""
        x = self.x0_m + (np.asarray(col) + 0.5) * self.resolution_m
        y = self.y1_m - (np.asarray(row) + 0.5) * self.resolution_m
        return x, y

    def inside(self, row: int, col: int) -> bool:
        return 0 <= row < self.cost.shape[0] and 0 <= col < self.cost.shape[1]

    def extent_text(self) -> str:
        """The grid's extent for messages (site m): ``x in [x0, x1], y in [y0, y1] m``,
        and that it holds whole cells only."""
        res = self.resolution_m
        rows, cols = self.shape
        return (
            f"x in [{self.x0_m:g}, {self.x0_m + cols * res:g}], "
            f"y in [{self.y1_m - rows * res:g}, {self.y1_m:g}] m (whole {res:g} m cells; a "
            f"site edge narrower than a cell is left out)"
        )


def _block_max(a: np.ndarray, k: int) -> np.ndarray:
    r, c = (a.shape[0] // k) * k, (a.shape[1] // k) * k
    return a[:r, :c].reshape(r // k, k, c // k, k).max(axis=(1, 3))


def hazard_layers(z, *, resolution_m: float, baseline_m: float, step_window_m: float):
    """(slope_deg, step_m, roughness_m) on the DEM's own grid (module docstring)."""
    z = np.asarray(z, dtype=np.float64)
    if not np.isfinite(z).all():
        raise ConfigError("the map holds nodata (NaN) cells; fill or crop them before planning")
    # Odd windows: centred on each pixel (an even box would shift the smoothed surface
    # by half a pixel and read a plane as rough).
    nb = 2 * (round(baseline_m / resolution_m) // 2) + 1
    ns = 2 * (round(step_window_m / resolution_m) // 2) + 1
    smooth = ndimage.uniform_filter(z, size=nb, mode="nearest")
    gy, gx = np.gradient(smooth, resolution_m)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    resid = z - smooth
    step = ndimage.maximum_filter(resid, size=ns, mode="nearest") - ndimage.minimum_filter(
        resid, size=ns, mode="nearest"
    )
    rough = np.sqrt(np.maximum(ndimage.uniform_filter(resid * resid, size=nb, mode="nearest"), 0.0))
    return slope, step, rough


def build_costmap(
    z, *, resolution_m: float, x0_m: float, y1_m: float, rover: RoverEnvelope, config: HazardConfig
) -> Costmap:
    """The costmap of a DEM ``z`` (m; pixel ``resolution_m``; west edge ``x0_m``, north
    edge ``y1_m``) for ``rover`` (module docstring)."""
    config.validate()
    baseline, window, max_step = hazard_limits(config, rover)
    slope, step, rough = hazard_layers(
        z, resolution_m=resolution_m, baseline_m=baseline, step_window_m=window
    )
    k = max(1, round(config.resolution_m / resolution_m))
    slope, step, rough = (_block_max(a, k) for a in (slope, step, rough))
    lethal = (slope > config.max_slope_deg) | (step > max_step)
    return costmap_from_layers(
        slope_deg=slope, step_m=step, roughness_m=rough, lethal_raw=lethal,
        resolution_m=resolution_m * k, x0_m=x0_m, y1_m=y1_m, rover=rover, config=config,
    )  # fmt: skip


def hazard_limits(config: HazardConfig, rover: RoverEnvelope) -> tuple:
    """(baseline_m, step_window_m, max_step_m) of ``config`` with its zero defaults
    resolved for ``rover`` (see :class:`HazardConfig`)."""
    baseline = config.baseline_m or rover.wheelbase_m
    window = config.step_window_m or 2.0 * rover.wheel_radius_m
    max_step = config.max_step_m or 0.8 * min(rover.wheel_radius_m, rover.ground_clearance_m)
    return baseline, window, max_step


def costmap_from_layers(*, slope_deg, step_m, roughness_m, lethal_raw, resolution_m: float,
                        x0_m: float, y1_m: float, rover: RoverEnvelope,
                        config: HazardConfig, unconfirmed=None) -> Costmap:  # fmt: skip
    """The costmap of hazard layers already on the planning grid (cell ``resolution_m``;
    west edge ``x0_m``, north edge ``y1_m``): ``lethal_raw`` (with ``unconfirmed``, a
    mask of cells lethal until stereo sees them, if given) inflated by the rover's
    footprint radius plus ``config.inflation_m``, free cells costed from slope and
    roughness (module docstring). :func:`build_costmap` ends here."""
    config.validate()
    slope = np.asarray(slope_deg, np.float64)
    rough = np.asarray(roughness_m, np.float64)
    lethal = np.asarray(lethal_raw, bool)
    if unconfirmed is not None:
        unconfirmed = np.asarray(unconfirmed, bool)
        if unconfirmed.shape != lethal.shape:
            raise ConfigError(
                f"unconfirmed has shape {unconfirmed.shape}; the layers {lethal.shape}"
            )
        lethal = lethal | unconfirmed
    radius = rover.footprint_radius_m + config.inflation_m
    if lethal.any():
        dist = ndimage.distance_transform_edt(~lethal) * resolution_m
        inflated = dist <= radius
    else:
        inflated = lethal
    cost = (
        1.0
        + config.slope_weight * (slope / config.max_slope_deg) ** 2
        + config.roughness_weight * (rough / config.max_roughness_m) ** 2
    )
    cost = np.where(inflated, np.inf, cost)
    return Costmap(
        cost=cost,
        slope_deg=slope,
        step_m=np.asarray(step_m, np.float64),
        roughness_m=rough,
        lethal_raw=lethal,
        x0_m=float(x0_m),
        y1_m=float(y1_m),
        resolution_m=float(resolution_m),
        unconfirmed=unconfirmed,
        max_slope_deg=float(config.max_slope_deg),
        max_step_m=float(hazard_limits(config, rover)[2]),
        inflation_radius_m=float(radius),
    )


def map_dem_for_site(*, heightfield, points_xy, map_config: MapConfig, seed: int,
                     rock_mask=None) -> tuple:  # fmt: skip
    """(z, pixel size, x0_m, y1_m) of :func:`~lunar_drake.autonomy.map_product.
    make_map_product` (the ground's a-priori DEM around ``points_xy``)."""
    p = make_map_product(heightfield=heightfield, points_xy=points_xy, map_config=map_config,
                         seed=seed, rock_mask=rock_mask)  # fmt: skip
    return p.z, p.resolution_m, p.x0_m, p.y1_m


def costmap_of_product(product: MapProduct, *, rover: "RoverEnvelope",
                       hazards: HazardConfig) -> Costmap:  # fmt: skip
    """The costmap of a map product, through :func:`build_costmap`; an orbital product's
    cells steeper than its ``confirm_slope_deg`` unconfirmed (module docstring)."""
    cm = build_costmap(product.z, resolution_m=product.resolution_m, x0_m=product.x0_m,
                       y1_m=product.y1_m, rover=rover, config=hazards)  # fmt: skip
    if product.source != "orbital" or product.confirm_slope_deg <= 0.0:
        return cm
    unconfirmed = (cm.slope_deg > product.confirm_slope_deg) & ~cm.lethal_raw
    return costmap_from_layers(
        slope_deg=cm.slope_deg, step_m=cm.step_m, roughness_m=cm.roughness_m,
        lethal_raw=cm.lethal_raw, resolution_m=cm.resolution_m, x0_m=cm.x0_m, y1_m=cm.y1_m,
        rover=rover, config=hazards, unconfirmed=unconfirmed,
    )  # fmt: skip


def costmap_for_site(*, heightfield, points_xy, rover: "RoverEnvelope", hazards: HazardConfig,
                     map_config: MapConfig, seed: int, rock_mask=None) -> Costmap:  # fmt: skip
    """The ground's costmap around ``points_xy`` (start, goals; site m) from the site's
    ``heightfield``: :func:`costmap_of_product` of :func:`~lunar_drake.autonomy.
    map_product.make_map_product`."""
    product = make_map_product(heightfield=heightfield, points_xy=points_xy,
                               map_config=map_config, seed=seed, rock_mask=rock_mask)  # fmt: skip
    return costmap_of_product(product, rover=rover, hazards=hazards)


__all__ = [
    "MAP_SOURCES",
    "Costmap",
    "HazardConfig",
    "MapConfig",
    "RoverEnvelope",
    "build_costmap",
    "costmap_for_site",
    "costmap_from_layers",
    "costmap_of_product",
    "hazard_layers",
    "hazard_limits",
    "map_dem_for_site",
    "orbital_dem",
]
