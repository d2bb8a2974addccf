"""The mission's seams: plant, flight, ground and the link, proven on the built diagram.

* every exported port is named ``<subsystem>.<signal>``;
* the flight diagram's inputs are fed only by plant sensor ports and the uplink;
* the ground diagram's inputs only by the downlink;
* ``truth.*`` ports feed nothing inside the mission (scoring and logging only);
* a link with delay D delays every message across it by exactly D, in the mission too.
"""

import math
import re

import numpy as np
import pytest

from lunar_drake.diagrams.flight import IMAGE_INPUTS, MakeFlightDiagram, flight_inputs
from lunar_drake.diagrams.ground import GROUND_INPUTS, MakeGroundDiagram
from lunar_drake.diagrams.mission import MakeMissionDiagram
from lunar_drake.diagrams.plant import SENSOR_PORTS, TRUTH_PORTS
from lunar_drake.scenario_files import apply_overrides

PORT_NAME = re.compile(r"^[a-z][a-z_]*(\.[A-Za-z0-9_]+)+$")


def _ports(system, kind):
    n = system.num_input_ports() if kind == "input" else system.num_output_ports()
    get = system.get_input_port if kind == "input" else system.get_output_port
    return [get(k) for k in range(n)]


@pytest.fixture
def mission(small_site):
    scenario, site = small_site
    return MakeMissionDiagram(scenario=scenario, site=site), scenario


def test_factories_name_their_diagrams_and_ports(mission):
    diagram, scenario = mission
    assert diagram.get_name() == "mission"
    for name in ("plant", "flight", "ground", "uplink", "downlink"):
        assert diagram.HasSubsystemNamed(name)
    for sub in ("plant", "flight", "ground"):
        system = diagram.GetSubsystemByName(sub)
        assert system.get_name() == sub
        for kind in ("input", "output"):
            for port in _ports(system, kind):
                assert PORT_NAME.match(port.get_name()), (sub, port.get_name())
    plant = diagram.GetSubsystemByName("plant")
    outs = {p.get_name() for p in _ports(plant, "output")}
    assert set(SENSOR_PORTS) <= outs and set(TRUTH_PORTS) <= outs
    flight = MakeFlightDiagram(scenario=scenario)
    assert {p.get_name() for p in _ports(flight, "input")} == set(flight_inputs(scenario))
    assert set(IMAGE_INPUTS) <= set(flight_inputs(scenario))  # the small site has cameras
    ground = MakeGroundDiagram(scenario=scenario)
    assert {p.get_name() for p in _ports(ground, "input")} == {*GROUND_INPUTS, "downlink.images"}


def _sources(diagram, sub):
    """For each input port of subsystem ``sub``: (source subsystem name, source port)."""
    system = diagram.GetSubsystemByName(sub)
    cm = diagram.connection_map()
    out = {}
    for (dst, k), (src, j) in cm.items():
        if dst is system:
            out[dst.get_input_port(k).get_name()] = (
                src.get_name(),
                src.get_output_port(j).get_name(),
            )
    return out


def test_flight_reads_only_sensors_and_the_uplink(mission):
    diagram, scenario = mission
    sources = _sources(diagram, "flight")
    assert set(sources) == set(flight_inputs(scenario))  # every input is fed
    for port, (src, src_port) in sources.items():
        assert not src_port.startswith("truth."), port
        if port == "uplink.commands":
            assert src == "uplink"
        else:
            assert (src, src_port) == ("plant", port)
            assert src_port in SENSOR_PORTS or src_port in IMAGE_INPUTS  # camera sensor
    # The flight diagram holds no plant (it is built from the scenario alone).
    flight = diagram.GetSubsystemByName("flight")
    kinds = {type(s).__name__ for s in flight.GetSystems()}
    assert "MultibodyPlant" not in kinds and "SceneGraph" not in kinds


def test_ground_reads_only_the_downlink(mission):
    diagram, _ = mission
    assert _sources(diagram, "ground") == {
        "downlink.telemetry": ("downlink", "telemetry"),
        "downlink.images": ("downlink", "images"),
    }
    # The links read their producers and, for loss of signal, the plant's radio path.
    radio = {"earth_visible": ("plant", "radio.earth_visible")}
    assert _sources(diagram, "uplink") == {"commands": ("ground", "uplink.commands"), **radio}
    assert _sources(diagram, "downlink") == {
        "telemetry": ("flight", "downlink.telemetry"),
        "images": ("flight", "downlink.images"),
        **radio,
    }


def test_truth_feeds_nothing_inside_the_mission(mission):
    diagram, _ = mission
    plant = diagram.GetSubsystemByName("plant")
    for (dst, k), (src, j) in diagram.connection_map().items():
        if src is plant:
            name = src.get_output_port(j).get_name()
            assert not name.startswith("truth."), (dst.get_name(), dst.get_input_port(k).get_name())
            if name.startswith("radio."):  # radio physics feeds only the link model
                assert dst.get_name() in ("uplink", "downlink"), dst.get_name()
    # ... and the plant's only inputs are the actuator commands, from flight.
    assert {p: s for p, s in _sources(diagram, "plant").items()} == {
        name: ("flight", name)
        for name in (
            "rover.wheel_speed_command",
            "rover.steer_angle_command",
            "rover.gimbal_command",
            "rover.brake_command",
        )
    }


def test_the_mission_link_delays_every_message_by_exactly_its_delay(small_site):
    """Uplink 0.7 s, downlink 1.1 s: every command and telemetry packet arrives exactly
    that long after it was sent, and the rover starts moving only after the first drive
    command could have arrived."""
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    scenario = apply_overrides(
        scenario,
        "{simulation_duration: 4.0, comms: {uplink: {delay_s: 0.7}, downlink: {delay_s: 1.1}},"
        " flight: {telemetry_rate_hz: 5.0}, sensors: {camera: {enabled: false}},"
        " ground: {route: [{duration_s: 10.0, vx_mps: 0.2}]}}",
    )
    logs = simulate(scenario=scenario, site=site)
    up = [r for r in logs.link if r.direction == "uplink"]
    down = [r for r in logs.link if r.direction == "downlink"]
    assert len(up) == 1 and len(down) == 20
    for rows, delay in ((up, 0.7), (down, 1.1)):
        got = [r for r in rows if math.isfinite(r.t_received)]
        assert got, rows
        for r in got:
            assert r.t_received - r.t_sent == pytest.approx(delay, abs=1e-12)
    # In flight at the end: sent within the last delay.
    for r in down:
        if not math.isfinite(r.t_received):
            assert r.t_sent > 4.0 - 1.1 - 1e-9
    tel = logs.telemetry
    np.testing.assert_allclose(tel.t_received - tel.t_sent, 1.1, atol=1e-12)
    assert list(tel.seq) == sorted(tel.seq)
    twist = logs.vectors["flight.twist_command"]
    first = twist.times[np.argmax(twist.data[:, 0] > 0)]
    assert 0.7 <= first <= 0.7 + 2 * scenario.logging.period_s
