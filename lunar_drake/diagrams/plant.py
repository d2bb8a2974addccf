"""MakePlantDiagram: the world and the rover hardware (everything that is not software).

Wiring only (DESIGN.md: functional core, thin systems, factories that wire). Exported
ports are named ``<subsystem>.<signal>``:

* inputs -- actuator commands: ``rover.wheel_speed_command`` (4, rad/s),
  ``rover.steer_angle_command`` (4, rad; explicit steer only), ``rover.gimbal_command``
  (2: pan, tilt, rad), ``rover.brake_command`` (1: >= 0.5 engages the wheel brakes);
* sensor outputs -- :data:`SENSOR_PORTS` (``rover.power``, 3: SOC, array and load power
  in W, when ``power.enabled``), ``rover.nss`` (2: epithermal and thermal counts) when
  ``sensors.nss.enabled``, ``rover.nirvss`` (8: band depths and the LCS temperature) when
  ``sensors.nirvss.enabled`` and, with cameras, ``camera.{left,right}.{raw,preview}`` and
  ``camera.frame_index``;
* truth outputs -- :data:`TRUTH_PORTS` (``truth.power`` when ``power.enabled``) and,
  with cameras, ``truth.camera.{left,right}.{depth,label}``: ground truth for scoring and
  logging only.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.multibody.plant import AddMultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (
    Adder,
    ConstantVectorSource,
    MatrixGain,
    Multiplexer,
    SharedPointerSystem,
)
from pydrake.visualization import ApplyVisualizationConfig

from lunar_drake import moon
from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.ephemeris.sun_earth import SiteLocation
from lunar_drake.errors import ConfigError
from lunar_drake.models.plant_tree import tree_kinematics_from_plant
from lunar_drake.models.rover_sdf import RoverModel, add_rover
from lunar_drake.models.spawn import spawn_pose
from lunar_drake.power.solar_array import PanelMount
from lunar_drake.scenario import Scenario
from lunar_drake.site import SiteData
from lunar_drake.systems.body_pose_vector import BodyPoseVector
from lunar_drake.systems.earth_line_of_sight import EarthLineOfSight
from lunar_drake.systems.energy_meter import EnergyMeter
from lunar_drake.systems.ephemeris_source import EphemerisSource
from lunar_drake.systems.imu import add_imu
from lunar_drake.systems.meshcat_sun import MeshcatSun
from lunar_drake.systems.power_system import PowerSystem
from lunar_drake.systems.star_tracker import StarTracker
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.terrain_visualizer import TerrainVisualizer
from lunar_drake.systems.wheel_brakes import WheelBrakes
from lunar_drake.systems.wheel_encoders import WheelEncoders, wheel_angle_selector
from lunar_drake.systems.wheel_regolith_contact import WheelRegolithContact

#: Sensor outputs (what flight software may read); ``rover.power`` (3: SOC, array and
#: load power, W) when ``power.enabled``.
SENSOR_PORTS = ("rover.imu", "rover.star_tracker", "rover.wheel_encoders", "rover.power")
#: Science instrument outputs, when the rover carries them (sensors too).
INSTRUMENT_PORTS = ("rover.nss", "rover.nirvss", "rover.drill")

#: Ground-truth outputs (scoring and logging only).
TRUTH_PORTS = (
    "truth.pose",
    "truth.wheel_state",
    "truth.drive_energy",
    "truth.off_terrain",
    "truth.imu_bias",
    "truth.sun_direction_W",
    "truth.sun_elevation_deg",
    "truth.heightfield",
    "truth.power",
)

#: Actuator-command inputs, in the order of the servo set-point multiplexer.
COMMAND_PORTS = ("rover.wheel_speed_command", "rover.steer_angle_command", "rover.gimbal_command")


def MakePlantDiagram(*, scenario: Scenario, site: SiteData, meshcat=None):
    """Builds the plant diagram (named ``plant``).

    It holds the MultibodyPlant (with SceneGraph and lunar gravity) and the rover on its
    wheel-soil contact, the terrain, the Sun/Earth ephemeris, the wheel brakes, the
    sensors (IMU, star tracker, wheel encoders and, when ``sensors.camera.enabled``, the
    Hapke stereo pair with its baked lightmaps and wheel tracks) and, with Meshcat, the
    terrain view and Drake's visualizers. See the module docstring for its ports.

    Raises:
        OutOfBoundsError / NoDataError: the rover spawn is off the raster or over a hole.
        ConfigError: an invalid rover description or a lamp on an unknown body.
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    plant.mutable_gravity_field().set_gravity_vector(moon.GRAVITY_W)
    rover = add_rover(plant, description=scenario.rover.description)
    plant.Finalize()
    hf = site.heightfield
    soil = scenario.soil

    terrain = builder.AddNamedSystem("terrain", TerrainSource(heightfield=hf))
    builder.ExportOutput(terrain.heightfield_output, "truth.heightfield")
    location = SiteLocation(scenario.site.latitude_deg, scenario.site.longitude_deg)
    ephem = builder.AddNamedSystem(
        "ephemeris",
        EphemerisSource(
            site=location,
            epoch_utc=scenario.site.epoch_utc,
            extra_kernels=scenario.lighting.extra_kernels,
            update_period_s=scenario.lighting.ephemeris_update_s,
            world_frame="polar_grid",
        ),
    )
    builder.ExportOutput(ephem.GetOutputPort("sun_direction_W"), "truth.sun_direction_W")
    builder.ExportOutput(ephem.GetOutputPort("sun_elevation_deg"), "truth.sun_elevation_deg")

    rc = scenario.rover
    X_WC = spawn_pose(
        heightfield=hf,
        rover=rover,
        x_m=rc.spawn_x_m,
        y_m=rc.spawn_y_m,
        yaw_rad=math.radians(rc.spawn_yaw_deg),
        soil=soil,
    )
    plant.SetDefaultFloatingBaseBodyPose(rover.chassis, X_WC)

    d = rover.description
    contact = builder.AddNamedSystem(
        "rover.contact",
        WheelRegolithContact(
            wheel_bodies=[b.index() for b in rover.wheels],
            wheel=tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m),
            soil=soil,
            belly_body=rover.chassis.index(),
            belly_points_B=rover.belly_points_C,
            time_step_s=scenario.plant_config.time_step,
            tree=tree_kinematics_from_plant(plant),
        ),
    )
    builder.Connect(plant.get_state_output_port(), contact.plant_state_input)
    builder.Connect(terrain.heightfield_output, contact.heightfield_input)
    _add_actuators(
        builder, plant=plant, rover=rover, time_step_s=scenario.plant_config.time_step,
        contact_force=contact.generalized_force_output,
    )  # fmt: skip
    _add_sensors(builder, scenario=scenario, plant=plant, rover=rover)
    if scenario.sensors.nss.enabled:
        _add_nss(builder, scenario=scenario, plant=plant, rover=rover, site=site)
    if scenario.sensors.nirvss.enabled:
        _add_nirvss(builder, scenario=scenario, plant=plant, rover=rover, site=site)
    if scenario.sensors.drill.enabled:
        _add_drill(builder, scenario=scenario, plant=plant, rover=rover, site=site)
    _add_truth(builder, plant=plant, rover=rover, contact=contact)
    if scenario.power.enabled:
        _add_power(builder, scenario=scenario, plant=plant, rover=rover, terrain=terrain,
                   ephem=ephem)  # fmt: skip
    if scenario.comms.line_of_sight.enabled:
        los_cfg = scenario.comms.line_of_sight
        los = builder.AddNamedSystem(
            "radio.line_of_sight",
            EarthLineOfSight(
                heightfield=hf,
                period_s=los_cfg.period_s,
                antenna_height_m=los_cfg.antenna_height_m,
                min_margin_deg=los_cfg.min_margin_deg,
            ),
        )
        builder.Connect(ephem.GetOutputPort("earth_direction_W"), los.earth_direction_input)
        pose_sys = builder.GetSubsystemByName("rover.truth")
        builder.Connect(pose_sys.pose_output, los.pose_input)
        builder.ExportOutput(los.earth_visible_output, "radio.earth_visible")
        builder.ExportOutput(los.earth_margin_output, "truth.earth_margin_deg")
    if scenario.sensors.camera.enabled:
        _add_cameras(
            builder,
            scenario=scenario,
            plant=plant,
            scene_graph=scene_graph,
            rover=rover,
            contact=contact,
            site=site,
            ephem=ephem,
            location=location,
        )
    if meshcat is not None:
        view = builder.AddNamedSystem(
            "terrain_view",
            TerrainVisualizer(
                meshcat=meshcat,
                max_mesh_px=scenario.terrain_view.max_mesh_px,
                albedo=site.albedo,
                albedo_gain=scenario.terrain_view.albedo_gain,
            ),
        )
        builder.Connect(terrain.heightfield_output, view.heightfield_input)
        sun = builder.AddNamedSystem("meshcat_sun", MeshcatSun(meshcat=meshcat))
        builder.Connect(ephem.GetOutputPort("sun_direction_W"), sun.sun_direction_input)
        # Drake's LCM publishers go to an in-process bus (no network traffic); the diagram
        # owns that bus so it lives as long as the publishers.
        lcm = DrakeLcm("memq://lunar_drake")
        builder.AddNamedSystem("visualization_lcm", SharedPointerSystem(lcm))
        ApplyVisualizationConfig(scenario.visualization, builder, meshcat=meshcat, lcm=lcm)
    diagram = builder.Build()
    diagram.set_name("plant")
    return diagram


