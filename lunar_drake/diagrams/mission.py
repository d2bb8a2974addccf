"""MakeMissionDiagram: plant, flight and ground software joined through the link.

Wiring only::

    plant --sensors--> flight --actuator commands--> plant
    flight --downlink.telemetry--> [downlink] --> ground
    ground --uplink.commands--> [uplink] --> flight
    plant --truth.*--> (exported for scoring and logging only)

The flight diagram's inputs come only from plant sensor ports and the uplink; the ground
diagram's only from the downlink; ``truth.*`` ports feed nothing inside the mission
(``tests/test_seams.py`` proves each). What each is handed when it is built: the plant
the site, the ground only the pre-flight map product (orbital by default; the true DEM
only as a declared oracle), the flight only the scenario's rover description and its
pre-flight slip calibration. Exported: every plant output (sensors, cameras,
``truth.*``), the flight's on-board records (``flight.*``), the ground's received
telemetry (``ground.*``).
"""

from __future__ import annotations

from pydrake.systems.framework import DiagramBuilder

from lunar_drake.comms.light_time import light_time_s
from lunar_drake.diagrams.flight import (
    MakeFlightDiagram,
    image_timing,
    science_timing,
    sends_images,
    sends_science,
)
from lunar_drake.diagrams.ground import MakeGroundDiagram
from lunar_drake.diagrams.plant import MakePlantDiagram
from lunar_drake.ephemeris.sun_earth import SiteLocation
from lunar_drake.preflight import ground_map_product
from lunar_drake.scenario import Scenario
from lunar_drake.site import SiteData
from lunar_drake.systems.link import Link


def MakeMissionDiagram(*, scenario: Scenario, site: SiteData, meshcat=None, map_product=None):
    """Builds the mission diagram (named ``mission``) with subsystems ``plant``,
    ``flight``, ``ground``, ``uplink`` and ``downlink``. The plant gets the site; the
    ground only its pre-flight map product (``map_product``, default
    :func:`lunar_drake.preflight.ground_map_product`); the flight its slip calibration
    (:func:`lunar_drake.diagrams.flight.flight_estimator_config`)."""
    builder = DiagramBuilder()
    plant = builder.AddNamedSystem(
        "plant", MakePlantDiagram(scenario=scenario, site=site, meshcat=meshcat)
    )
    flight = builder.AddNamedSystem("flight", MakeFlightDiagram(scenario=scenario))
    # The ground gets the pre-flight map product, never the site.
    if map_product is None:
        map_product = ground_map_product(scenario, site)
    ground = builder.AddNamedSystem(
        "ground", MakeGroundDiagram(scenario=scenario, map_product=map_product)
    )
    light = None
    if scenario.comms.uplink.delay_s is None or scenario.comms.downlink.delay_s is None:
        light = light_time_s(
            site=SiteLocation(scenario.site.latitude_deg, scenario.site.longitude_deg),
            epoch_utc=scenario.site.epoch_utc,
            extra_kernels=scenario.lighting.extra_kernels,
        )
    uplink = builder.AddNamedSystem(
        "uplink",
        Link(
            direction="uplink",
            topics={"commands": 1.0 / scenario.ground.rate_hz},
            config=scenario.comms.uplink,
            seed=scenario.random_seed,
            light_time_s=light,
        ),
    )
    downlink = builder.AddNamedSystem(
        "downlink",
        Link(
            direction="downlink",
            topics={
                "telemetry": 1.0 / scenario.flight.telemetry_rate_hz,
                **({"images": image_timing(scenario)} if sends_images(scenario) else {}),
                **({"science": science_timing(scenario)} if sends_science(scenario) else {}),
            },
            config=scenario.comms.downlink,
            seed=scenario.random_seed,
            light_time_s=light,
        ),
    )
    # Sensors to flight; flight's actuator commands to the plant.
    for k in range(flight.num_input_ports()):
        name = flight.get_input_port(k).get_name()
        if plant.HasOutputPort(name):
            builder.Connect(plant.GetOutputPort(name), flight.get_input_port(k))
    for k in range(plant.num_input_ports()):
        name = plant.get_input_port(k).get_name()
        builder.Connect(flight.GetOutputPort(name), plant.get_input_port(k))
    # The link.
    builder.Connect(ground.GetOutputPort("uplink.commands"), uplink.inputs["commands"])
    builder.Connect(uplink.outputs["commands"], flight.GetInputPort("uplink.commands"))
    builder.Connect(flight.GetOutputPort("downlink.telemetry"), downlink.inputs["telemetry"])
    builder.Connect(downlink.outputs["telemetry"], ground.GetInputPort("downlink.telemetry"))
    if sends_images(scenario):
        builder.Connect(flight.GetOutputPort("downlink.images"), downlink.inputs["images"])
        builder.Connect(downlink.outputs["images"], ground.GetInputPort("downlink.images"))
    if sends_science(scenario):
        builder.Connect(flight.GetOutputPort("downlink.science"), downlink.inputs["science"])
        builder.Connect(downlink.outputs["science"], ground.GetInputPort("downlink.science"))
    if plant.HasOutputPort("radio.earth_visible"):  # loss of signal behind terrain
        for link in (uplink, downlink):
            builder.Connect(plant.GetOutputPort("radio.earth_visible"), link.earth_visible_input)
    if meshcat is not None:  # the ground's command preview beside the live rover
        from lunar_drake.systems.preview_visualizer import PreviewVisualizer

        viz = builder.AddNamedSystem("preview_visualizer", PreviewVisualizer(meshcat=meshcat))
        builder.Connect(ground.GetOutputPort("ground.preview"), viz.preview_input)
    # Exports for scoring, logging and displays.
    for k in range(plant.num_output_ports()):
        port = plant.get_output_port(k)
        builder.ExportOutput(port, port.get_name())
    for k in range(flight.num_output_ports()):
        port = flight.get_output_port(k)
        if port.get_name().startswith("flight."):
            builder.ExportOutput(port, port.get_name())
    for k in range(ground.num_output_ports()):
        port = ground.get_output_port(k)
        if port.get_name().startswith("ground."):
            builder.ExportOutput(port, port.get_name())
    diagram = builder.Build()
    diagram.set_name("mission")
    return diagram


def ground_operator(mission):
    """The mission's :class:`~lunar_drake.systems.ground_operator.GroundOperator`: the
    operator API (``send_goal``, ``stop``, ``resume``, ``drive_arc``, ``point_mast``;
    each takes the simulator's root context) between ``AdvanceTo`` calls::

        simulator = Simulator(mission)
        ops = ground_operator(mission)
        simulator.AdvanceTo(5.0)
        ops.send_goal(simulator.get_mutable_context(), x_m=9.0, y_m=0.0)
        simulator.AdvanceTo(120.0)
    """
    return mission.GetSubsystemByName("ground").GetSubsystemByName("ground.operator")
