"""Typed, validated description of a rover, from which the SDFormat model is generated.

Paper section 6 ("Simulating Vehicle Mobility") compared two proxies of the Resource
Prospector (RP) rover: a skid-steer Husky carrying the RP sensor mast, and NASA Ames'
KRex2 modified with RP's offset steering and a differencing bar. Both got a stereo pair
on a pan/tilt gimbal at the top of a mast and the solar-panel superstructure.
:func:`husky_rp` and :func:`krex2_rp` are those two; every number is a field, so trade
studies vary them with ``dataclasses.replace`` or YAML.

Chassis frame C (= the SDFormat model frame and the ``chassis`` body frame): origin at the
centre of the chassis box, x forward, y left, z up. Lengths in metres, masses in kg,
angles in radians, torques in N·m, gains in N·m/rad and N·m·s/rad.

The class is a plain (mutable) dataclass, not ``frozen``: Drake's ``yaml_load_typed``
assigns fields with ``setattr`` and fails on frozen dataclasses (measured with pydrake
1.51.1: ``FrozenInstanceError``). As in ``lunar_drake/scenario.py``, loading bypasses
``__post_init__``, so :meth:`RoverDescription.validate` is public and is called again by
``rover_sdf`` / ``add_rover``. Treat instances as values: derive variants with
``dataclasses.replace``.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np
from pydrake.common.yaml import yaml_load_typed

from lunar_drake.errors import ConfigError, OutOfRangeError, check_range
from lunar_drake.moon import GRAVITY_MPS2

STEERING_KINDS = ("skid", "explicit")
"""Allowed values of :attr:`RoverDescription.steering`."""


BRAKE_SAFETY_FACTOR = 2.0
"""Safety factor of the automatic parking-brake torque
(:meth:`RoverDescription.brake_holding_torque_nm`)."""


@dc.dataclass
class RoverDescription:
    """Geometry, masses, joint limits and servo gains of a four-wheeled rover.

    The defaults are the explicit-steer RP proxy (:func:`krex2_rp`); see that function
    for sources. Zero joint angles are the nominal configuration: wheels straight, rockers
    level, cameras looking along +x_C.

    Attributes:
        name: label of the description (not the Drake model-instance name).
        steering: ``"skid"`` (4 wheels on fixed axles) or ``"explicit"`` (4 independently
            steered wheels with offset steering, on two rockers tied by a differencing
            bar).
        wheelbase_m: front-to-rear wheel-centre distance (m).
        track_m: left-to-right wheel-centre distance (m).
        wheel_radius_m, wheel_width_m: wheel cylinder (m).
        chassis_length_m, chassis_width_m, chassis_height_m: chassis box (m, along x/y/z_C).
        chassis_mass_kg: chassis box mass, spread uniformly (kg).
        wheel_mass_kg: mass of one wheel (kg; solid-cylinder inertia).
        steering_module_mass_kg: mass of one steering module (explicit only; kg).
        rocker_mass_kg: mass of one rocker / differencing-bar side (explicit only; kg).
        rocker_limit_rad: rocker pitch range is [-limit, +limit] (explicit only).
        mast_x_m: x_C of the mast axis (m; the mast stands on the chassis top, y_C = 0).
        mast_height_m: gimbal centre (pan and tilt axes) above the chassis top (m).
        mast_mass_kg: mast tube mass (kg).
        gimbal_mass_kg: pan yoke + camera head mass, split evenly between them (kg).
        camera_baseline_m: distance between the left and right camera centres (m).
        gimbal_pan_min_rad, gimbal_pan_max_rad: pan joint limits (about +z; + looks left).
        gimbal_tilt_min_rad, gimbal_tilt_max_rad: tilt joint limits (about +y; + looks
            down).
        steering_offset_m: lateral offset of the wheel centre outboard of its steering
            axis (m; explicit only; 0 = wheel centred on the axis).
        steering_limit_rad: steering joint range is [-limit, +limit] (+ turns left).
        ground_clearance_m: chassis underside above level ground with the wheels just
            touching and all joints at zero (m).
        solar_panel_width_m: panel edge that stays horizontal when tilted (m).
        solar_panel_height_m: the other in-plane panel edge (m).
        solar_panel_thickness_m: panel thickness (m).
        solar_panel_tilt_rad: angle of the panel normal from +z_C (0 = horizontal panel,
            pi/2 = vertical panel).
        solar_panel_azimuth_rad: direction of the normal's horizontal part, from +x_C
            towards +y_C. Normal n_C = (sin t cos a, sin t sin a, cos t).
        solar_panel_x_m, solar_panel_y_m: panel centre over the chassis, in C (m).
        solar_panel_mount_height_m: panel centre above the chassis top (m).
        solar_panel_mass_kg: panel + superstructure mass (kg).
        belly_contact_x_m, belly_contact_y_m: belly strike points on the chassis underside
            (m in C, parallel lists; z_C = -chassis_height_m/2). Empty = a 3x3 grid at
            0 and +-0.45 of the chassis length and width.
        drive_effort_limit_nm: wheel drive torque limit (N·m).
        max_rated_slope_deg: the steepest slope the rover is rated to park on (deg), in
            (0, 60).
        brake_torque_nm: holding torque of each wheel's parking brake (N·m), in
            [0, 1e5]; 0 (the default) = automatic, see
            :meth:`RoverDescription.brake_holding_torque_nm`.
        drive_kp, drive_kd: drive servo gains (N·m/rad, N·m·s/rad). kp = 0 makes the drive
            a pure velocity servo, tau = kd (v_d - v), clamped to the effort limit. The
            defaults are stiff (geared drives are nearly kinematic) and, with the plant's
            implicit PD, keep the wheel-spin mode stable against the explicitly applied
            soil torque at a 10 ms step: the soil torque's sensitivity to wheel speed,
            r^2 W dmu/ds / max(r omega, v_eps), must stay below ~(2 I + dt kd) / dt.
        steer_effort_limit_nm, steer_kp, steer_kd: steering servo (explicit only).
        gimbal_effort_limit_nm, gimbal_kp, gimbal_kd: pan and tilt servos.
    """

    name: str = "krex2_rp"
    steering: str = "explicit"
    wheelbase_m: float = 1.2
    track_m: float = 1.2
    wheel_radius_m: float = 0.25
    wheel_width_m: float = 0.2
    chassis_length_m: float = 1.4
    chassis_width_m: float = 0.8
    chassis_height_m: float = 0.35
    chassis_mass_kg: float = 180.0
    wheel_mass_kg: float = 8.0
    steering_module_mass_kg: float = 10.0
    rocker_mass_kg: float = 8.0
    rocker_limit_rad: float = 0.35
    mast_x_m: float = 0.5
    mast_height_m: float = 0.9
    mast_mass_kg: float = 8.0
    gimbal_mass_kg: float = 4.0
    camera_baseline_m: float = 0.3
    gimbal_pan_min_rad: float = -math.pi
    gimbal_pan_max_rad: float = math.pi
    gimbal_tilt_min_rad: float = -0.5
    gimbal_tilt_max_rad: float = 1.2
    steering_offset_m: float = 0.1
    steering_limit_rad: float = 1.6
    ground_clearance_m: float = 0.3
    solar_panel_width_m: float = 1.0
    solar_panel_height_m: float = 0.7
    solar_panel_thickness_m: float = 0.03
    solar_panel_tilt_rad: float = math.pi / 2
    solar_panel_azimuth_rad: float = math.pi / 2
    solar_panel_x_m: float = -0.15
    solar_panel_y_m: float = 0.0
    solar_panel_mount_height_m: float = 0.45
    solar_panel_mass_kg: float = 20.0
    belly_contact_x_m: list[float] = dc.field(default_factory=list)
    belly_contact_y_m: list[float] = dc.field(default_factory=list)
    drive_effort_limit_nm: float = 60.0
    max_rated_slope_deg: float = 25.0
    brake_torque_nm: float = 0.0
    drive_kp: float = 0.0
    drive_kd: float = 2000.0
    steer_effort_limit_nm: float = 40.0
    steer_kp: float = 200.0
    steer_kd: float = 20.0
    gimbal_effort_limit_nm: float = 10.0
    gimbal_kp: float = 20.0
    gimbal_kd: float = 1.0

    def __post_init__(self):
        self.validate()

    # ----------------------------------------------------------------------------------
    def validate(self) -> None:
        """Checks every field; raises ConfigError / OutOfRangeError naming the field."""
        for f in dc.fields(self):
            value = getattr(self, f.name)
            if f.type is float:
                if isinstance(value, bool) or not isinstance(value, (int, float)):
                    raise ConfigError(
                        f"{f.name} = {value!r} must be a number, not {type(value).__name__}"
                    )
            elif f.type is str:
                if not isinstance(value, str):
                    raise ConfigError(f"{f.name} = {value!r} must be a string")
            elif f.type == list[float]:
                if not isinstance(value, (list, tuple)) or any(
                    isinstance(v, bool) or not isinstance(v, (int, float)) for v in value
                ):
                    raise ConfigError(f"{f.name} = {value!r} must be a list of numbers")
        if not self.name:
            raise ConfigError("name = '' must be a non-empty string")
        if self.steering not in STEERING_KINDS:
            raise ConfigError(
                f"steering = {self.steering!r} is unknown; choose one of {list(STEERING_KINDS)}"
            )
        pos = dict(lo_open=True, unit=" m")
        _check("wheelbase_m", self.wheelbase_m, 0.0, 10.0, **pos)
        _check("wheel_radius_m", self.wheel_radius_m, 0.0, 5.0, **pos)
        _check("wheel_width_m", self.wheel_width_m, 0.0, 5.0, **pos)
        _check("track_m", self.track_m, self.wheel_width_m, 10.0, lo_open=True, unit=" m")
        _check("chassis_length_m", self.chassis_length_m, 0.0, 20.0, **pos)
        _check("chassis_width_m", self.chassis_width_m, 0.0, 20.0, **pos)
        _check("chassis_height_m", self.chassis_height_m, 0.0, 20.0, **pos)
        _check("ground_clearance_m", self.ground_clearance_m, 0.0, 5.0, unit=" m")
        kg = dict(lo_open=True, unit=" kg")
        _check("chassis_mass_kg", self.chassis_mass_kg, 0.0, 1.0e5, **kg)
        _check("wheel_mass_kg", self.wheel_mass_kg, 0.0, 1.0e4, **kg)
        _check("mast_mass_kg", self.mast_mass_kg, 0.0, 1.0e4, **kg)
        _check("gimbal_mass_kg", self.gimbal_mass_kg, 0.0, 1.0e4, **kg)
        _check("solar_panel_mass_kg", self.solar_panel_mass_kg, 0.0, 1.0e4, **kg)
        # Steering modules and rockers only exist on the explicit-steer rover.
        explicit = self.steering == "explicit"
        _check("steering_module_mass_kg", self.steering_module_mass_kg, 0.0, 1.0e4,
               lo_open=explicit, unit=" kg")  # fmt: skip
        _check("rocker_mass_kg", self.rocker_mass_kg, 0.0, 1.0e4, lo_open=explicit, unit=" kg")
        _check("rocker_limit_rad", self.rocker_limit_rad, 0.0, math.pi / 2, lo_open=True,
               unit=" rad")  # fmt: skip
        _check("steering_offset_m", self.steering_offset_m, 0.0, self.track_m / 2,
               hi_open=True, unit=" m (must stay inboard of the track half-width)")  # fmt: skip
        _check("steering_limit_rad", self.steering_limit_rad, 0.0, math.pi, lo_open=True,
               unit=" rad")  # fmt: skip
        half = self.chassis_length_m / 2
        _check("mast_x_m", self.mast_x_m, -half, half, unit=" m (on the chassis top)")
        _check("mast_height_m", self.mast_height_m, 0.0, 20.0, **pos)
        _check("camera_baseline_m", self.camera_baseline_m, 0.0, 5.0, **pos)
        for joint in ("pan", "tilt"):
            lo_name, hi_name = f"gimbal_{joint}_min_rad", f"gimbal_{joint}_max_rad"
            lo, hi = getattr(self, lo_name), getattr(self, hi_name)
            _check(lo_name, lo, -2 * math.pi, 0.0, unit=" rad (zero must be reachable)")
            _check(hi_name, hi, 0.0, 2 * math.pi, unit=" rad (zero must be reachable)")
            if not lo < hi:
                raise OutOfRangeError(f"{lo_name} = {lo!r} must be below {hi_name} = {hi!r}")
        _check("solar_panel_width_m", self.solar_panel_width_m, 0.0, 20.0, **pos)
        _check("solar_panel_height_m", self.solar_panel_height_m, 0.0, 20.0, **pos)
        _check("solar_panel_thickness_m", self.solar_panel_thickness_m, 0.0, 1.0, **pos)
        _check("solar_panel_tilt_rad", self.solar_panel_tilt_rad, -math.pi, math.pi,
               unit=" rad")  # fmt: skip
        _check("solar_panel_azimuth_rad", self.solar_panel_azimuth_rad, -2 * math.pi,
               2 * math.pi, unit=" rad")  # fmt: skip
        _check("solar_panel_x_m", self.solar_panel_x_m, -half, half, unit=" m (over the chassis)")
        _check("solar_panel_y_m", self.solar_panel_y_m, -self.chassis_width_m / 2,
               self.chassis_width_m / 2, unit=" m (over the chassis)")  # fmt: skip
        _check("solar_panel_mount_height_m", self.solar_panel_mount_height_m, 0.0, 20.0,
               unit=" m")  # fmt: skip
        if len(self.belly_contact_x_m) != len(self.belly_contact_y_m):
            raise ConfigError(
                f"belly_contact_x_m ({len(self.belly_contact_x_m)} values) and "
                f"belly_contact_y_m ({len(self.belly_contact_y_m)} values) must have the "
                "same length"
            )
        w = self.chassis_width_m / 2
        pairs = zip(self.belly_contact_x_m, self.belly_contact_y_m, strict=True)
        for i, (x, y) in enumerate(pairs):
            _check(f"belly_contact_x_m[{i}]", x, -half, half, unit=" m (on the chassis)")
            _check(f"belly_contact_y_m[{i}]", y, -w, w, unit=" m (on the chassis)")
        nm = dict(lo_open=True, unit=" N·m")
        _check("drive_effort_limit_nm", self.drive_effort_limit_nm, 0.0, 1.0e5, **nm)
        _check("steer_effort_limit_nm", self.steer_effort_limit_nm, 0.0, 1.0e5, **nm)
        _check("gimbal_effort_limit_nm", self.gimbal_effort_limit_nm, 0.0, 1.0e5, **nm)
        _check("max_rated_slope_deg", self.max_rated_slope_deg, 0.0, 60.0, lo_open=True,
               hi_open=True, unit=" deg")  # fmt: skip
        _check("brake_torque_nm", self.brake_torque_nm, 0.0, 1.0e5, unit=" N·m (0 = automatic)")
        _check("drive_kp", self.drive_kp, 0.0, 1.0e7, unit=" N·m/rad")
        _check("drive_kd", self.drive_kd, 0.0, 1.0e7, lo_open=True, unit=" N·m·s/rad")
        _check("steer_kp", self.steer_kp, 0.0, 1.0e7, lo_open=True, unit=" N·m/rad")
        _check("steer_kd", self.steer_kd, 0.0, 1.0e7, unit=" N·m·s/rad")
        _check("gimbal_kp", self.gimbal_kp, 0.0, 1.0e7, lo_open=True, unit=" N·m/rad")
        _check("gimbal_kd", self.gimbal_kd, 0.0, 1.0e7, unit=" N·m·s/rad")

    # ----------------------------------------------------------------------------------
    def total_mass_kg(self) -> float:
        """Mass of every body the model contains (kg); steering modules and rockers
        count only for ``steering == "explicit"``."""
        m = (
            self.chassis_mass_kg
            + 4 * self.wheel_mass_kg
            + self.mast_mass_kg
            + self.gimbal_mass_kg
            + self.solar_panel_mass_kg
        )
        if self.steering == "explicit":
            m += 4 * self.steering_module_mass_kg + 2 * self.rocker_mass_kg
        return m

    def brake_holding_torque_nm(self, *, gravity_mps2: float = GRAVITY_MPS2) -> float:
        """Holding torque of each wheel's parking brake (N·m).

        ``brake_torque_nm`` if it is set (> 0); otherwise automatic: the torque that holds
        the whole rover on a ``max_rated_slope_deg`` slope with all its weight on the
        wheels, shared by the four wheels, times :data:`BRAKE_SAFETY_FACTOR`::

            T = BRAKE_SAFETY_FACTOR * m g sin(max_rated_slope) * wheel_radius / 4

        (``m`` = :meth:`total_mass_kg`, ``g`` lunar gravity by default). The factor 2
        means any two wheels can hold the rover alone, which covers the uneven load split
        on a slope (the downhill wheels carry more).
        """
        if self.brake_torque_nm > 0.0:
            return float(self.brake_torque_nm)
        downslope = (
            self.total_mass_kg() * gravity_mps2 * math.sin(math.radians(self.max_rated_slope_deg))
        )
        return BRAKE_SAFETY_FACTOR * downslope * self.wheel_radius_m / 4.0

    def nominal_chassis_height_m(self) -> float:
        """Height of the chassis origin above level ground when the wheels just touch it
        with all joints at zero (m): ``ground_clearance_m + chassis_height_m / 2``."""
        return self.ground_clearance_m + self.chassis_height_m / 2

    def wheel_centres_C(self) -> np.ndarray:
        """(4, 3) wheel centres in C at zero joint angles, ordered fl, fr, rl, rr (m)."""
        a, b = self.wheelbase_m / 2, self.track_m / 2
        z = self.wheel_radius_m - self.nominal_chassis_height_m()
        return np.array([[a, b, z], [a, -b, z], [-a, b, z], [-a, -b, z]], dtype=float)

    def belly_contact_points_C(self) -> np.ndarray:
        """(N, 3) belly strike points on the chassis underside, in C (m)."""
        if self.belly_contact_x_m:
            x = np.asarray(self.belly_contact_x_m, dtype=float)
            y = np.asarray(self.belly_contact_y_m, dtype=float)
        else:
            gx = np.array([0.45, 0.0, -0.45]) * self.chassis_length_m
            gy = np.array([0.45, 0.0, -0.45]) * self.chassis_width_m
            x, y = (v.ravel() for v in np.meshgrid(gx, gy, indexing="ij"))
        z = np.full_like(x, -self.chassis_height_m / 2)
        return np.stack([x, y, z], axis=-1)

    def solar_panel_normal_C(self) -> np.ndarray:
        """Unit normal of the panel's active face in C."""
        t, a = self.solar_panel_tilt_rad, self.solar_panel_azimuth_rad
        return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


