"""Rover descriptions, generated SDFormat and the parsed MultibodyPlant models."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
import pytest
from pydrake.common.yaml import yaml_dump_typed
from pydrake.geometry import Box, Cylinder, Role
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lunar_drake.errors import ConfigError, OutOfRangeError, SimulationError
from lunar_drake.models.rover_description import (
    PRESET_NAMES,
    RoverDescription,
    husky_rp,
    krex2_rp,
    rover_description_from_yaml,
    rover_preset,
)
from lunar_drake.models.rover_sdf import (
    WHEELS,
    add_rover,
    rover_sdf,
    static_wheel_loads,
)
from lunar_drake.moon import GRAVITY_MPS2

PRESETS = {"husky_rp": husky_rp, "krex2_rp": krex2_rp}


def build(description, *, approximation="sap", finalize=True, desired_port=False):
    """A SAP plant (+SceneGraph) holding one rover; returns (diagram, plant, scene_graph,
    rover). With ``desired_port`` the rover's desired-state port is exported."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=0.005, discrete_contact_approximation=approximation),
        builder,
    )
    rover = add_rover(plant, description=description)
    if not finalize:
        return None, plant, scene_graph, rover
    plant.Finalize()
    if desired_port:
        builder.ExportInput(plant.get_desired_state_input_port(rover.model_instance), "x_d")
    return builder.Build(), plant, scene_graph, rover


@pytest.fixture(scope="module", params=sorted(PRESETS))
def built(request):
    description = PRESETS[request.param]()
    _, plant, scene_graph, rover = build(description)
    return description, plant, scene_graph, rover


def pose_in_chassis(plant, context, rover, frame):
    X_WC = plant.EvalBodyPoseInWorld(context, rover.chassis)
    return X_WC.inverse() @ frame.CalcPoseInWorld(context)


# ---------------------------------------------------------------------------------------
# Parsed structure


def test_total_mass_matches_description(built):
    description, plant, _, rover = built
    context = plant.CreateDefaultContext()
    expected = description.total_mass_kg()
    assert rover.total_mass_kg == pytest.approx(expected, rel=1e-12)
    assert plant.CalcTotalMass(context, [rover.model_instance]) == pytest.approx(expected, 1e-12)
    assert expected == pytest.approx(60.0 if description.steering == "skid" else 300.0)


def test_joint_body_and_frame_names(built):
    description, plant, _, rover = built
    inst = rover.model_instance
    joints = {plant.get_joint(j).name() for j in plant.GetJointIndices(inst)}
    expected = {f"wheel_{w}_drive" for w in WHEELS} | {
        "gimbal_pan", "gimbal_tilt", "mast_mount", "solar_panel_mount", "chassis",
    }  # fmt: skip
    if description.steering == "explicit":
        expected |= {f"steer_{w}" for w in WHEELS} | {"rocker_left_pivot", "rocker_right_pivot"}
    assert joints == expected
    for name in ("left_camera", "right_camera", "belly", "solar_panel", "mast_head"):
        assert plant.HasFrameNamed(name, inst)
    assert rover.chassis.name() == "chassis"
    assert rover.chassis.is_floating_base_body()
    assert [w.name() for w in rover.wheels] == [f"wheel_{w}" for w in WHEELS]
    assert [j.name() for j in rover.drive_joints] == [f"wheel_{w}_drive" for w in WHEELS]
    assert rover.left_camera.body().name() == "mast_head"
    assert rover.right_camera.body().name() == "mast_head"


