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

from lunar_drake.autonomy.commands import DriveCommand
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


def MakeGroundDiagram(*, scenario: Scenario):
    """Builds the ground-software diagram (named ``ground``): the operator command source
    (the route as a command sequence, one command per ground tick) and the telemetry
    receiver (every packet the downlink delivered, once, in order)."""
    g = scenario.ground
    builder = DiagramBuilder()
    operator = builder.AddNamedSystem(
        "ground.operator", CommandSequencer(commands=route_commands(scenario), rate_hz=g.rate_hz)
    )
    receiver = builder.AddNamedSystem("ground.telemetry", TelemetryReceiver(rate_hz=g.rate_hz))
    builder.ExportInput(receiver.telemetry_input, "downlink.telemetry")
    builder.ExportOutput(operator.commands_output, "uplink.commands")
    builder.ExportOutput(receiver.telemetry_output, "ground.telemetry")
    builder.ExportOutput(receiver.t_received_output, "ground.telemetry_t_received")
    diagram = builder.Build()
    diagram.set_name("ground")
    return diagram