_check = check_range


# --------------------------------------------------------------------------------------
# Presets


def husky_rp() -> RoverDescription:
    """Skid-steer RP proxy: a Husky-class base carrying the RP mast, gimbal and panel.

    Base from Clearpath Husky A200 specs (from memory): 0.99 x 0.67 x 0.39 m overall,
    50 kg, 0.33 m (13 in) wheels, ~0.13 m ground clearance; ``husky_description`` URDF
    values (from memory): wheelbase 0.512 m, track 0.555 m, wheel radius 0.165 m, wheel
    width 0.114 m, wheel mass 2.64 kg. The chassis box (0.99 x 0.43 x 0.25 m) fits
    between the wheels and tops out at 0.38 m. Paper section 6 mounted the RP sensors on
    the Husky; mast, gimbal and panel masses and sizes here are assumptions, chosen so
    the cameras sit ~1.5 m above ground like on :func:`krex2_rp`. Drive torque limit
    30 N·m is an assumption, and so is the 20 deg rated parking slope (an assumption
    below the ~35 deg at which the lunar soil model lets a braked rover slide; note that
    this rover cannot *climb* 20 deg in that soil, see docs/rover.md).
    """
    return RoverDescription(
        name="husky_rp",
        steering="skid",
        wheelbase_m=0.512,
        track_m=0.555,
        wheel_radius_m=0.165,
        wheel_width_m=0.114,
        chassis_length_m=0.99,
        chassis_width_m=0.43,
        chassis_height_m=0.25,
        chassis_mass_kg=50.0 - 4 * 2.64,
        wheel_mass_kg=2.64,
        steering_module_mass_kg=0.0,
        rocker_mass_kg=0.0,
        mast_x_m=0.3,
        mast_height_m=1.1,
        mast_mass_kg=3.0,
        gimbal_mass_kg=2.0,
        camera_baseline_m=0.3,
        steering_offset_m=0.0,
        ground_clearance_m=0.13,
        solar_panel_width_m=0.5,
        solar_panel_height_m=0.5,
        solar_panel_thickness_m=0.02,
        solar_panel_mount_height_m=0.35,
        solar_panel_mass_kg=5.0,
        drive_effort_limit_nm=30.0,
        max_rated_slope_deg=20.0,
        drive_kd=300.0,
        gimbal_effort_limit_nm=5.0,
        gimbal_kp=10.0,
        gimbal_kd=0.5,
    )