def test_actuators_and_gains(built):
    description, plant, _, rover = built
    inst = rover.model_instance
    names = [plant.get_joint_actuator(i).name() for i in plant.GetJointActuatorIndices(inst)]
    expected = {f"wheel_{w}_drive" for w in WHEELS} | {"gimbal_pan", "gimbal_tilt"}
    if description.steering == "explicit":
        expected |= {f"steer_{w}" for w in WHEELS}
        assert not any("rocker" in n for n in names)  # passive suspension
    assert set(names) == expected
    assert plant.num_actuators() == len(expected) == (10 if rover.steer_joints else 6)
    for act in rover.drive_actuators:
        assert act.has_controller()
        assert act.get_controller_gains().p == description.drive_kp
        assert act.get_controller_gains().d == description.drive_kd
        assert act.effort_limit() == description.drive_effort_limit_nm
    for act in rover.steer_actuators:
        assert (act.get_controller_gains().p, act.get_controller_gains().d) == (
            description.steer_kp,
            description.steer_kd,
        )
    for act in rover.gimbal_actuators:
        assert act.get_controller_gains().p == description.gimbal_kp
        assert act.effort_limit() == description.gimbal_effort_limit_nm
    assert [a.joint().name() for a in rover.gimbal_actuators] == ["gimbal_pan", "gimbal_tilt"]


def test_joint_limits(built):
    description, _, _, rover = built
    for joint in rover.drive_joints:
        assert np.isinf(joint.position_lower_limits()[0])
        assert np.isinf(joint.position_upper_limits()[0])
    for joint in rover.steer_joints:
        assert joint.position_lower_limits()[0] == -description.steering_limit_rad
        assert joint.position_upper_limits()[0] == description.steering_limit_rad
    for joint in rover.rocker_joints:
        assert joint.position_upper_limits()[0] == description.rocker_limit_rad
    assert rover.gimbal_pan.position_lower_limits()[0] == description.gimbal_pan_min_rad
    assert rover.gimbal_pan.position_upper_limits()[0] == description.gimbal_pan_max_rad
    assert rover.gimbal_tilt.position_lower_limits()[0] == description.gimbal_tilt_min_rad
    assert rover.gimbal_tilt.position_upper_limits()[0] == description.gimbal_tilt_max_rad


def test_wheel_centres_match_wheelbase_and_track(built):
    description, plant, _, rover = built
    context = plant.CreateDefaultContext()
    plant.SetFreeBodyPose(context, rover.chassis, RigidTransform([3.0, -2.0, 1.0]))
    a, b = description.wheelbase_m / 2, description.track_m / 2
    z = description.wheel_radius_m - description.ground_clearance_m
    z -= description.chassis_height_m / 2
    expected = np.array([[a, b, z], [a, -b, z], [-a, b, z], [-a, -b, z]])
    got = np.array([pose_in_chassis(plant, context, rover, w.body_frame()).translation()
                    for w in rover.wheels])  # fmt: skip
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # The wheel bottoms touch level ground at the nominal chassis height.
    assert z - description.wheel_radius_m == pytest.approx(-rover.nominal_chassis_height_m)


def test_offset_steering_swings_wheel_about_the_steering_axis():
    description = krex2_rp()
    _, plant, _, rover = build(description)
    context = plant.CreateDefaultContext()
    a, b, e = description.wheelbase_m / 2, description.track_m / 2, description.steering_offset_m
    theta = 0.7
    rover.steer_joints[0].set_angle(context, theta)  # front-left, steering axis at y = b - e
    p = pose_in_chassis(plant, context, rover, rover.wheels[0].body_frame()).translation()
    np.testing.assert_allclose(p[:2], [a - e * math.sin(theta), b - e + e * math.cos(theta)],
                               atol=1e-12)  # fmt: skip
    # The axle turns with the module.
    R = pose_in_chassis(plant, context, rover, rover.wheels[0].body_frame()).rotation()
    np.testing.assert_allclose(R.matrix()[:, 1], [-math.sin(theta), math.cos(theta), 0], atol=1e-12)
    # Steering axes sit at y = +-(track/2 - offset): the right-front swings the mirror way.
    rover.steer_joints[1].set_angle(context, theta)
    p = pose_in_chassis(plant, context, rover, rover.wheels[1].body_frame()).translation()
    np.testing.assert_allclose(p[:2], [a + e * math.sin(theta), -(b - e) - e * math.cos(theta)],
                               atol=1e-12)  # fmt: skip