def servo_setpoint_gain(plant, rover: RoverModel) -> np.ndarray:
    """Matrix mapping [wheel speeds (4); steering angles (4 or 0); pan, tilt] to the
    rover's desired-state input [q_d; v_d] (actuator order) for the plant's PD servos:
    drive joints get v_d, steering and gimbal joints q_d."""
    acts = plant.GetJointActuatorIndices(rover.model_instance)
    names = [plant.get_joint_actuator(a).joint().name() for a in acts]
    nu = len(names)
    cols = [j.name() for j in rover.drive_joints] + [j.name() for j in rover.steer_joints]
    cols += [rover.gimbal_pan.name(), rover.gimbal_tilt.name()]
    n_drive = len(rover.drive_joints)
    m = np.zeros((2 * nu, len(cols)))
    for c, name in enumerate(cols):
        slot = names.index(name)
        m[(nu if c < n_drive else 0) + slot, c] = 1.0
    return m


def _add_actuators(builder, *, plant, rover: RoverModel, time_step_s: float,
                   contact_force) -> None:  # fmt: skip
    """Servo set-points from the commands, zero feed-forward torque, and the brakes,
    whose generalized forces are added to the contact's (``contact_force``, (nv,)) on
    the plant's applied generalized force."""
    sizes = [len(rover.drive_joints), len(rover.steer_joints), 2]
    names = [n for n, k in zip(COMMAND_PORTS, sizes, strict=True) if k]
    mux = builder.AddNamedSystem("rover.command_mux", Multiplexer([k for k in sizes if k]))
    gain = builder.AddNamedSystem(
        "rover.servo_setpoints", MatrixGain(servo_setpoint_gain(plant, rover))
    )
    builder.Connect(mux.get_output_port(0), gain.get_input_port())
    builder.Connect(
        gain.get_output_port(), plant.get_desired_state_input_port(rover.model_instance)
    )
    for k, name in enumerate(names):
        builder.ExportInput(mux.get_input_port(k), name)
    zero = builder.AddNamedSystem(
        "rover.zero_actuation",
        ConstantVectorSource(np.zeros(plant.num_actuated_dofs(rover.model_instance))),
    )
    builder.Connect(zero.get_output_port(), plant.get_actuation_input_port(rover.model_instance))
    brakes = builder.AddNamedSystem(
        "rover.brakes", WheelBrakes(plant=plant, rover=rover, time_step_s=time_step_s)
    )
    builder.Connect(plant.get_state_output_port(), brakes.state_input)
    forces = builder.AddNamedSystem("rover.applied_forces", Adder(2, plant.num_velocities()))
    builder.Connect(contact_force, forces.get_input_port(0))
    builder.Connect(brakes.generalized_force_output, forces.get_input_port(1))
    builder.Connect(forces.get_output_port(), plant.get_applied_generalized_force_input_port())
    builder.ExportInput(brakes.brake_command_input, "rover.brake_command")