def krex2_rp() -> RoverDescription:
    """Explicit-steer RP proxy: KRex2-style 4-wheel independent steering with RP's offset
    steering and a rocker/differencing-bar suspension (paper section 6, Fig. 13).

    Scale from the RP15 rover (Colaprete et al., NASA Resource Prospector; from memory):
    ~300 kg, ~1.4 x 1.4 m footprint, ~0.5 m wheel diameter. K-REX2 (NASA Ames Intelligent
    Robotics Group) supplies the kinematics: four steerable wheels, differencing bar.
    Here: wheel centres 1.2 x 1.2 m (so the 0.2 m wide wheels span 1.4 m across), wheel
    radius 0.25 m, mass split 180 kg chassis + 4 x 8 kg wheels + 4 x 10 kg steering
    modules + 2 x 8 kg rockers + 8 kg mast + 4 kg gimbal + 20 kg solar panel = 300 kg.
    The split, steering offset (0.1 m), ground clearance (0.3 m), mast height (cameras at
    ~1.55 m above ground), 0.3 m stereo baseline, the vertical left-facing 1.0 x 0.7 m
    panel (placed behind the mast) and the servo gains are assumptions, not published RP
    values. So is the 25 deg rated parking slope (the Apollo LRV's rated slope, from
    memory, taken as a typical lunar-rover design figure). A vertical panel suits a polar
    site, where the Sun stays within a few degrees of the horizon.
    """
    return RoverDescription()