def test_no_collision_geometry_and_visuals_present(built):
    _, plant, scene_graph, rover = built
    inspector = scene_graph.model_inspector()
    assert inspector.NumGeometriesWithRole(Role.kProximity) == 0
    assert inspector.NumGeometriesWithRole(Role.kIllustration) > 10
    for body in (rover.chassis, *rover.wheels):
        assert plant.GetVisualGeometriesForBody(body)
        assert not plant.GetCollisionGeometriesForBody(body)


def test_dimensions_round_trip_through_scene_graph(built):
    description, plant, scene_graph, rover = built
    inspector = scene_graph.model_inspector()

    def shapes(body, kind):
        ids = plant.GetVisualGeometriesForBody(body)
        return [inspector.GetShape(i) for i in ids if isinstance(inspector.GetShape(i), kind)]

    for wheel in rover.wheels:
        (tyre,) = shapes(wheel, Cylinder)
        assert tyre.radius() == description.wheel_radius_m
        assert tyre.length() == description.wheel_width_m
    body = max(shapes(rover.chassis, Box), key=lambda s: s.depth())
    assert (body.width(), body.depth(), body.height()) == (
        description.chassis_length_m,
        description.chassis_width_m,
        description.chassis_height_m,
    )
    panel = plant.GetBodyByName("solar_panel", rover.model_instance)
    (cells,) = shapes(panel, Box)
    assert (cells.width(), cells.depth(), cells.height()) == (
        description.solar_panel_height_m,
        description.solar_panel_width_m,
        description.solar_panel_thickness_m,
    )


def test_description_yaml_round_trip():
    for factory in PRESETS.values():
        d = dc.replace(factory(), belly_contact_x_m=[0.1, -0.1], belly_contact_y_m=[0.0, 0.05])
        preset = "krex2_rp" if d.steering == "skid" else "husky_rp"  # load over the other one
        assert rover_description_from_yaml(data=yaml_dump_typed(d), preset=preset) == d


# ---------------------------------------------------------------------------------------
# Cameras, gimbal, panel, belly


def test_camera_frames_follow_drake_camera_convention(built):
    description, plant, _, rover = built
    context = plant.CreateDefaultContext()
    X_CL = pose_in_chassis(plant, context, rover, rover.left_camera)
    X_CR = pose_in_chassis(plant, context, rover, rover.right_camera)
    R = X_CL.rotation().matrix()
    np.testing.assert_allclose(R[:, 2], [1, 0, 0], atol=1e-12)  # optical axis forward
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)  # image right = chassis right
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image down
    np.testing.assert_allclose(X_CR.rotation().matrix(), R, atol=1e-12)
    p_L, p_R = X_CL.translation(), X_CR.translation()
    np.testing.assert_allclose(p_L - p_R, [0, description.camera_baseline_m, 0], atol=1e-12)
    top = description.chassis_height_m / 2
    assert p_L[2] == pytest.approx(top + description.mast_height_m, abs=1e-12)
    assert (p_L[0] + p_R[0]) / 2 > description.mast_x_m  # on the head's front face

    # Pan + looks left, tilt + looks down.
    rover.gimbal_pan.set_angle(context, 0.4)
    z = pose_in_chassis(plant, context, rover, rover.left_camera).rotation().matrix()[:, 2]
    np.testing.assert_allclose(z, [math.cos(0.4), math.sin(0.4), 0], atol=1e-12)
    rover.gimbal_pan.set_angle(context, 0.0)
    rover.gimbal_tilt.set_angle(context, 0.3)
    z = pose_in_chassis(plant, context, rover, rover.left_camera).rotation().matrix()[:, 2]
    np.testing.assert_allclose(z, [math.cos(0.3), 0, -math.sin(0.3)], atol=1e-12)


