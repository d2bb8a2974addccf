"""SDFormat rover models generated from a :class:`RoverDescription`, and ``add_rover``.

Paper section 6 simulated the RP rover twice: skid-steered (a Husky model) and
explicit-steered (KRex2 with RP's offset steering and a differencing bar), each with a
stereo pair on a mast-top gimbal and the solar-panel superstructure. This module writes
both as SDFormat 1.9 text (with Drake extensions) and parses it into a MultibodyPlant.

Frames (all right-handed; lengths in m):

* ``chassis`` body frame C = model frame: origin at the chassis box centre, x forward,
  y left, z up. The chassis is free-floating (Drake adds its floating joint, named
  ``chassis``, at Finalize); place it with ``plant.SetFreeBodyPose``. On level ground
  with the wheels just touching, C's origin is
  ``description.nominal_chassis_height_m()`` above the ground.
* ``wheel_fl/fr/rl/rr`` body frames W: origin at the wheel centre, axle along +y_W,
  parallel to C at zero joint angles. Drive joints ``wheel_xx_drive`` rotate W about
  +y_W; a positive rate rolls the wheel forward (+x). There are no contact frames: the
  terrain force element finds the contact point from the wheel centre, axle and radius.
* ``belly`` frame on the chassis: centre of the underside, axes of C.
* ``solar_panel`` body frame P: panel centre, active-face normal along +z_P (=
  ``description.solar_panel_normal_C()`` at rest), panel edges along x_P and y_P.
* ``left_camera`` / ``right_camera`` frames on the ``mast_head`` body (the tilt link):
  at +-baseline/2 along y of the head, on its front face. They follow Drake's camera
  convention (as ``RgbdSensor`` and ``CameraConfig`` expect): +z is the optical axis
  (forward, +x of the head), +x points to image right (-y of the head), +y to image down
  (-z of the head). At zero gimbal angles the optical axes are parallel to +x_C.
  ``gimbal_pan`` turns the head about +z (+ looks left), ``gimbal_tilt`` about +y of the
  yoke (+ looks down).

Skid rover: chassis -> wheel (``wheel_xx_drive``). Explicit rover: chassis ->
``rocker_left|right`` (``rocker_left|right_pivot``, pitch about +y at y = +-(track/2 -
steering_offset), x = 0) -> ``steer_module_xx`` (``steer_xx``, vertical axis through the
rocker end) -> wheel (``wheel_xx_drive``) whose centre is ``steering_offset_m`` outboard of
the steering axis. The differencing bar is ``<drake:mimic>``: rocker_right = -rocker_left,
which Drake enforces as a coupler constraint; it needs a discrete plant using the SAP
solver (approximations ``sap``, ``similar``, ``lagged``) or a continuous plant with the
CENIC integrator. ``add_rover`` refuses a discrete plant without SAP, where Drake would
silently drop the constraint (measured with pydrake 1.51.1: a warning, no coupling).

Actuators (Drake makes one per joint with a non-zero ``<effort>`` limit; joints that must
stay passive say ``<effort>0</effort>``, since SDFormat's default -1 means "unlimited"):
drive, steer and gimbal joints, each with ``<drake:controller_gains>`` so MultibodyPlant's
implicit PD (SAP) servos them when the model instance's desired-state input port is
connected (disarmed otherwise). Drives default to a pure velocity servo (kp = 0).

There is no collision geometry: wheel-terrain and belly-terrain forces come from a
separate force element reading the Heightfield. Visuals are simple boxes and cylinders.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import DiscreteContactSolver, MultibodyPlant
from pydrake.multibody.tree import (
    Frame,
    JointActuator,
    ModelInstanceIndex,
    RevoluteJoint,
    RigidBody,
)

from lunar_drake.errors import ConfigError, SimulationError
from lunar_drake.models.rover_description import RoverDescription
from lunar_drake.moon import GRAVITY_MPS2

WHEELS = ("fl", "fr", "rl", "rr")
"""Wheel labels in the order used everywhere: front-left, front-right, rear-left,
rear-right."""

_MAST_RADIUS_M = 0.025
_YOKE_SIZE_M = 0.06
_HEAD_DEPTH_M = 0.08
_HEAD_HEIGHT_M = 0.06
_MODULE_SECTION_M = 0.08
_ROCKER_SECTION_M = 0.06
# R_HC of a Drake camera frame C on the head H: Cx = -Hy, Cy = -Hz, Cz = +Hx.
_CAMERA_RPY = (-math.pi / 2, 0.0, -math.pi / 2)

_COLORS = {
    "chassis": "0.85 0.85 0.80 1",
    "wheel": "0.15 0.15 0.15 1",
    "spoke": "0.9 0.6 0.1 1",
    "metal": "0.6 0.6 0.65 1",
    "head": "0.2 0.3 0.6 1",
    "lens": "0.05 0.05 0.05 1",
    "panel": "0.1 0.15 0.45 1",
}


# --------------------------------------------------------------------------------------
# SDFormat text


def _f(x: float) -> str:
    return repr(float(x))


def _vec(*xs: float) -> str:
    return " ".join(_f(x) for x in xs)


def _inertial(mass: float, ixx: float, iyy: float, izz: float, xyz=(0.0, 0.0, 0.0)) -> str:
    return (
        f"<inertial><pose>{_vec(*xyz, 0, 0, 0)}</pose><mass>{_f(mass)}</mass>"
        f"<inertia><ixx>{_f(ixx)}</ixx><iyy>{_f(iyy)}</iyy><izz>{_f(izz)}</izz>"
        "<ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial>"
    )


def _box_inertial(mass: float, size, xyz=(0.0, 0.0, 0.0)) -> str:
    x, y, z = size
    return _inertial(
        mass, mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12,
        mass * (x * x + y * y) / 12, xyz,
    )  # fmt: skip


def _cylinder_inertial(mass: float, radius: float, length: float, axis: str, xyz=(0, 0, 0)):
    axial = mass * radius * radius / 2
    transverse = mass * (3 * radius * radius + length * length) / 12
    i = {"x": (axial, transverse, transverse), "y": (transverse, axial, transverse)}.get(
        axis, (transverse, transverse, axial)
    )
    return _inertial(mass, *i, xyz)


def _visual(name: str, geometry: str, color: str, pose=(0, 0, 0, 0, 0, 0)) -> str:
    return (
        f'<visual name="{name}"><pose>{_vec(*pose)}</pose><geometry>{geometry}</geometry>'
        f"<material><diffuse>{_COLORS[color]}</diffuse></material></visual>"
    )


def _box(size) -> str:
    return f"<box><size>{_vec(*size)}</size></box>"


def _cylinder(radius: float, length: float) -> str:
    return f"<cylinder><radius>{_f(radius)}</radius><length>{_f(length)}</length></cylinder>"


def _link(name: str, xyz, body: str, rpy=(0.0, 0.0, 0.0)) -> str:
    return f'<link name="{name}"><pose>{_vec(*xyz, *rpy)}</pose>{body}</link>'


def _joint(
    name: str,
    kind: str,
    parent: str,
    child: str,
    *,
    axis=None,
    lower=None,
    upper=None,
    effort: float = 0.0,
    gains=None,
    extra: str = "",
) -> str:
    inner = f"<parent>{parent}</parent><child>{child}</child>"
    if axis is not None:
        limit = ""
        if lower is not None:
            limit += f"<lower>{_f(lower)}</lower><upper>{_f(upper)}</upper>"
        limit += f"<effort>{_f(effort)}</effort>"
        inner += f"<axis><xyz>{_vec(*axis)}</xyz><limit>{limit}</limit></axis>"
    if gains is not None:
        inner += f'<drake:controller_gains p="{_f(gains[0])}" d="{_f(gains[1])}"/>'
    return f'<joint name="{name}" type="{kind}">{inner}{extra}</joint>'


def _wheel_link(d: RoverDescription, label: str, xyz) -> str:
    r, w = d.wheel_radius_m, d.wheel_width_m
    body = _cylinder_inertial(d.wheel_mass_kg, r, w, "y")
    body += _visual("tyre", _cylinder(r, w), "wheel", (0, 0, 0, math.pi / 2, 0, 0))
    # A stripe across the outer face so that wheel rotation is visible.
    side = 1.0 if label[1] == "l" else -1.0
    body += _visual(
        "stripe", _box((1.6 * r, 0.01, 0.15 * r)), "spoke", (0, side * (w / 2 + 0.005), 0, 0, 0, 0)
    )
    return _link(f"wheel_{label}", xyz, body)


def rover_sdf(description: RoverDescription, *, model_name: str = "rover") -> str:
    """SDFormat 1.9 text (with ``drake:`` extensions) of the rover; see the module
    docstring for links, joints, frames and conventions.

    Raises:
        ConfigError / OutOfRangeError: the description is invalid.
    """
    d = description
    if not isinstance(d, RoverDescription):
        raise ConfigError(f"description must be a RoverDescription, got {type(d).__name__}")
    d.validate()
    if not model_name or any(c in model_name for c in "<>&\"' ") or "::" in model_name:
        raise ConfigError(
            f"model_name = {model_name!r} must be non-empty, without spaces, quotes, <>& or ::"
        )
    L, W, H = d.chassis_length_m, d.chassis_width_m, d.chassis_height_m
    top = H / 2
    centres = d.wheel_centres_C()
    parts: list[str] = []

    # Chassis: box inertia, body + underside plate visuals, belly frame.
    chassis = _box_inertial(d.chassis_mass_kg, (L, W, H))
    chassis += _visual("body", _box((L, W, H)), "chassis")
    chassis += _visual("belly_plate", _box((0.9 * L, 0.9 * W, 0.01)), "metal",
                       (0, 0, -H / 2 - 0.005, 0, 0, 0))  # fmt: skip
    parts.append(_link("chassis", (0, 0, 0), chassis))
    parts.append(
        f'<frame name="belly" attached_to="chassis"><pose relative_to="chassis">'
        f"{_vec(0, 0, -H / 2, 0, 0, 0)}</pose></frame>"
    )

    drive_gains = (d.drive_kp, d.drive_kd)
    if d.steering == "skid":
        for label, xyz in zip(WHEELS, centres, strict=True):
            parts.append(_wheel_link(d, label, xyz))
            parts.append(
                _joint(f"wheel_{label}_drive", "continuous", "chassis", f"wheel_{label}",
                       axis=(0, 1, 0), effort=d.drive_effort_limit_nm, gains=drive_gains)
            )  # fmt: skip
    else:
        y_axis = d.track_m / 2 - d.steering_offset_m  # |y| of the steering axes and pivots
        a = d.wheelbase_m / 2
        leg = centres[0, 2]  # wheel-centre z relative to the pivot height (z_C = 0)
        for side, sign in (("left", 1.0), ("right", -1.0)):
            bar = (2 * a + _ROCKER_SECTION_M, _ROCKER_SECTION_M, _ROCKER_SECTION_M)
            rocker = _box_inertial(d.rocker_mass_kg, bar)
            rocker += _visual("bar", _box(bar), "metal")
            parts.append(_link(f"rocker_{side}", (0, sign * y_axis, 0), rocker))
            mimic = ""
            if side == "right":
                mimic = '<drake:mimic joint="rocker_left_pivot" multiplier="-1" offset="0"/>'
            parts.append(
                _joint(f"rocker_{side}_pivot", "revolute", "chassis", f"rocker_{side}",
                       axis=(0, 1, 0), lower=-d.rocker_limit_rad, upper=d.rocker_limit_rad,
                       effort=0.0, extra=mimic)
            )  # fmt: skip
        for label, xyz in zip(WHEELS, centres, strict=True):
            side = "left" if label[1] == "l" else "right"
            sign = 1.0 if side == "left" else -1.0
            post = (_MODULE_SECTION_M, _MODULE_SECTION_M, max(abs(leg), _MODULE_SECTION_M))
            module = _box_inertial(d.steering_module_mass_kg, post, (0, 0, leg / 2))
            module += _visual("post", _box(post), "metal", (0, 0, leg / 2, 0, 0, 0))
            if d.steering_offset_m > 0:
                arm = (_MODULE_SECTION_M / 2, d.steering_offset_m, _MODULE_SECTION_M / 2)
                module += _visual("arm", _box(arm), "metal",
                                  (0, sign * d.steering_offset_m / 2, leg, 0, 0, 0))  # fmt: skip
            parts.append(_link(f"steer_module_{label}", (xyz[0], sign * y_axis, 0), module))
            parts.append(
                _joint(f"steer_{label}", "revolute", f"rocker_{side}", f"steer_module_{label}",
                       axis=(0, 0, 1), lower=-d.steering_limit_rad, upper=d.steering_limit_rad,
                       effort=d.steer_effort_limit_nm, gains=(d.steer_kp, d.steer_kd))
            )  # fmt: skip
            parts.append(_wheel_link(d, label, xyz))
            parts.append(
                _joint(f"wheel_{label}_drive", "continuous", f"steer_module_{label}",
                       f"wheel_{label}", axis=(0, 1, 0), effort=d.drive_effort_limit_nm,
                       gains=drive_gains)
            )  # fmt: skip

    # Mast (welded), pan yoke, tilt head with the stereo pair.
    mh = d.mast_height_m
    mast = _cylinder_inertial(d.mast_mass_kg, _MAST_RADIUS_M, mh, "z", (0, 0, mh / 2))
    mast += _visual("tube", _cylinder(_MAST_RADIUS_M, mh), "metal", (0, 0, mh / 2, 0, 0, 0))
    parts.append(_link("mast", (d.mast_x_m, 0, top), mast))
    parts.append(_joint("mast_mount", "fixed", "chassis", "mast"))
    gimbal_xyz = (d.mast_x_m, 0, top + mh)
    yoke_size = (_YOKE_SIZE_M,) * 3
    yoke = _box_inertial(d.gimbal_mass_kg / 2, yoke_size)
    yoke += _visual("yoke", _box(yoke_size), "metal")
    parts.append(_link("gimbal_yoke", gimbal_xyz, yoke))
    gimbal_gains = (d.gimbal_kp, d.gimbal_kd)
    parts.append(
        _joint("gimbal_pan", "revolute", "mast", "gimbal_yoke", axis=(0, 0, 1),
               lower=d.gimbal_pan_min_rad, upper=d.gimbal_pan_max_rad,
               effort=d.gimbal_effort_limit_nm, gains=gimbal_gains)
    )  # fmt: skip
    b2 = d.camera_baseline_m / 2
    head_size = (_HEAD_DEPTH_M, d.camera_baseline_m + 0.08, _HEAD_HEIGHT_M)
    head = _box_inertial(d.gimbal_mass_kg / 2, head_size)
    head += _visual("head", _box(head_size), "head")
    for side, y in (("left", b2), ("right", -b2)):
        head += _visual(f"{side}_lens", _cylinder(0.02, 0.02), "lens",
                        (_HEAD_DEPTH_M / 2, y, 0, 0, math.pi / 2, 0))  # fmt: skip
    parts.append(_link("mast_head", gimbal_xyz, head))
    parts.append(
        _joint("gimbal_tilt", "revolute", "gimbal_yoke", "mast_head", axis=(0, 1, 0),
               lower=d.gimbal_tilt_min_rad, upper=d.gimbal_tilt_max_rad,
               effort=d.gimbal_effort_limit_nm, gains=gimbal_gains)
    )  # fmt: skip
    for side, y in (("left", b2), ("right", -b2)):
        parts.append(
            f'<frame name="{side}_camera" attached_to="mast_head">'
            f'<pose relative_to="mast_head">{_vec(_HEAD_DEPTH_M / 2, y, 0, *_CAMERA_RPY)}'
            "</pose></frame>"
        )

    # Solar panel superstructure (welded; visual only like everything else).
    panel_size = (d.solar_panel_height_m, d.solar_panel_width_m, d.solar_panel_thickness_m)
    panel = _box_inertial(d.solar_panel_mass_kg, panel_size)
    panel += _visual("cells", _box(panel_size), "panel")
    parts.append(
        _link("solar_panel",
              (d.solar_panel_x_m, d.solar_panel_y_m, top + d.solar_panel_mount_height_m), panel,
              rpy=(0.0, d.solar_panel_tilt_rad, d.solar_panel_azimuth_rad))
    )  # fmt: skip
    parts.append(_joint("solar_panel_mount", "fixed", "chassis", "solar_panel"))

    body = "\n    ".join(parts)
    return (
        '<?xml version="1.0"?>\n'
        '<sdf version="1.9" xmlns:drake="http://drake.mit.edu">\n'
        f'  <model name="{model_name}">\n'
        f"    <!-- {d.name}: {d.steering}-steer rover generated by lunar_drake -->\n"
        f"    {body}\n"
        "  </model>\n"
        "</sdf>\n"
    )


# --------------------------------------------------------------------------------------
# MultibodyPlant


@dc.dataclass(frozen=True, eq=False)
class RoverModel:
    """Handles to one rover in a MultibodyPlant, as returned by :func:`add_rover`.

    Wheel-indexed tuples are ordered fl, fr, rl, rr (:data:`WHEELS`). Joint and frame
    conventions are in the module docstring.

    Attributes:
        description: the description the model was built from.
        model_instance: the rover's model instance.
        chassis: the free-floating chassis body (frame C).
        wheels: wheel bodies (frame W at the wheel centre, axle +y_W).
        drive_joints: wheel drive joints (continuous revolute about +y_W).
        steer_joints: steering joints (explicit only; else empty).
        rocker_joints: (left, right) rocker pivots (explicit only; else empty); coupled
            so that right = -left.
        gimbal_pan, gimbal_tilt: gimbal joints.
        drive_actuators, steer_actuators, gimbal_actuators: the PD-servoed actuators
            (gimbal: pan, tilt). Actuator names equal their joint names.
        left_camera, right_camera: camera frames (Drake camera convention).
        belly: frame at the centre of the chassis underside.
        solar_panel: panel body frame (normal +z).
        belly_points_C: (N, 3) belly strike points in C (m).
        total_mass_kg: sum of the instance's body masses, from the plant (kg).
        static_wheel_load_N: vertical wheel loads on level ground in lunar gravity, from
            the parsed model's CoM and wheel positions (N; see
            :func:`static_wheel_loads`).
        nominal_chassis_height_m: chassis origin height above level ground with the
            wheels just touching (m).
    """

    description: RoverDescription
    model_instance: ModelInstanceIndex
    chassis: RigidBody
    wheels: tuple
    drive_joints: tuple
    steer_joints: tuple
    rocker_joints: tuple
    gimbal_pan: RevoluteJoint
    gimbal_tilt: RevoluteJoint
    drive_actuators: tuple
    steer_actuators: tuple
    gimbal_actuators: tuple
    left_camera: Frame
    right_camera: Frame
    belly: Frame
    solar_panel: Frame
    belly_points_C: np.ndarray
    total_mass_kg: float
    static_wheel_load_N: tuple
    nominal_chassis_height_m: float


def _actuator(plant: MultibodyPlant, name: str, instance) -> JointActuator:
    return plant.GetJointActuatorByName(name, instance)


def _handles(plant, instance, d: RoverDescription) -> dict:
    joint = plant.GetJointByName
    explicit = d.steering == "explicit"
    drive = tuple(joint(f"wheel_{w}_drive", instance) for w in WHEELS)
    steer = tuple(joint(f"steer_{w}", instance) for w in WHEELS) if explicit else ()
    rockers = (
        (joint("rocker_left_pivot", instance), joint("rocker_right_pivot", instance))
        if explicit
        else ()
    )
    return dict(
        model_instance=instance,
        chassis=plant.GetBodyByName("chassis", instance),
        wheels=tuple(plant.GetBodyByName(f"wheel_{w}", instance) for w in WHEELS),
        drive_joints=drive,
        steer_joints=steer,
        rocker_joints=rockers,
        gimbal_pan=joint("gimbal_pan", instance),
        gimbal_tilt=joint("gimbal_tilt", instance),
        drive_actuators=tuple(_actuator(plant, j.name(), instance) for j in drive),
        steer_actuators=tuple(_actuator(plant, j.name(), instance) for j in steer),
        gimbal_actuators=(
            _actuator(plant, "gimbal_pan", instance),
            _actuator(plant, "gimbal_tilt", instance),
        ),
        left_camera=plant.GetFrameByName("left_camera", instance),
        right_camera=plant.GetFrameByName("right_camera", instance),
        belly=plant.GetFrameByName("belly", instance),
        solar_panel=plant.GetFrameByName("solar_panel", instance),
    )


def _solve_wheel_loads(p_CW: np.ndarray, p_CCm: np.ndarray, weight: float, pivots_x=None):
    """Vertical loads at wheel centres p_CW (4, 3) balancing ``weight`` at p_CCm.

    Rigid four-wheel chassis: statically indeterminate; returns the minimum-norm solution,
    which is the load of a rigid plate on four equal vertical springs. With a
    differencing bar (``pivots_x`` = rocker pivot x of left and right), the equal-torque
    condition on the two rockers makes the problem determinate and is added as a fourth
    equation.
    """
    x, y = p_CW[:, 0], p_CW[:, 1]
    A = np.stack([np.ones(4), x, y])
    b = weight * np.array([1.0, p_CCm[0], p_CCm[1]])
    if pivots_x is None:
        return A.T @ np.linalg.solve(A @ A.T, b)
    # Torques of the wheel loads about the rocker pivots must match (virtual work with
    # q_right = -q_left): sum_left F (x - xl) - sum_right F (x - xr) = 0.
    left = np.array([1.0, 0.0, 1.0, 0.0])
    bar = left * (x - pivots_x[0]) - (1 - left) * (x - pivots_x[1])
    return np.linalg.solve(np.vstack([A, bar]), np.append(b, 0.0))


def static_wheel_loads(
    plant: MultibodyPlant,
    rover: RoverModel,
    *,
    context=None,
    gravity_mps2: float = GRAVITY_MPS2,
) -> np.ndarray:
    """Vertical wheel loads (N, ordered fl, fr, rl, rr) with the chassis level and gravity
    along -z_C, from the finalized plant's CoM and wheel centres in ``context`` (default
    context if None). Negative loads mean that wheel would lift off.

    Skid: minimum-norm (equal-stiffness) distribution, since four rigid supports are
    statically indeterminate. Explicit: exact, with the differencing-bar equal-torque
    condition.
    """
    if not plant.is_finalized():
        raise SimulationError("static_wheel_loads needs a finalized plant")
    context = plant.CreateDefaultContext() if context is None else context
    X_CW = plant.EvalBodyPoseInWorld(context, rover.chassis).inverse()
    p_CCm = X_CW @ plant.CalcCenterOfMassPositionInWorld(context, [rover.model_instance])
    p_CWh = np.array(
        [X_CW @ plant.EvalBodyPoseInWorld(context, w).translation() for w in rover.wheels]
    )
    pivots = None
    if rover.rocker_joints:
        pivots = [
            (X_CW @ plant.EvalBodyPoseInWorld(context, j.child_body()).translation())[0]
            for j in rover.rocker_joints
        ]
    weight = plant.CalcTotalMass(context, [rover.model_instance]) * gravity_mps2
    return _solve_wheel_loads(p_CWh, p_CCm, weight, pivots)


def level_wheel_loads(description: RoverDescription) -> np.ndarray:
    """Vertical wheel loads (N; fl, fr, rl, rr) on level ground in lunar gravity, from a
    private, finalized copy of the rover model (:func:`static_wheel_loads`)."""
    scratch = MultibodyPlant(0.0)
    (instance,) = Parser(scratch).AddModelsFromString(rover_sdf(description), "sdf")
    scratch.Finalize()
    total_mass = sum(scratch.get_body(i).default_mass() for i in scratch.GetBodyIndices(instance))
    rover = RoverModel(
        description=description,
        belly_points_C=np.zeros((0, 3)),
        total_mass_kg=total_mass,
        static_wheel_load_N=(),
        nominal_chassis_height_m=0.0,
        **_handles(scratch, instance, description),
    )
    return static_wheel_loads(scratch, rover)


def _check_plant_supports(plant: MultibodyPlant, d: RoverDescription) -> None:
    if plant.is_finalized():
        raise SimulationError("add_rover needs a plant that is not finalized yet")
    if d.steering == "explicit" and plant.time_step() > 0:
        if plant.get_discrete_contact_solver() != DiscreteContactSolver.kSap:
            raise ConfigError(
                "the explicit-steer rover's differencing bar is a coupler constraint, "
                "which a discrete MultibodyPlant only enforces with the SAP solver; set "
                "discrete_contact_approximation to 'sap', 'similar' or 'lagged' (got "
                f"{plant.get_discrete_contact_approximation()})"
            )


def add_rover(
    plant: MultibodyPlant, *, description: RoverDescription, model_name: str = "rover"
) -> RoverModel:
    """Parses :func:`rover_sdf` into ``plant`` (not yet finalized) and returns handles.

    The plant may have a SceneGraph (visual geometry is then registered; there is no
    collision geometry) or not. ``static_wheel_load_N`` is computed on a private,
    finalized copy of the same model.

    Raises:
        ConfigError: invalid description or model name, or an explicit-steer rover in a
            discrete plant whose contact solver is not SAP.
        SimulationError: the plant is already finalized.
    """
    sdf = rover_sdf(description, model_name=model_name)
    _check_plant_supports(plant, description)
    (instance,) = Parser(plant).AddModelsFromString(sdf, "sdf")
    handles = _handles(plant, instance, description)
    total_mass = sum(plant.get_body(i).default_mass() for i in plant.GetBodyIndices(instance))
    loads = level_wheel_loads(description)
    return RoverModel(
        description=description,
        belly_points_C=description.belly_contact_points_C(),
        total_mass_kg=float(total_mass),
        static_wheel_load_N=tuple(float(v) for v in loads),
        nominal_chassis_height_m=description.nominal_chassis_height_m(),
        **handles,
    )
