"""run_mission: resolve the site, build the mission diagram, simulate, write a run directory."""

from __future__ import annotations

import dataclasses as dc
import json
import os
import re
import time
from pathlib import Path

import numpy as np

from lunar_drake.errors import SimulationError
from lunar_drake.scenario import Scenario, dump_scenario
from lunar_drake.site import Site, ensure_site


@dc.dataclass
class MissionResult:
    """What a run produced. ``summary`` is also written to ``out_dir/summary.json``."""

    out_dir: Path
    summary: dict
    timing: dict
    meshcat_url: str | None


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def load_site_layers(site: Site, *, max_albedo_px: int = 1024):
    """Opens the site's Heightfield and a reduced albedo grid (or None)."""
    from lunar_drake.terrain.heightfield import Heightfield

    hf = Heightfield.open(site.dem)
    albedo = None
    if site.albedo is not None:
        albedo = Heightfield.open(site.albedo).decimated(max_size=max_albedo_px)[0]
    return hf, albedo


def run_mission(
    *,
    scenario: Scenario,
    scenario_name: str,
    out_dir: str | Path,
    meshcat=None,
    duration: float | None = None,
    cache_dir: str | Path | None = None,
    progress: bool = True,
) -> MissionResult:
    """Runs one mission headless (or with ``meshcat``) and writes the run directory.

    The run directory holds ``scenario.yaml`` (the resolved scenario), ``summary.json``
    (deterministic: same scenario, same bytes) and ``timing.json`` (wall-clock figures),
    plus ``meshcat.html`` (a static replay) when Meshcat is on.
    """
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    site = ensure_site(scenario, cache_dir=cache_dir, progress=progress)
    t_site = time.perf_counter()
    heightfield, albedo = load_site_layers(site)
    diagram = MakeMissionDiagram(
        scenario=scenario, heightfield=heightfield, albedo=albedo, meshcat=meshcat
    )
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    if meshcat is not None:
        meshcat.StartRecording(set_visualizations_while_recording=True)
    simulator.Initialize()
    t_built = time.perf_counter()
    end = scenario.simulation_duration if duration is None else float(duration)
    try:
        simulator.AdvanceTo(end)
    except Exception as exc:  # Drake raises RuntimeError on integrator failures.
        raise SimulationError(
            f"simulation failed at t = {simulator.get_context().get_time():.3f} s: {exc}"
        ) from exc
    t_sim = time.perf_counter()
    url = None
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()
        _write_text(out_dir / "meshcat.html", meshcat.StaticHtml())
        url = meshcat.web_url()

    b = heightfield.bounds
    x0, x1, y0, y1 = b.left, b.right, b.bottom, b.top
    zc = float(heightfield.height(np.array([0.0]), np.array([0.0]))[0])
    summary = {
        "scenario": scenario_name,
        "random_seed": scenario.random_seed,
        "simulated_s": float(simulator.get_context().get_time()),
        "diagram": diagram.get_name(),
        "systems": sorted(re.sub(r"@[0-9a-f]+$", "", s.get_name()) for s in diagram.GetSystems()),
        "site": {
            "dem": str(site.dem.name),
            "synthesized": site.synthesized,
            "shape_px": list(heightfield.shape),
            "resolution_m": heightfield.resolution_m,
            "bounds_m": [x0, x1, y0, y1],
            "z_at_origin_m": zc,
        },
    }
    if site.directory is not None:
        info = json.loads((site.directory / "site.json").read_text())
        summary["site"]["craters"] = info["stats"]["craters"]
        summary["site"]["rocks"] = info["stats"]["rocks"]
        summary["site"]["content_key"] = info["stats"]["content_key"]
    timing = {
        "site_s": t_site - t0,
        "site_cached": site.cached,
        "build_s": t_built - t_site,
        "simulate_s": t_sim - t_built,
        "realtime_factor": (end / (t_sim - t_built)) if t_sim > t_built else None,
        "site_dir": str(site.directory or site.dem),
    }
    _write_text(out_dir / "scenario.yaml", dump_scenario(scenario))
    _write_text(out_dir / "summary.json", json.dumps(summary, indent=2, sort_keys=True) + "\n")
    _write_text(out_dir / "timing.json", json.dumps(timing, indent=2, sort_keys=True) + "\n")
    return MissionResult(out_dir=out_dir, summary=summary, timing=timing, meshcat_url=url)
