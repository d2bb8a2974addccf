"""MakeGroundDiagram: operations software on Earth. It reads only what the downlink
delivered.

Wiring only. Ports: input ``downlink.telemetry`` (the downlink inbox); outputs
``uplink.commands`` (the uplink outbox) and, for displays and logging,
``ground.telemetry`` (the newest telemetry packet received,
:data:`~lunar_drake.autonomy.telemetry.TELEMETRY_FIELDS`) and
``ground.telemetry_t_received`` (s).
"""

from __future__ import annotations

from pydrake.systems.framework import DiagramBuilder

from lunar_drake.autonomy.commands import DriveCommand, GotoCommand
from lunar_drake.scenario import Scenario
from lunar_drake.systems.command_sequencer import CommandSequencer
from lunar_drake.systems.telemetry import TelemetryReceiver

#: The only input of the ground software.
GROUND_INPUTS = ("downlink.telemetry",)


def route_commands(scenario: Scenario) -> list[DriveCommand]:
    """The scenario's route (``ground.route``) as drive commands."""
    return [
        DriveCommand(duration_s=s.duration_s, vx_mps=s.vx_mps, vy_mps=s.vy_mps, wz_radps=s.wz_radps)
        for s in scenario.ground.route
    ]


def goal_commands(scenario: Scenario, site) -> list[GotoCommand]:
    """Plans from the spawn point through ``ground.goals`` in order on the ground's
    a-priori map (``ground.map``, ``ground.hazards``; :mod:`lunar_drake.autonomy.planner`)
    and returns one goto command per goal. Raises OutOfBoundsError / PlanningError for a
    goal off the map, inside a hazard or unreachable."""
    from lunar_drake.autonomy.costmap import RoverEnvelope, costmap_for_site
    from lunar_drake.autonomy.planner import PlanningError, plan_path
    from lunar_drake.errors import OutOfBoundsError

    g = scenario.ground
    start = (scenario.rover.spawn_x_m, scenario.rover.spawn_y_m)
    goals = [(p.x_m, p.y_m) for p in g.goals]
    cm = costmap_for_site(
        heightfield=site.heightfield,
        points_xy=[start, *goals],
        rover=RoverEnvelope.of(scenario.rover.description),
        hazards=g.hazards,
        map_config=g.map,
        seed=scenario.random_seed,
    )
    out = []
    for k, goal in enumerate(goals):
        try:
            path = plan_path(costmap=cm, start_xy=start, goal_xy=goal)
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


def MakeGroundDiagram(*, scenario: Scenario, site=None):
    """Builds the ground-software diagram (named ``ground``): the operator command source
    (the route, or with ``ground.goals`` the planned gotos, as a command sequence, one
    command per ground tick) and the telemetry receiver (every packet the downlink
    delivered, once, in order). ``site`` (its DEM is the ground's a-priori map) is needed
    only with goals."""
    g = scenario.ground
    builder = DiagramBuilder()
    if g.goals:
        if site is None:
            raise ValueError("ground.goals need the site (the ground's a-priori map)")
        commands = goal_commands(scenario, site)
    else:
        commands = route_commands(scenario)
    operator = builder.AddNamedSystem(
        "ground.operator", CommandSequencer(commands=commands, rate_hz=g.rate_hz)
    )
    receiver = builder.AddNamedSystem("ground.telemetry", TelemetryReceiver(rate_hz=g.rate_hz))
    builder.ExportInput(receiver.telemetry_input, "downlink.telemetry")
    builder.ExportOutput(operator.commands_output, "uplink.commands")
    builder.ExportOutput(receiver.telemetry_output, "ground.telemetry")
    builder.ExportOutput(receiver.t_received_output, "ground.telemetry_t_received")
    diagram = builder.Build()
    diagram.set_name("ground")
    return diagram
