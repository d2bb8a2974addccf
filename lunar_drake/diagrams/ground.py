"""MakeGroundDiagram: operations software on Earth. It reads only what the downlink
delivered.

Wiring only. Ports: input ``downlink.telemetry`` (the downlink inbox); outputs
``uplink.commands`` (the uplink outbox) and, for displays and logging,
``ground.telemetry`` (the newest telemetry packet received,
:data:`~lunar_drake.autonomy.telemetry.TELEMETRY_FIELDS`),
``ground.telemetry_t_received`` (s) and ``ground.pose_estimate`` (the ground's estimate
of the rover's pose from telemetry, x, y, z, roll, pitch, yaw).
"""

from __future__ import annotations

import dataclasses as dc
import math

from pydrake.systems.framework import DiagramBuilder

from lunar_drake.autonomy.commands import DriveCommand, GotoCommand
from lunar_drake.autonomy.operations import OperatorParams, Request, goal_shift_limit_m
from lunar_drake.autonomy.planner import PlanningError
from lunar_drake.diagrams.flight import sends_images, sends_science
from lunar_drake.errors import OutOfBoundsError
from lunar_drake.scenario import Scenario
from lunar_drake.systems.ground_operator import GroundOperator, plan_waypoints
from lunar_drake.systems.ground_perception import GroundPerception
from lunar_drake.systems.image_downlink import ImageReceiver
from lunar_drake.systems.science_downlink import ScienceReceiver
from lunar_drake.systems.telemetry import TelemetryReceiver

#: The inputs of the ground software (``downlink.images`` too when frames come down,
#: ``downlink.science`` when instrument records do).
GROUND_INPUTS = ("downlink.telemetry",)


def route_commands(scenario: Scenario) -> list[DriveCommand]:
    """The scenario's route (``ground.route``) as drive commands."""
    return [
        DriveCommand(duration_s=s.duration_s, vx_mps=s.vx_mps, vy_mps=s.vy_mps, wz_radps=s.wz_radps)
        for s in scenario.ground.route
    ]


def goal_commands(scenario: Scenario, *, costmap) -> list[GotoCommand]:
    """Plans from the spawn point through ``ground.goals`` in order on the ground's
    a-priori ``costmap`` (:func:`ground_costmap`; :mod:`lunar_drake.autonomy.planner`)
    and returns one goto command per goal (what the ground sends when the estimate is
    perfect). Raises OutOfBoundsError / PlanningError naming the goal for a goal off the
    map, inside a hazard or unreachable."""
    from lunar_drake.autonomy.planner import plan_path

    g = scenario.ground
    start = (scenario.rover.spawn_x_m, scenario.rover.spawn_y_m)
    out = []
    for k, p in enumerate(g.goals):
        goal = (p.x_m, p.y_m)
        try:
            path = plan_path(costmap=costmap, start_xy=start, goal_xy=goal)
        except (PlanningError, OutOfBoundsError) as exc:
            raise type(exc)(f"ground.goals[{k}]: {exc}") from None
        timeout = 3.0 * path.length_m / g.drive_speed_mps + 60.0
        out.append(
            GotoCommand(
                waypoints=tuple((float(x), float(y)) for x, y in path.waypoints_xy),
                speed_mps=g.drive_speed_mps,
                tolerance_m=g.goto_tolerance_m,
                timeout_s=timeout,
            )
        )
        start = goal
    return out


def ground_map_dem(map_product):
    """The ground's a-priori DEM (:class:`~lunar_drake.perception.elevation_map.PriorDem`)
    of its map product."""
    from lunar_drake.perception.elevation_map import PriorDem

    p = map_product
    return PriorDem(z=p.z, resolution_m=p.resolution_m, x0_m=p.x0_m, y1_m=p.y1_m)


def ground_costmap(scenario: Scenario, map_product):
    """The ground's costmap of its map product (``ground.hazards``; an orbital map's
    steep cells unconfirmed until stereo sees them)."""
    from lunar_drake.autonomy.costmap import RoverEnvelope, costmap_of_product

    return costmap_of_product(map_product, rover=RoverEnvelope.of(scenario.rover.description),
                              hazards=scenario.ground.hazards)  # fmt: skip


def operator_params(scenario: Scenario) -> OperatorParams:
    """The ground's settings: each OperatorParams field from the ``scenario.ground``
    field of the same name (one source of truth, documented on GroundConfig)."""
    g = scenario.ground
    return OperatorParams(**{f.name: getattr(g, f.name) for f in dc.fields(OperatorParams)})


