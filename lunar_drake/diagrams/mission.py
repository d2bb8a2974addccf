"""MakeMissionDiagram: the one diagram every run simulates.

It holds the plant (with SceneGraph, lunar gravity), the TerrainSource, the rover with
its wheel-soil contact, kinematics and sensors driven by an open-loop route, and, with
Meshcat, the terrain view and Drake's visualizers. Later work adds cameras, flight and
ground software and the comms links to this same factory. Exported ports are named
``<subsystem>.<signal>`` (manipulation ``station.py`` style).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.multibody.plant import AddMultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import SharedPointerSystem
from pydrake.visualization import ApplyVisualizationConfig

from lunar_drake.diagrams.rover import add_rover_model, check_soil_name, spawn_pose, wire_rover
from lunar_drake.ephemeris.sun_earth import SiteLocation
from lunar_drake.errors import ConfigError
from lunar_drake.models.rover_sdf import LUNAR_GRAVITY_MPS2
from lunar_drake.scenario import Scenario
from lunar_drake.systems.energy_meter import EnergyMeter
from lunar_drake.systems.ephemeris_source import EphemerisSource
from lunar_drake.systems.gimbal_pointing import GimbalPointing
from lunar_drake.systems.meshcat_sun import MeshcatSun
from lunar_drake.systems.rover_kinematics import TwistSchedule
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.terrain_visualizer import TerrainVisualizer
from lunar_drake.terrain.heightfield import Heightfield

#: Output ports exported when the scenario has a rover.
ROVER_PORTS = (
    "rover.pose",
    "rover.wheel_state",
    "rover.imu",
    "rover.star_tracker",
    "rover.encoder_angles",
    "rover.energy",
    "rover.off_terrain",
    "rover.twist_command",
)


def MakeMissionDiagram(
    *,
    scenario: Scenario,
    heightfield: Heightfield,
    albedo: np.ndarray | None = None,
    meshcat=None,
    cameras: bool = True,
    duration_s: float | None = None,
):
    """Builds the mission diagram (named ``mission``).

    Args:
        scenario: the validated scenario.
        heightfield: the site terrain.
        albedo: optional albedo grid for the Meshcat terrain colours.
        meshcat: a pydrake Meshcat, or None for headless runs.
        cameras: add the mast stereo pair (when the scenario enables it).
        duration_s: how long it will be simulated (s; default the scenario's), so time-
            tabulated inputs (baked lightmaps) cover the run.

    Exported output ports: ``terrain.heightfield`` and, with a rover, :data:`ROVER_PORTS`
    (``rover.pose`` is ground truth for scoring: x, y, z, roll, pitch, yaw, linear and
    angular velocity in the site frame), ``sun.direction_W``, ``sun.elevation_deg`` and,
    with cameras, ``camera.{left,right}.{raw,preview,depth,label}`` and
    ``camera.frame_index``. Sun and Earth directions are in the site's grid frame.

    Raises:
        OutOfBoundsError / NoDataError: the rover spawn is off the raster or over a hole.
        ConfigError: unknown soil or an invalid rover description.
    """
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -LUNAR_GRAVITY_MPS2])
    rc = scenario.rover
    rover = None
    if rc.enabled:
        soil = check_soil_name(rc.soil)
        rover = add_rover_model(plant, description=rc.description)
    plant.Finalize()
    terrain = builder.AddNamedSystem("terrain", TerrainSource(heightfield=heightfield))
    builder.ExportOutput(terrain.heightfield_output, "terrain.heightfield")
    site = SiteLocation(scenario.site.latitude_deg, scenario.site.longitude_deg)
    ephem = builder.AddNamedSystem(
        "ephemeris",
        EphemerisSource(
            site=site,
            epoch_utc=scenario.site.epoch_utc,
            extra_kernels=scenario.lighting.extra_kernels,
            update_period_s=scenario.lighting.ephemeris_update_s,
            world_frame="polar_grid",
        ),
    )
    builder.ExportOutput(ephem.GetOutputPort("sun_direction_W"), "sun.direction_W")
    builder.ExportOutput(ephem.GetOutputPort("sun_elevation_deg"), "sun.elevation_deg")
    if rover is not None:
        X_WC = spawn_pose(
            heightfield=heightfield,
            rover=rover,
            x_m=rc.spawn_x_m,
            y_m=rc.spawn_y_m,
            yaw_rad=math.radians(rc.spawn_yaw_deg),
            soil=soil,
        )
        plant.SetDefaultFloatingBaseBodyPose(rover.chassis, X_WC)
        h = wire_rover(
            builder,
            plant=plant,
            rover=rover,
            heightfield_port=terrain.heightfield_output,
            soil=soil,
            seed=scenario.random_seed,
        )
        route = builder.AddNamedSystem(
            "rover.route",
            TwistSchedule(
                segments=[(s.duration_s, s.vx_mps, s.vy_mps, s.wz_radps) for s in rc.route]
            ),
        )
        builder.Connect(route.twist_output, h.kinematics.twist_input)
        d = rover.description
        pan_pos = rover.gimbal_pan.frame_on_parent().GetFixedPoseInBodyFrame().translation()
        gimbal = builder.AddNamedSystem(
            "rover.gimbal_pointing",
            GimbalPointing(
                chassis_index=rover.chassis.index(),
                p_CG=pan_pos,
                ground_below_m=rover.nominal_chassis_height_m,
                lookahead_m=scenario.camera.lookahead_m,
                pan_limits=(d.gimbal_pan_min_rad, d.gimbal_pan_max_rad),
                tilt_limits=(d.gimbal_tilt_min_rad, d.gimbal_tilt_max_rad),
            ),
        )
        builder.Connect(plant.get_body_poses_output_port(), gimbal.body_poses_input)
        builder.Connect(gimbal.gimbal_command_output, h.kinematics.gimbal_input)
        drive_act = [
            plant.get_joint_actuator(a).input_start()
            for a in [act.index() for act in rover.drive_actuators]
        ]
        drive_v = [plant.num_positions() + j.velocity_start() for j in rover.drive_joints]
        meter = builder.AddNamedSystem(
            "rover.energy_meter",
            EnergyMeter(
                actuation_indices=drive_act,
                velocity_indices=drive_v,
                n_actuation=plant.num_actuators(),
                n_state=plant.num_multibody_states(),
                period_s=scenario.plant_config.time_step,
            ),
        )
        builder.Connect(plant.get_net_actuation_output_port(), meter.actuation_input)
        builder.Connect(plant.get_state_output_port(), meter.state_input)
        builder.ExportOutput(h.truth.pose_output, "rover.pose")
        builder.ExportOutput(h.contact.wheel_state_output, "rover.wheel_state")
        builder.ExportOutput(h.imu.GetOutputPort("measurement"), "rover.imu")
        builder.ExportOutput(h.star_tracker.GetOutputPort("R_WB_measured"), "rover.star_tracker")
        builder.ExportOutput(h.encoders.GetOutputPort("angles"), "rover.encoder_angles")
        builder.ExportOutput(meter.energy_output, "rover.energy")
        builder.ExportOutput(h.contact.off_terrain_output, "rover.off_terrain")
        builder.ExportOutput(route.twist_output, "rover.twist_command")
        if cameras and scenario.camera.enabled:
            _add_cameras(
                builder,
                scenario=scenario,
                plant=plant,
                scene_graph=scene_graph,
                rover=rover,
                contact=h.contact,
                heightfield=heightfield,
                albedo=albedo,
                ephem=ephem,
                site=site,
                duration_s=scenario.simulation_duration if duration_s is None else duration_s,
            )
    if meshcat is not None:
        view = builder.AddNamedSystem(
            "terrain_view",
            TerrainVisualizer(
                meshcat=meshcat,
                max_mesh_px=scenario.terrain_view.max_mesh_px,
                albedo=albedo,
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
    diagram.set_name("mission")
    return diagram


def _add_cameras(
    builder,
    *,
    scenario,
    plant,
    scene_graph,
    rover,
    contact,
    heightfield,
    albedo,
    ephem,
    site,
    duration_s,
):
    """The mast stereo pair: HapkeCamera fed by the plant, SceneGraph, the ephemeris and
    the baked lightmaps."""
    from lunar_drake.render.camera import CameraModel, TerrainCameraRenderer
    from lunar_drake.systems.hapke_camera import CameraMount, HapkeCamera, rover_meshes
    from lunar_drake.systems.lightmap_source import LightmapSource
    from lunar_drake.systems.wheel_tracks import WheelTracks

    c = scenario.camera
    model = CameraModel(
        width=c.width,
        height=c.height,
        fov_y_deg=c.fov_y_deg,
        exposure_s=c.exposure_s,
        gain=c.gain,
        shadow_samples=c.shadow_samples,
        engine=c.engine,
    )
    geometry = rover_meshes(
        plant,
        scene_graph,
        rover.model_instance,
        exclude_bodies=[rover.left_camera.body().index(), rover.right_camera.body().index()],
    )
    renderer = TerrainCameraRenderer(
        heightfield=heightfield, albedo=albedo, model=model, dynamic_meshes=[m for _, m in geometry]
    )
    mounts = [
        CameraMount(name=n, body_index=f.body().index(), X_BC=f.GetFixedPoseInBodyFrame())
        for n, f in (("left", rover.left_camera), ("right", rover.right_camera))
    ]
    from lunar_drake.render.shading import SpotLight

    band = renderer.sensor.band_solar_irradiance_W_m2
    lights = []
    for k, L in enumerate(c.spotlights):
        if not plant.HasBodyNamed(L.body, rover.model_instance):
            names = sorted(
                plant.get_body(b).name() for b in plant.GetBodyIndices(rover.model_instance)
            )
            raise ConfigError(
                f"camera.spotlights[{k}].body = {L.body!r} is not a rover body; choose one "
                f"of {names}"
            )
        body = plant.GetBodyByName(L.body, rover.model_instance)
        tmpl = SpotLight(
            position_W=(0.0, 0.0, 0.0),
            direction_W=(1.0, 0.0, 0.0),
            intensity=L.intensity_W_per_sr / band,
            outer_half_angle_rad=math.radians(L.outer_half_angle_deg),
            inner_half_angle_rad=math.radians(L.inner_half_angle_deg),
            cast_shadows=L.cast_shadows,
        )
        lights.append(
            (body.index(), np.asarray(L.xyz, float), np.asarray(L.direction, float), tmpl)
        )
    cam = builder.AddNamedSystem(
        "camera",
        HapkeCamera(
            lights=lights,
            renderer=renderer,
            mounts=mounts,
            rover_geometry=geometry,
            rate_hz=c.rate_hz,
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
                heightfield=heightfield,
                site=site,
                epoch_utc=scenario.site.epoch_utc,
                duration_s=duration_s,
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
        builder.ExportOutput(port, f"camera.{name}")
    builder.ExportOutput(cam.frame_index_output, "camera.frame_index")
    return cam