def _add_sensors(builder, *, scenario: Scenario, plant, rover: RoverModel) -> None:
    seed = scenario.random_seed
    sc = scenario.sensors
    chassis = rover.chassis.index()
    imu = add_imu(builder, plant=plant, body=rover.chassis, seed=seed, name="rover.imu",
                  config=sc.imu)  # fmt: skip
    builder.ExportOutput(imu.measurement_output, "rover.imu")
    builder.ExportOutput(imu.bias_truth_output, "truth.imu_bias")
    st = builder.AddNamedSystem(
        "rover.star_tracker",
        StarTracker(
            body_index=chassis, seed=seed, name="rover.star_tracker", config=sc.star_tracker
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), st.body_poses_input)
    builder.ExportOutput(st.measurement_output, "rover.star_tracker")
    sel = builder.AddNamedSystem(
        "rover.wheel_angles", wheel_angle_selector(plant, list(rover.drive_joints))
    )
    enc = builder.AddNamedSystem(
        "rover.wheel_encoders",
        WheelEncoders(
            n_wheels=len(rover.drive_joints),
            seed=seed,
            name="rover.wheel_encoders",
            config=sc.wheel_encoders,
        ),
    )
    builder.Connect(plant.get_state_output_port(), sel.get_input_port())
    builder.Connect(sel.get_output_port(), enc.wheel_angles_input)
    builder.ExportOutput(enc.measurement_output, "rover.wheel_encoders")