@pytest.mark.parametrize(
    "field, value",
    [("camera_baseline_m", 0.5), ("mast_height_m", 1.4), ("mast_x_m", -0.2)],
)
def test_varying_the_description_moves_the_cameras(field, value):
    base = husky_rp()
    varied = dc.replace(base, **{field: value})
    poses = []
    for d in (base, varied):
        _, plant, _, rover = build(d)
        context = plant.CreateDefaultContext()
        poses.append([pose_in_chassis(plant, context, rover, f).translation()
                      for f in (rover.left_camera, rover.right_camera)])  # fmt: skip
    (l0, r0), (l1, r1) = poses
    if field == "camera_baseline_m":
        assert l1[1] - r1[1] == pytest.approx(value)
        assert l0[1] - r0[1] == pytest.approx(base.camera_baseline_m)
        np.testing.assert_allclose([l1[0], l1[2]], [l0[0], l0[2]])
    elif field == "mast_height_m":
        np.testing.assert_allclose(l1 - l0, [0, 0, value - base.mast_height_m], atol=1e-12)
    else:
        np.testing.assert_allclose(r1 - r0, [value - base.mast_x_m, 0, 0], atol=1e-12)


def test_solar_panel_frame_and_belly(built):
    description, plant, _, rover = built
    context = plant.CreateDefaultContext()
    X_CP = pose_in_chassis(plant, context, rover, rover.solar_panel)
    np.testing.assert_allclose(X_CP.rotation().matrix()[:, 2],
                               description.solar_panel_normal_C(), atol=1e-12)  # fmt: skip
    top = description.chassis_height_m / 2
    np.testing.assert_allclose(
        X_CP.translation(),
        [description.solar_panel_x_m, description.solar_panel_y_m,
         top + description.solar_panel_mount_height_m],
        atol=1e-12,
    )  # fmt: skip
    # The panel (half-width along its horizontal edge) clears the mast.
    edge = np.abs(X_CP.rotation().matrix()[:2, 1]) * description.solar_panel_width_m / 2
    assert description.solar_panel_x_m + edge[0] < description.mast_x_m - 0.05
    X_CB = pose_in_chassis(plant, context, rover, rover.belly)
    np.testing.assert_allclose(X_CB.translation(), [0, 0, -top], atol=1e-12)
    pts = rover.belly_points_C
    assert pts.shape == (9, 3)
    np.testing.assert_allclose(pts[:, 2], -top)
    assert pts[:, 0].max() == pytest.approx(0.45 * description.chassis_length_m)
    assert pts[:, 1].min() == pytest.approx(-0.45 * description.chassis_width_m)


def test_custom_belly_points_and_panel_normal():
    d = dc.replace(husky_rp(), belly_contact_x_m=[0.2, -0.3], belly_contact_y_m=[0.1, 0.0],
                   solar_panel_tilt_rad=0.0)  # fmt: skip
    np.testing.assert_allclose(d.belly_contact_points_C(), [[0.2, 0.1, -0.125], [-0.3, 0, -0.125]])
    np.testing.assert_allclose(d.solar_panel_normal_C(), [0, 0, 1], atol=1e-15)
    d = dc.replace(d, solar_panel_tilt_rad=math.pi / 2, solar_panel_azimuth_rad=0.0)
    np.testing.assert_allclose(d.solar_panel_normal_C(), [1, 0, 0], atol=1e-15)


# ---------------------------------------------------------------------------------------
# Dynamics: differencing bar and servos


def test_differencing_bar_couples_the_rockers():
    diagram, plant, _, rover = build(krex2_rp())
    simulator = Simulator(diagram)
    context = plant.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    left, right = rover.rocker_joints
    left.set_angle(context, 0.1)  # violates right = -left; the bar must restore it
    left.set_angular_rate(context, 0.3)
    simulator.AdvanceTo(0.5)
    q_left, q_right = left.get_angle(context), right.get_angle(context)
    assert abs(q_right) > 0.02  # the right rocker moved ...
    assert q_right == pytest.approx(-q_left, abs=1e-4)  # ... opposite to the left
    assert left.get_angular_rate(context) == pytest.approx(-right.get_angular_rate(context),
                                                           abs=1e-3)  # fmt: skip