def scheduled_requests(scenario: Scenario) -> list:
    """((t_s, Request), ...): the route (``drive``) or the goals at t = 0, then
    ``ground.actions`` at their times."""
    g = scenario.ground
    out = []
    if g.goals:
        out += [(0.0, Request("goal", (p.x_m, p.y_m))) for p in g.goals]
    else:
        out += [(0.0, Request("drive", (c,))) for c in route_commands(scenario)]
    for a in g.actions:
        if a.action == "goal":
            r = Request("goal", (a.x_m, a.y_m))
        elif a.action == "drive_arc":
            r = Request("drive_arc", (a.speed_mps, a.curvature_per_m, a.distance_m))
        elif a.action == "point_mast":
            args = () if a.auto else (math.radians(a.pan_deg), math.radians(a.tilt_deg))
            r = Request("point_mast", args)
        elif a.action == "drill":
            r = Request("drill", (a.depth_m, a.step_m))
        else:
            r = Request(a.action)
        out.append((a.t_s, r))
    return out


def command_preview(scenario: Scenario, *, prior_dem=None):
    """``preview(pose, waypoints)`` for the operator: the flight software's follower run
    forward from the ground's estimate (:func:`~lunar_drake.autonomy.preview.
    preview_goto`) at the flight rate, at most 10 Hz, heights from ``prior_dem``."""
    from lunar_drake.autonomy.preview import preview_goto
    from lunar_drake.diagrams.flight import follower_params

    g = scenario.ground
    params = follower_params(scenario.rover.description, scenario.flight.heading)
    rate = min(scenario.flight.rate_hz, 10.0)
    height = None if prior_dem is None else prior_dem.sample

    def preview(pose, waypoints, sun_azimuth_rad=None):
        return preview_goto(
            pose=(pose[0], pose[1], pose[5]), waypoints=waypoints, speed_mps=g.drive_speed_mps,
            tolerance_m=g.goto_tolerance_m, rate_hz=rate, params=params, height=height,
            sun_azimuth_rad=sun_azimuth_rad,
        )  # fmt: skip

    return preview


def sun_azimuth_source(scenario: Scenario):
    """``sun_azimuth(t_s)`` for the ground when the rover points its panel at the Sun
    (``flight.heading.policy: sun``), else None: the Sun's azimuth (rad,
    counter-clockwise from the site frame's +x, grid east) at simulation time ``t_s``,
    from the ephemeris the ground has before launch (SPICE, the site centre and
    ``site.epoch_utc``, ``lighting.extra_kernels``; apparent direction, turned into the
    site's polar grid frame as the plant's ephemeris is). The operator sends it with
    each goto (:func:`~lunar_drake.autonomy.operations.operator_step`)."""
    if scenario.flight.heading.policy != "sun":
        return None
    from lunar_drake.ephemeris.kernels import ensure_kernels
    from lunar_drake.ephemeris.sun_earth import (
        SiteLocation,
        site_frame_rotation,
        sun_earth_enu,
        utc_to_tdb_s,
    )

    site = SiteLocation(scenario.site.latitude_deg, scenario.site.longitude_deg)
    extra = tuple(scenario.lighting.extra_kernels)
    ensure_kernels(extra)
    epoch = float(utc_to_tdb_s(scenario.site.epoch_utc))
    R_EG = site_frame_rotation(site)

    def sun_azimuth(t_s: float) -> float:
        se = sun_earth_enu(epoch_tdb_s=epoch + float(t_s), site=site, extra_kernels=extra)
        v = R_EG.T @ se.sun_dir_enu
        return math.atan2(float(v[1]), float(v[0]))

    return sun_azimuth


def ground_perception(scenario: Scenario, *, costmap, prior_dem) -> GroundPerception:
    """The ground's stereo / VO / mapping system (``ground.perception``) over the
    a-priori ``costmap`` (refined to ``ground.hazards.resolution_m``): the rig
    calibration from the camera model and the rover's kinematics (what operations know
    of the rover)."""
    from lunar_drake.autonomy.costmap import RoverEnvelope
    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.perception.elevation_map import refined_costmap

    d = scenario.rover.description
    haz = scenario.ground.hazards
    # Stereo hazards go onto the hazard grid (ground.hazards.resolution_m), not the
    # coarser orbital one.
    costmap = refined_costmap(costmap, resolution_m=haz.resolution_m,
                              rover=RoverEnvelope.of(d), hazards=haz)  # fmt: skip
    return GroundPerception(
        config=scenario.ground.perception,
        rate_hz=scenario.ground.rate_hz,
        calib=StereoCalibration.from_camera(camera=scenario.sensors.camera, description=d),
        description=d,
        prior_costmap=costmap,
        prior_dem=prior_dem,
        rover=RoverEnvelope.of(d),
        hazards=scenario.ground.hazards,
        adc_bits=scenario.flight.images.adc_bits,
    )


