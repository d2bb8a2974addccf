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
from pydrake.systems.primitives import ConstantVectorSource, SharedPointerSystem
from pydrake.visualization import ApplyVisualizationConfig

from lunar_drake.diagrams.rover import add_rover_model, check_soil_name, spawn_pose, wire_rover
from lunar_drake.models.rover_sdf import LUNAR_GRAVITY_MPS2
from lunar_drake.scenario import Scenario
from lunar_drake.systems.energy_meter import EnergyMeter
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
):
    """Builds the mission diagram (named ``mission``).

    Args:
        scenario: the validated scenario.
        heightfield: the site terrain.
        albedo: optional albedo grid for the Meshcat terrain colours.
        meshcat: a pydrake Meshcat, or None for headless runs.

    Exported output ports: ``terrain.heightfield`` and, with a rover, :data:`ROVER_PORTS`
    (``rover.pose`` is ground truth for scoring: x, y, z, roll, pitch, yaw, linear and
    angular velocity in the site frame).

    Raises:
        OutOfBoundsError / NoDataError: the rover spawn is off the raster or over a hole.
        ConfigError: unknown soil or an invalid rover description.
    """
    builder = DiagramBuilder()
    plant, _scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -LUNAR_GRAVITY_MPS2])
    rc = scenario.rover
    rover = None
    if rc.enabled:
        soil = check_soil_name(rc.soil)
        rover = add_rover_model(plant, description=rc.description)
    plant.Finalize()
    terrain = builder.AddNamedSystem("terrain", TerrainSource(heightfield=heightfield))
    builder.ExportOutput(terrain.heightfield_output, "terrain.heightfield")
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
        gimbal = builder.AddNamedSystem("rover.gimbal_command", ConstantVectorSource(np.zeros(2)))
        builder.Connect(gimbal.get_output_port(), h.kinematics.gimbal_input)
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
        # Drake's LCM publishers go to an in-process bus (no network traffic); the diagram
        # owns that bus so it lives as long as the publishers.
        lcm = DrakeLcm("memq://lunar_drake")
        builder.AddNamedSystem("visualization_lcm", SharedPointerSystem(lcm))
        ApplyVisualizationConfig(scenario.visualization, builder, meshcat=meshcat, lcm=lcm)
    diagram = builder.Build()
    diagram.set_name("mission")
    return diagram