def test_implicit_pd_servos_track_commands():
    diagram, plant, _, rover = build(krex2_rp(), desired_port=True)
    inst = rover.model_instance
    names = [plant.get_joint_actuator(i).name() for i in plant.GetJointActuatorIndices(inst)]
    n = len(names)
    q_d, v_d = np.zeros(n), np.zeros(n)
    q_d[names.index("steer_fr")] = 0.5
    q_d[names.index("gimbal_tilt")] = 0.3
    v_d[names.index("wheel_rl_drive")] = 2.0
    context = diagram.CreateDefaultContext()
    diagram.get_input_port(0).FixValue(context, np.concatenate([q_d, v_d]))
    simulator = Simulator(diagram, context)
    simulator.AdvanceTo(0.5)
    pc = plant.GetMyContextFromRoot(context)
    assert rover.steer_joints[1].get_angle(pc) == pytest.approx(0.5, abs=0.01)
    assert rover.steer_joints[0].get_angle(pc) == pytest.approx(0.0, abs=0.01)
    assert rover.gimbal_tilt.get_angle(pc) == pytest.approx(0.3, abs=0.01)
    assert rover.drive_joints[2].get_angular_rate(pc) == pytest.approx(2.0, abs=0.02)
    assert rover.drive_joints[3].get_angular_rate(pc) == pytest.approx(0.0, abs=0.02)


def test_explicit_rover_refuses_a_solver_that_drops_the_bar():
    builder = DiagramBuilder()
    plant, _ = AddMultibodyPlant(
        MultibodyPlantConfig(time_step=0.005, discrete_contact_approximation="tamsi"), builder
    )
    with pytest.raises(ConfigError, match="SAP"):
        add_rover(plant, description=krex2_rp())
    add_rover(plant, description=husky_rp())  # skid has no constraint: accepted


def test_add_rover_needs_an_unfinalized_plant_and_unique_names():
    plant = MultibodyPlant(0.005)
    add_rover(plant, description=husky_rp(), model_name="a")
    add_rover(plant, description=krex2_rp(), model_name="b")
    with pytest.raises(ConfigError, match="model_name"):
        add_rover(plant, description=husky_rp(), model_name="bad name")
    plant.Finalize()
    assert plant.num_actuators() == 16
    with pytest.raises(SimulationError, match="finalized"):
        add_rover(plant, description=husky_rp(), model_name="c")


# ---------------------------------------------------------------------------------------
# Static wheel loads


def test_static_wheel_loads_balance_weight_and_moments(built):
    description, plant, _, rover = built
    loads = np.array(rover.static_wheel_load_N)
    weight = description.total_mass_kg() * GRAVITY_MPS2
    assert loads.sum() == pytest.approx(weight, rel=1e-12)
    context = plant.CreateDefaultContext()
    np.testing.assert_allclose(static_wheel_loads(plant, rover, context=context), loads)
    p_WCm = plant.CalcCenterOfMassPositionInWorld(context, [rover.model_instance])
    x = np.array([w.EvalPoseInWorld(context).translation()[0] for w in rover.wheels])
    y = np.array([w.EvalPoseInWorld(context).translation()[1] for w in rover.wheels])
    assert loads @ x == pytest.approx(weight * p_WCm[0], abs=1e-9)
    assert loads @ y == pytest.approx(weight * p_WCm[1], abs=1e-9)
    # Rectangle of wheels: F_i = W/4 (1 + x_c x_i / a^2 + y_c y_i / b^2).
    a, b = description.wheelbase_m / 2, description.track_m / 2
    expected = weight / 4 * (1 + p_WCm[0] * x / a**2 + p_WCm[1] * y / b**2)
    np.testing.assert_allclose(loads, expected, rtol=1e-12)
    assert p_WCm[0] > 0 and loads[0] > loads[2]  # the mast is forward: fronts carry more


def test_static_wheel_loads_follow_the_centre_of_mass():
    base = krex2_rp()
    heavy_front = dc.replace(base, mast_x_m=0.7, mast_mass_kg=60.0)
    l0 = np.array(build(base)[3].static_wheel_load_N)
    l1 = np.array(build(heavy_front)[3].static_wheel_load_N)
    assert l1.sum() == pytest.approx(l0.sum() + 52.0 * GRAVITY_MPS2)
    assert l1[0] - l1[2] > l0[0] - l0[2] > 0
    # Differencing bar: both rockers carry the same front-rear torque.
    assert l1[0] - l1[2] == pytest.approx(l1[1] - l1[3])