def _add_nss(builder, *, scenario: Scenario, plant, rover: RoverModel, site) -> None:
    """The neutron spectrometer, reading the site's world model (built and cached on
    first use) at the chassis' true pose: ``rover.nss`` (2: epithermal, thermal counts)."""
    from lunar_drake.science.world import hydrogen_map
    from lunar_drake.systems.neutron_spectrometer import NeutronSpectrometer

    nss = builder.AddNamedSystem(
        "rover.nss",
        NeutronSpectrometer(
            body_index=rover.chassis.index(),
            hmap=hydrogen_map(scenario=scenario, site=site),
            seed=scenario.random_seed,
            name="rover.nss",
            config=scenario.sensors.nss,
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), nss.body_poses_input)
    builder.ExportOutput(nss.measurement_output, "rover.nss")


def _add_nirvss(builder, *, scenario: Scenario, plant, rover: RoverModel, site) -> None:
    """NIRVSS and its LCS, reading the site's world model at the spot's true position:
    ``rover.nirvss`` (8: band depths, then the LCS temperature in K)."""
    from lunar_drake.science.world import surface_map
    from lunar_drake.systems.nirvss import NIRVSSSensor

    nirvss = builder.AddNamedSystem(
        "rover.nirvss",
        NIRVSSSensor(
            body_index=rover.chassis.index(),
            smap=surface_map(scenario=scenario, site=site),
            seed=scenario.random_seed,
            name="rover.nirvss",
            config=scenario.sensors.nirvss,
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), nirvss.body_poses_input)
    builder.ExportOutput(nirvss.measurement_output, "rover.nirvss")