def MakeGroundDiagram(*, scenario: Scenario, map_product=None):
    """Builds the ground-software diagram (named ``ground``): the operator
    (:class:`~lunar_drake.systems.ground_operator.GroundOperator`: the route, or the
    goals driven one at a time with planning and replanning on the ground's map from
    the downlinked estimate, the scheduled ``ground.actions``, Python requests,
    heartbeats, the ground pose estimate) and the telemetry receiver (every packet the
    downlink delivered, once, in order).

    ``map_product`` (:class:`~lunar_drake.autonomy.map_product.MapProduct`, made before
    launch by :func:`lunar_drake.preflight.ground_map_product`) is the ground's a-priori
    map, and all it knows of the terrain: the ground never sees the site. It is needed
    for goals; scenario goals the map cannot serve (off it, in a hazard, unreachable
    from the previous one) are refused here, before the run."""
    g = scenario.ground
    builder = DiagramBuilder()
    planner, in_map, prior_dem, preview, costmap = None, None, None, None, None
    if map_product is not None:
        costmap = ground_costmap(scenario, map_product)
        planner = plan_waypoints(
            costmap, goal_free_radius_m=goal_shift_limit_m(operator_params(scenario))
        )
        prior_dem = ground_map_dem(map_product)
        preview = command_preview(scenario, prior_dem=prior_dem)

        def in_map(x, y):
            return costmap.inside(*costmap.cell_of(x, y))

    elif g.goals or any(a.action == "goal" for a in g.actions):
        raise ValueError("ground.goals need the ground's a-priori map (map_product)")
    if g.goals:
        goal_commands(scenario, costmap=costmap)  # refuse what the map cannot serve
    for k, a in enumerate(g.actions):
        if a.action == "goal" and not in_map(a.x_m, a.y_m):
            raise OutOfBoundsError(
                f"ground.actions[{k}]: goal ({a.x_m:.2f}, {a.y_m:.2f}) m is off the ground's "
                f"map: {costmap.extent_text()}"
            )

    def no_map(start_xy, goal_xy):
        raise PlanningError("the ground has no map (MakeGroundDiagram without a map_product)")

    operator = builder.AddNamedSystem(
        "ground.operator",
        GroundOperator(
            params=operator_params(scenario),
            rate_hz=g.rate_hz,
            planner=planner or no_map,
            start_pose=(
                scenario.rover.spawn_x_m,
                scenario.rover.spawn_y_m,
                math.radians(scenario.rover.spawn_yaw_deg),
            ),
            actions=scheduled_requests(scenario),
            in_map=in_map,
            preview=preview,
            costmap=costmap,
            sun_azimuth=sun_azimuth_source(scenario),
        ),
    )
    receiver = builder.AddNamedSystem("ground.telemetry", TelemetryReceiver(rate_hz=g.rate_hz))
    builder.ExportInput(receiver.telemetry_input, "downlink.telemetry")
    builder.ConnectInput("downlink.telemetry", operator.telemetry_input)
    builder.ExportOutput(operator.commands_output, "uplink.commands")
    builder.ExportOutput(receiver.telemetry_output, "ground.telemetry")
    builder.ExportOutput(receiver.t_received_output, "ground.telemetry_t_received")
    builder.ExportOutput(operator.pose_estimate_output, "ground.pose_estimate")
    builder.ExportOutput(operator.preview_output, "ground.preview")
    if sends_images(scenario):
        images = builder.AddNamedSystem("ground.images", ImageReceiver(rate_hz=g.rate_hz))
        builder.ExportInput(images.images_input, "downlink.images")
        builder.ExportOutput(images.frames_received_output, "ground.frames_received")
        if g.perception.enabled and map_product is not None:
            perception = builder.AddNamedSystem(
                "ground.perception",
                ground_perception(scenario, costmap=costmap, prior_dem=prior_dem),
            )
            builder.ConnectInput("downlink.images", perception.images_input)
            builder.Connect(perception.costmap_output, operator.costmap_input)
            if g.perception.use_vo:
                builder.Connect(perception.pose_correction_output, operator.pose_correction_input)
                builder.Connect(perception.pose_sigma_output, operator.pose_sigma_input)
            builder.ExportOutput(perception.pose_correction_output, "ground.pose_correction")
    if sends_science(scenario):
        science = builder.AddNamedSystem("ground.science", ScienceReceiver(rate_hz=g.rate_hz))
        builder.ExportInput(science.science_input, "downlink.science")
        builder.ExportOutput(science.records_received_output, "ground.science_received")
    diagram = builder.Build()
    diagram.set_name("ground")
    return diagram