# ---------------------------------------------------------------------------------------
# Descriptions and validation


def test_presets_and_aliases():
    assert rover_preset("skid") == husky_rp()
    assert rover_preset("explicit") == krex2_rp() == RoverDescription()
    assert set(PRESET_NAMES) == {"skid", "explicit", "husky_rp", "krex2_rp"}
    h = husky_rp()
    assert (h.steering, h.wheelbase_m, h.track_m, h.wheel_radius_m) == ("skid", 0.512, 0.555, 0.165)
    with pytest.raises(ConfigError, match="husky_rp"):
        rover_preset("rover9000")


@pytest.mark.parametrize(
    "field, value",
    [
        ("wheelbase_m", 0.0),
        ("wheel_radius_m", -0.1),
        ("track_m", 0.1),  # narrower than the wheel width
        ("chassis_mass_kg", 0.0),
        ("wheel_mass_kg", float("nan")),
        ("steering_module_mass_kg", 0.0),  # explicit rover needs real modules
        ("rocker_mass_kg", -1.0),
        ("steering_offset_m", 0.6),  # = track/2: axis would sit on the centreline
        ("steering_limit_rad", 4.0),
        ("camera_baseline_m", 0.0),
        ("mast_height_m", -1.0),
        ("mast_x_m", 0.8),  # off the 1.4 m chassis
        ("gimbal_pan_min_rad", 0.1),  # zero would be out of range
        ("gimbal_tilt_max_rad", -0.2),
        ("ground_clearance_m", -0.01),
        ("solar_panel_thickness_m", 0.0),
        ("solar_panel_x_m", -0.71),
        ("drive_kd", 0.0),
        ("steer_effort_limit_nm", 0.0),
    ],
)
def test_out_of_range_fields_are_named(field, value):
    with pytest.raises(OutOfRangeError, match=field):
        dc.replace(krex2_rp(), **{field: value})


def test_other_validation_errors():
    with pytest.raises(ConfigError, match=r"steering = 'tank'.*\['skid', 'explicit'\]"):
        dc.replace(krex2_rp(), steering="tank")
    with pytest.raises(ConfigError, match="belly_contact_x_m"):
        dc.replace(krex2_rp(), belly_contact_x_m=[0.1])
    with pytest.raises(OutOfRangeError, match=r"belly_contact_y_m\[0\]"):
        dc.replace(krex2_rp(), belly_contact_x_m=[0.1], belly_contact_y_m=[2.0])
    with pytest.raises(ConfigError, match="wheelbase_m"):
        dc.replace(krex2_rp(), wheelbase_m="long")
    # Skid rovers have no modules or rockers, so zero masses are fine there.
    assert husky_rp().steering_module_mass_kg == 0.0
    # A description mutated after construction is re-validated when used.
    d = krex2_rp()
    d.wheel_radius_m = -1.0
    with pytest.raises(OutOfRangeError, match="wheel_radius_m"):
        rover_sdf(d)


def test_yaml_overrides_load_and_validate():
    d = rover_description_from_yaml(data="{camera_baseline_m: 0.42, mast_height_m: 1.3}",
                                    preset="skid")  # fmt: skip
    assert d == dc.replace(husky_rp(), camera_baseline_m=0.42, mast_height_m=1.3)
    with pytest.raises(ConfigError, match="no_such_field"):
        rover_description_from_yaml(data="{no_such_field: 1.0}")
    with pytest.raises(OutOfRangeError, match="wheel_width_m"):
        rover_description_from_yaml(data="{wheel_width_m: -0.2}")


def test_sdf_text_is_deterministic_and_named():
    text = rover_sdf(krex2_rp(), model_name="rp")
    assert text == rover_sdf(krex2_rp(), model_name="rp")
    assert '<model name="rp">' in text and 'version="1.9"' in text
    assert text.count("<drake:controller_gains") == 10
    assert text.count("<drake:mimic") == 1
    assert "<collision" not in text