def _add_drill(builder, *, scenario: Scenario, plant, rover: RoverModel, site) -> None:
    """The drill: input ``rover.drill_command`` (3: seq, depth, step), output
    ``rover.drill`` (4: samples so far, depth m, NIRVSS ice band depth, time s)."""
    from lunar_drake.science.world import surface_map
    from lunar_drake.systems.drill import Drill

    drill = builder.AddNamedSystem(
        "rover.drill",
        Drill(
            body_index=rover.chassis.index(),
            smap=surface_map(scenario=scenario, site=site),
            seed=scenario.random_seed,
            config=scenario.sensors.drill,
            nirvss=scenario.sensors.nirvss,
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), drill.body_poses_input)
    builder.ExportInput(drill.command_input, "rover.drill_command")
    builder.ExportOutput(drill.samples_output, "rover.drill")


def _add_truth(builder, *, plant, rover: RoverModel, contact) -> None:
    truth = builder.AddNamedSystem("rover.truth", BodyPoseVector(body_index=rover.chassis.index()))
    builder.Connect(plant.get_body_poses_output_port(), truth.body_poses_input)
    builder.Connect(
        plant.get_body_spatial_velocities_output_port(), truth.body_spatial_velocities_input
    )
    builder.ExportOutput(truth.pose_output, "truth.pose")
    builder.ExportOutput(contact.wheel_state_output, "truth.wheel_state")
    builder.ExportOutput(contact.off_terrain_output, "truth.off_terrain")
    nq = plant.num_positions()

    def actuation(actuators):
        return [plant.get_joint_actuator(a.index()).input_start() for a in actuators]

    # Positive work of the drive motors (``truth.drive_energy``) and of the steering
    # motors (``steer_energy``, for the power system), integrated at the plant's step.
    meter = builder.AddNamedSystem(
        "rover.energy_meter",
        EnergyMeter(
            actuation_indices=actuation(rover.drive_actuators),
            velocity_indices=[nq + j.velocity_start() for j in rover.drive_joints],
            n_actuation=plant.num_actuators(),
            n_state=plant.num_multibody_states(),
            period_s=plant.time_step(),
            groups=[("steer", actuation(rover.steer_actuators),
                     [nq + j.velocity_start() for j in rover.steer_joints])],
        ),
    )  # fmt: skip
    builder.Connect(plant.get_net_actuation_output_port(), meter.actuation_input)
    builder.Connect(plant.get_state_output_port(), meter.state_input)
    builder.ExportOutput(meter.energy_output, "truth.drive_energy")


def _add_power(builder, *, scenario: Scenario, plant, rover: RoverModel, terrain, ephem) -> None:
    """The solar array, battery and loads: ``rover.power`` (sensor: SOC, array and load
    power) and ``truth.power`` (:data:`~lunar_drake.systems.power_system.TRUTH_FIELDS`).
    The motors' work comes from the energy meter (drive and steering joints)."""
    power = builder.AddNamedSystem(
        "rover.power",
        PowerSystem(
            config=scenario.power,
            mount=PanelMount.from_description(rover.description),
            chassis_body_index=rover.chassis.index(),
        ),
    )
    meter = builder.GetSubsystemByName("rover.energy_meter")
    builder.Connect(plant.get_body_poses_output_port(), power.body_poses_input)
    builder.Connect(ephem.GetOutputPort("sun_direction_W"), power.sun_direction_input)
    builder.Connect(ephem.GetOutputPort("sun_distance_km"), power.sun_distance_input)
    builder.Connect(terrain.heightfield_output, power.heightfield_input)
    builder.Connect(meter.energy_output, power.drive_energy_input)
    builder.Connect(meter.group_outputs["steer"], power.steer_energy_input)
    builder.ConnectInput("rover.brake_command", power.brake_command_input)
    builder.ExportOutput(power.measurement_output, "rover.power")
    builder.ExportOutput(power.truth_output, "truth.power")


