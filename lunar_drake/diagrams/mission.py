"""MakeMissionDiagram: the one diagram every run simulates.

Today it holds the plant (with SceneGraph), the TerrainSource and, with Meshcat, the
terrain view and Drake's visualizers. Later work adds the rover, cameras, flight and
ground software and the comms links to this same factory. Exported ports are named
``<subsystem>.<signal>`` (manipulation ``station.py`` style).
"""

from __future__ import annotations

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.multibody.plant import AddMultibodyPlant
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import SharedPointerSystem
from pydrake.visualization import ApplyVisualizationConfig

from lunar_drake.scenario import Scenario
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.terrain_visualizer import TerrainVisualizer
from lunar_drake.terrain.heightfield import Heightfield


def MakeMissionDiagram(
    *, scenario: Scenario, heightfield: Heightfield, albedo: np.ndarray | None = None, meshcat=None
):
    """Builds the mission diagram (named ``mission``).

    Args:
        scenario: the validated scenario.
        heightfield: the site terrain.
        albedo: optional albedo grid for the Meshcat terrain colours.
        meshcat: a pydrake Meshcat, or None for headless runs.

    Exported output ports: ``terrain.heightfield``.
    """
    builder = DiagramBuilder()
    plant, _scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    plant.Finalize()
    terrain = builder.AddNamedSystem("terrain", TerrainSource(heightfield=heightfield))
    builder.ExportOutput(terrain.heightfield_output, "terrain.heightfield")
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
