"""The solar array: panel pose, Sun incidence, the visible part of the solar disk, power.

Frames and units: W is the site frame (x grid east, y grid north, z up; the
``polar_grid`` frame of :class:`~lunar_drake.systems.ephemeris_source.EphemerisSource`),
B the chassis body frame (= the rover model's C: x forward, y left, z up), P the panel
frame (origin at the panel centre). ``X_WB`` is given as ``R_WB`` (3x3) and ``p_WB`` (m).
Angles in the config are radians or degrees as their names say; power in W.

Model (:func:`array_output`)::

    P = S(d) * A * eta(T) * max(cos i, 0) * f

* ``S(d) = S0 (1 au / d)**2``: the solar constant ``S0`` = 1361 W/m^2 at 1 au (Kopp &
  Lean 2011, GRL 38, L01706), ``d`` the site-Sun distance from the ephemeris.
* ``A``: the panel's area (``solar_panel_width_m * solar_panel_height_m``), one active
  face (the back face makes nothing: ``cos i`` is clipped at 0).
* ``i``: angle between the panel's active-face normal ``n_W = R_WB n_B`` and the unit
  vector to the Sun's centre ``s_W``. The incidence of the visible part of a partly
  hidden disk differs from the centre's by at most the disk's radius (0.27 deg):
  neglected.
* ``f``: the visible fraction of the solar disk seen from the panel's centre, over the
  terrain horizon along the Sun's azimuth: the horizon is a straight level line across
  the small disk and ``f`` is the circular-segment area above it
  (:func:`lunar_drake.render.lightmap.solar_disk_visible_fraction`, the lightmap's own
  function; uniform disk by default, limb-darkened flux with ``limb="darkened"``). The
  horizon elevation is marched over the site raster from the panel's own height
  (:func:`lunar_drake.comms.line_of_sight.terrain_horizon_deg`, the Earth line-of-sight
  code), optionally raised by an outside :class:`~lunar_drake.render.horizon.HorizonMask`.
  The Sun's elevation is taken in W (the site origin's vertical): the local vertical at
  ``u`` m from the origin differs by ``u / R`` (0.003 deg at 100 m), neglected.
* ``eta(T) = cell_efficiency * packing_factor * (1 + temperature_coefficient_per_K *
  (T - reference_temperature_K))``, clipped at 0: cell efficiency with a linear
  temperature derating; the panel temperature is a constant of the config (no thermal
  model of the panel yet).

Neglected, and said so: Earthshine (the full Earth lights the site with ~0.1 W/m^2 at most,
about 1e-4 of the Sun), light scattered by the terrain onto the panel, shadows of the
rover's own mast on the panel, cell mismatch and wiring/MPPT losses beyond
``packing_factor``, dust.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.comms.line_of_sight import terrain_horizon_deg
from lunar_drake.ephemeris.sun_earth import SUN_RADIUS_KM
from lunar_drake.errors import ConfigError, OutOfRangeError, check_range
from lunar_drake.render.lightmap import LIMBS, solar_disk_visible_fraction
from lunar_drake.science.sun_envelope import AU_KM

__all__ = [
    "SOLAR_CONSTANT_W_M2",
    "ArrayOutput",
    "PanelMount",
    "SolarArrayConfig",
    "array_output",
    "panel_horizon_elevation_rad",
    "sun_disk_visible_fraction",
]

SOLAR_CONSTANT_W_M2 = 1361.0
"""Total solar irradiance at 1 au (W/m^2) (Kopp & Lean 2011, GRL 38, L01706)."""


@dc.dataclass
class SolarArrayConfig:
    """Cells and their derating (the panel's size and mount are the rover description's).

    Attributes:
        cell_efficiency: AM0 cell efficiency at ``reference_temperature_K`` (-), (0, 1];
            0.28: assumption, triple-junction GaInP/GaAs/Ge class.
        packing_factor: cell area over panel area, times wiring/MPPT losses (-), (0, 1];
            0.85: assumption.
        temperature_coefficient_per_K: relative change of efficiency per kelvin (1/K),
            [-0.02, 0]; -0.0025: assumption, triple-junction class.
        reference_temperature_K: temperature of the rated efficiency (K), (0, 1000];
            301.15 (28 deg C, the usual space-cell rating point).
        panel_temperature_K: panel temperature used until a thermal model exists (K),
            (0, 1000]; 300: assumption.
        solar_constant_W_m2: irradiance at 1 au (W/m^2), (0, 1e5]; 1361 (Kopp & Lean 2011).
        limb: ``"uniform"`` (fraction of the disk's area) or ``"darkened"`` (of its flux,
            linear limb darkening; see :mod:`lunar_drake.render.lightmap`).

    For scale: NASA's VIPER quotes about 450 W peak from its three-sided array (as
    reported for the VIPER mission; not an input here). The defaults on the KRex2/RP
    preset's 1.0 x 0.7 m panel give about 227 W at normal incidence.
    """

    cell_efficiency: float = 0.28
    packing_factor: float = 0.85
    temperature_coefficient_per_K: float = -0.0025
    reference_temperature_K: float = 301.15
    panel_temperature_K: float = 300.0
    solar_constant_W_m2: float = SOLAR_CONSTANT_W_M2
    limb: str = "uniform"

    def validate(self) -> None:
        """Raises OutOfRangeError/ConfigError naming the field and its allowed range."""
        check_range("cell_efficiency", self.cell_efficiency, 0.0, 1.0, lo_open=True)
        check_range("packing_factor", self.packing_factor, 0.0, 1.0, lo_open=True)
        check_range("temperature_coefficient_per_K", self.temperature_coefficient_per_K,
                    -0.02, 0.0, unit=" 1/K")  # fmt: skip
        check_range("reference_temperature_K", self.reference_temperature_K, 0.0, 1000.0,
                    lo_open=True, unit=" K")  # fmt: skip
        check_range("panel_temperature_K", self.panel_temperature_K, 0.0, 1000.0,
                    lo_open=True, unit=" K")  # fmt: skip
        check_range("solar_constant_W_m2", self.solar_constant_W_m2, 0.0, 1.0e5,
                    lo_open=True, unit=" W/m^2")  # fmt: skip
        if self.limb not in LIMBS:
            raise ConfigError(f"limb = {self.limb!r} is unknown; allowed: {', '.join(LIMBS)}")

    def efficiency(self, temperature_K: float) -> float:
        """Array efficiency (-) at panel temperature ``temperature_K`` (K), clipped at 0."""
        derate = 1.0 + self.temperature_coefficient_per_K * (
            float(temperature_K) - self.reference_temperature_K
        )
        return max(0.0, self.cell_efficiency * self.packing_factor * derate)


@dc.dataclass(frozen=True)
class PanelMount:
    """Where the panel sits on the chassis.

    Attributes:
        n_B: unit normal of the active face in B (3,).
        p_BP: panel centre in B (m) (3,).
        area_m2: active-face area (m^2), > 0.
    """

    n_B: tuple[float, float, float]
    p_BP: tuple[float, float, float]
    area_m2: float

    def __post_init__(self) -> None:
        n = np.asarray(self.n_B, dtype=float)
        if n.shape != (3,) or not np.isfinite(n).all() or not np.linalg.norm(n) > 0:
            raise ConfigError(f"PanelMount.n_B = {self.n_B!r} must be a non-zero 3-vector")
        p = np.asarray(self.p_BP, dtype=float)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ConfigError(f"PanelMount.p_BP = {self.p_BP!r} must be a finite 3-vector (m)")
        check_range("PanelMount.area_m2", self.area_m2, 0.0, 1.0e3, lo_open=True, unit=" m^2")
        object.__setattr__(self, "n_B", tuple(float(v) for v in n / np.linalg.norm(n)))
        object.__setattr__(self, "p_BP", tuple(float(v) for v in p))
        object.__setattr__(self, "area_m2", float(self.area_m2))

    @classmethod
    def from_description(cls, description) -> "PanelMount":
        """The mount of a :class:`~lunar_drake.models.rover_description.RoverDescription`
        (read by field name, so this module needs no Drake): the normal from
        ``solar_panel_tilt_rad``/``solar_panel_azimuth_rad``, the centre at
        (``solar_panel_x_m``, ``solar_panel_y_m``, chassis top +
        ``solar_panel_mount_height_m``) as in the SDFormat model, area width x height."""
        d = description
        t, a = float(d.solar_panel_tilt_rad), float(d.solar_panel_azimuth_rad)
        n_B = (math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t))
        top = float(d.chassis_height_m) / 2.0
        p_BP = (float(d.solar_panel_x_m), float(d.solar_panel_y_m),
                top + float(d.solar_panel_mount_height_m))  # fmt: skip
        area = float(d.solar_panel_width_m) * float(d.solar_panel_height_m)
        return cls(n_B=n_B, p_BP=p_BP, area_m2=area)

    def pose_in_world(self, *, R_WB, p_WB) -> tuple[np.ndarray, np.ndarray]:
        """``(n_W, p_WP)``: the active-face normal in W and the panel centre in W (m)."""
        R = np.asarray(R_WB, dtype=float).reshape(3, 3)
        p = np.asarray(p_WB, dtype=float).reshape(3)
        return R @ np.asarray(self.n_B), p + R @ np.asarray(self.p_BP)


@dc.dataclass(frozen=True)
class ArrayOutput:
    """One evaluation of the array (``power.csv``'s array columns among them).

    Attributes:
        power_W: electrical power delivered by the array (W), >= 0.
        incidence_deg: angle between the Sun's centre and the panel normal (deg), [0, 180].
        visible_fraction: visible fraction of the solar disk from the panel centre, [0, 1].
        sun_elevation_deg, sun_azimuth_deg: the Sun in W (azimuth clockwise from grid north).
        horizon_elevation_deg: terrain horizon along the Sun's azimuth from the panel (deg).
        irradiance_W_m2: unobstructed irradiance normal to the Sun, ``S(d)`` (W/m^2).
        efficiency: array efficiency at the panel temperature (-).
    """

    power_W: float
    incidence_deg: float
    visible_fraction: float
    sun_elevation_deg: float
    sun_azimuth_deg: float
    horizon_elevation_deg: float
    irradiance_W_m2: float
    efficiency: float


def sun_disk_visible_fraction(
    *, sun_elevation_rad: float, horizon_elevation_rad: float, sun_radius_rad: float,
    limb: str = "uniform",
) -> float:  # fmt: skip
    """Visible fraction of the solar disk (radius ``sun_radius_rad``, centre at
    ``sun_elevation_rad``) above a straight level horizon at ``horizon_elevation_rad``
    (all rad): the lightmap's circular-segment formula."""
    return float(
        solar_disk_visible_fraction(
            horizon_elevation_rad, sun_elevation_rad, sun_radius_rad=sun_radius_rad, limb=limb
        )
    )


def _mask_elevation_deg(mask, azimuth_deg: float, p_W: np.ndarray) -> float:
    e = mask.elevation_deg(azimuth_deg)
    if not mask.gridded:
        return float(e)
    left, bottom, right, top = mask.bounds
    ny, nx = e.shape
    ci = min(max(math.floor((p_W[0] - left) / (right - left) * nx), 0), nx - 1)
    ri = min(max(math.floor((top - p_W[1]) / (top - bottom) * ny), 0), ny - 1)
    return float(e[ri, ci])


def panel_horizon_elevation_rad(
    *, heightfield, p_WP, azimuth_rad: float, horizon_mask=None
) -> float:
    """Terrain horizon elevation (rad) seen from the panel centre ``p_WP`` (W, m) toward
    ``azimuth_rad`` (clockwise from grid north): the site raster marched from the panel's
    own height (:func:`~lunar_drake.comms.line_of_sight.terrain_horizon_deg`), raised to
    ``horizon_mask``'s elevation there (terrain outside the raster) when one is given."""
    p = np.asarray(p_WP, dtype=float).reshape(3)
    h = terrain_horizon_deg(heightfield=heightfield, p_W=p, azimuth_rad=azimuth_rad)
    if horizon_mask is not None:
        h = max(h, _mask_elevation_deg(horizon_mask, math.degrees(azimuth_rad) % 360.0, p))
    return math.radians(h)


def array_output(
    *,
    config: SolarArrayConfig,
    mount: PanelMount,
    R_WB,
    p_WB,
    sun_direction_W,
    sun_distance_km: float,
    heightfield=None,
    horizon_mask=None,
    horizon_elevation_rad: float | None = None,
    panel_temperature_K: float | None = None,
) -> ArrayOutput:
    """Power of the array for the chassis pose ``X_WB`` = (``R_WB``, ``p_WB``).

    Args:
        config: cells and derating. mount: the panel on the chassis.
        R_WB: chassis orientation in W (3x3). p_WB: chassis origin in W (m).
        sun_direction_W: vector towards the Sun's centre in W (normalised here).
        sun_distance_km: site-Sun distance (km), > 0.
        heightfield: the site raster for the horizon from the panel's height (a
            :class:`~lunar_drake.terrain.heightfield.Heightfield`); with neither it nor
            ``horizon_mask`` nor ``horizon_elevation_rad``, a level plain (horizon 0).
        horizon_mask: terrain outside the raster (optional).
        horizon_elevation_rad: the horizon along the Sun's azimuth, given directly
            (instead of ``heightfield``/``horizon_mask``).
        panel_temperature_K: panel temperature (K); default ``config.panel_temperature_K``.

    Returns:
        :class:`ArrayOutput`.
    """
    s = np.asarray(sun_direction_W, dtype=float).reshape(3)
    norm = float(np.linalg.norm(s))
    if not (math.isfinite(norm) and norm > 0.0):
        raise OutOfRangeError(f"sun_direction_W = {s.tolist()!r} must be a non-zero vector")
    s = s / norm
    d_km = float(sun_distance_km)
    check_range("sun_distance_km", d_km, SUN_RADIUS_KM, 1.0e10, lo_open=True, unit=" km")
    n_W, p_WP = mount.pose_in_world(R_WB=R_WB, p_WB=p_WB)
    cos_i = float(np.clip(n_W @ s, -1.0, 1.0))
    sun_el = math.asin(float(np.clip(s[2], -1.0, 1.0)))
    sun_az = math.atan2(s[0], s[1])
    if horizon_elevation_rad is not None:
        if heightfield is not None or horizon_mask is not None:
            raise ConfigError("give horizon_elevation_rad or heightfield/horizon_mask, not both")
        h = float(horizon_elevation_rad)
    elif heightfield is not None:
        h = panel_horizon_elevation_rad(
            heightfield=heightfield, p_WP=p_WP, azimuth_rad=sun_az, horizon_mask=horizon_mask
        )
    elif horizon_mask is not None:
        h = math.radians(_mask_elevation_deg(horizon_mask, math.degrees(sun_az) % 360.0, p_WP))
    else:
        h = 0.0
    sun_radius = math.asin(SUN_RADIUS_KM / d_km)
    f = sun_disk_visible_fraction(
        sun_elevation_rad=sun_el, horizon_elevation_rad=h, sun_radius_rad=sun_radius,
        limb=config.limb,
    )  # fmt: skip
    irradiance = config.solar_constant_W_m2 * (AU_KM / d_km) ** 2
    temp = config.panel_temperature_K if panel_temperature_K is None else panel_temperature_K
    eta = config.efficiency(temp)
    power = irradiance * mount.area_m2 * eta * max(cos_i, 0.0) * f
    return ArrayOutput(
        power_W=float(power),
        incidence_deg=math.degrees(math.acos(cos_i)),
        visible_fraction=f,
        sun_elevation_deg=math.degrees(sun_el),
        sun_azimuth_deg=math.degrees(sun_az) % 360.0,
        horizon_elevation_deg=math.degrees(h),
        irradiance_W_m2=float(irradiance),
        efficiency=float(eta),
    )