def _add_cameras(builder, *, scenario, plant, scene_graph, rover, contact, site, ephem, location):
    """The mast stereo pair: HapkeCamera fed by the plant, SceneGraph, the ephemeris, the
    baked lightmaps and the wheel tracks."""
    from lunar_drake.render.camera import TerrainCameraRenderer
    from lunar_drake.render.shading import SpotLight
    from lunar_drake.systems.hapke_camera import CameraMount, HapkeCamera, rover_meshes
    from lunar_drake.systems.lightmap_source import LightmapSource
    from lunar_drake.systems.wheel_tracks import WheelTracks

    c = scenario.sensors.camera
    geometry = rover_meshes(
        plant,
        scene_graph,
        rover.model_instance,
        exclude_bodies=[rover.left_camera.body().index(), rover.right_camera.body().index()],
    )
    renderer = TerrainCameraRenderer(
        heightfield=site.heightfield,
        albedo=site.albedo,
        model=c,
        dynamic_meshes=[m for _, m in geometry],
    )
    mounts = [
        CameraMount(name=n, body_index=f.body().index(), X_BC=f.GetFixedPoseInBodyFrame())
        for n, f in (("left", rover.left_camera), ("right", rover.right_camera))
    ]
    band = renderer.sensor.band_solar_irradiance_W_m2
    lights = []
    for k, L in enumerate(scenario.rover.lights):
        if not plant.HasBodyNamed(L.body, rover.model_instance):
            names = sorted(
                plant.get_body(b).name() for b in plant.GetBodyIndices(rover.model_instance)
            )
            raise ConfigError(
                f"rover.lights[{k}].body = {L.body!r} is not a rover body; choose one of {names}"
            )
        body = plant.GetBodyByName(L.body, rover.model_instance)
        template = SpotLight(
            position_W=(0.0, 0.0, 0.0),
            direction_W=(1.0, 0.0, 0.0),
            intensity=L.intensity_W_per_sr / band,
            outer_half_angle_rad=math.radians(L.outer_half_angle_deg),
            inner_half_angle_rad=math.radians(L.inner_half_angle_deg),
            cast_shadows=L.cast_shadows,
        )
        lights.append(
            (body.index(), np.asarray(L.xyz, float), np.asarray(L.direction, float), template)
        )
    cam = builder.AddNamedSystem(
        "camera",
        HapkeCamera(
            lights=lights,
            renderer=renderer,
            mounts=mounts,
            rover_geometry=geometry,
            rate_hz=c.rate_hz,
            delay_s=c.delay_s,
            seed=scenario.random_seed,
            name="camera",
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), cam.body_poses_input)
    builder.Connect(scene_graph.get_query_output_port(), cam.geometry_query_input)
    for port in (
        "sun_direction_W",
        "sun_distance_km",
        "earth_direction_W",
        "earth_distance_km",
        "earth_phase",
    ):
        builder.Connect(ephem.GetOutputPort(port), cam.GetInputPort(port))
    if scenario.lighting.lightmap:
        lm = builder.AddNamedSystem(
            "lightmaps",
            LightmapSource(
                heightfield=site.heightfield,
                site=location,
                epoch_utc=scenario.site.epoch_utc,
                duration_s=scenario.simulation_duration,
                interval_s=scenario.lighting.lightmap_interval_s,
                max_px=scenario.lighting.lightmap_max_px,
                extra_kernels=scenario.lighting.extra_kernels,
            ),
        )
        builder.Connect(lm.lightmap_output, cam.lightmap_input)
    tracks = builder.AddNamedSystem(
        "rover.tracks",
        WheelTracks(
            wheel_bodies=[b.index() for b in rover.wheels],
            wheel_width_m=rover.description.wheel_width_m,
        ),
    )
    builder.Connect(plant.get_body_poses_output_port(), tracks.body_poses_input)
    builder.Connect(contact.wheel_state_output, tracks.wheel_state_input)
    builder.Connect(tracks.track_depth_output, cam.track_depth_input)
    for name, port in cam.ports.items():
        n, signal = name.split(".")
        prefix = "truth.camera" if signal in ("depth", "label") else "camera"
        builder.ExportOutput(port, f"{prefix}.{n}.{signal}")
    builder.ExportOutput(cam.frame_index_output, "camera.frame_index")
    return cam