_PRESETS = {
    "skid": husky_rp,
    "explicit": krex2_rp,
    "husky_rp": husky_rp,
    "krex2_rp": krex2_rp,
}

PRESET_NAMES = tuple(_PRESETS)
"""Names accepted by :func:`rover_preset`."""


def rover_preset(name: str) -> RoverDescription:
    """A preset description: ``skid`` (= ``husky_rp``) or ``explicit`` (= ``krex2_rp``).

    Raises:
        ConfigError: unknown name (the message lists the choices).
    """
    try:
        factory = _PRESETS[name]
    except (KeyError, TypeError):
        raise ConfigError(
            f"rover preset {name!r} is unknown; choose one of {list(PRESET_NAMES)}"
        ) from None
    return factory()


def rover_description_from_yaml(*, data: str, preset: str = "krex2_rp") -> RoverDescription:
    """Loads a YAML mapping of :class:`RoverDescription` fields over ``preset`` and
    validates the result (e.g. ``data="{camera_baseline_m: 0.4}"``).

    Raises:
        ConfigError: unknown preset or key, malformed value, value out of range.
    """
    base = rover_preset(preset)
    try:
        result = yaml_load_typed(schema=RoverDescription, data=data, defaults=base)
    except Exception as exc:  # Drake raises RuntimeError for schema mismatches.
        raise ConfigError(f"invalid rover description YAML: {exc}") from exc
    result.validate()
    return result
