"""run_mission: resolve the site, build the mission diagram, simulate, write a run directory."""

from __future__ import annotations

import dataclasses as dc
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np

from lunar_drake.diagrams.rover import BodyPoseVector
from lunar_drake.errors import LunarDrakeError, SimulationError
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


def load_site_layers(site: Site, *, max_albedo_px: int = 1024, in_memory_max_px: int = 4096 * 4096):
    """Opens the site's Heightfield and a reduced albedo grid (or None).

    Rasters up to ``in_memory_max_px`` pixels are loaded into memory; larger ones stay
    file-backed (windowed reads through the Heightfield's block cache).
    """
    from lunar_drake.terrain.heightfield import Heightfield

    hf = Heightfield.open(site.dem)
    rows, cols = hf.shape
    if rows * cols <= in_memory_max_px:
        # Small sites are read whole: per-step contact queries then skip the block cache.
        z = hf.read_window(0, 0, rows, cols)
        hf = Heightfield.from_array(
            z, resolution_m=hf.resolution_m, crs=hf.crs, origin_xy=hf.origin_xy
        )
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
    cameras: bool = True,
) -> MissionResult:
    """Runs one mission headless (or with ``meshcat``) and writes the run directory.

    The run directory holds ``scenario.yaml`` (the resolved scenario), ``summary.json``
    (deterministic: same scenario, same bytes) and ``timing.json`` (wall-clock figures),
    plus ``meshcat.html`` (a static replay) when Meshcat is on.
    """
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
    from pydrake.systems.framework import DiagramBuilder, EventStatus
    from pydrake.systems.primitives import LogVectorOutput

    from lunar_drake.diagrams.mission import ROVER_PORTS, MakeMissionDiagram

    if duration is not None and not (math.isfinite(duration) and 0 <= duration <= 1e7):
        from lunar_drake.errors import OutOfRangeError

        raise OutOfRangeError(f"duration = {duration!r} s; allowed [0, 1e7] s")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _clear_previous_outputs(out_dir)
    t0 = time.perf_counter()
    site = ensure_site(scenario, cache_dir=cache_dir, progress=progress)
    t_site = time.perf_counter()
    heightfield, albedo = load_site_layers(site)
    mission = MakeMissionDiagram(
        scenario=scenario,
        heightfield=heightfield,
        albedo=albedo,
        meshcat=meshcat,
        cameras=cameras,
        duration_s=scenario.simulation_duration if duration is None else float(duration),
    )
    builder = DiagramBuilder()
    builder.AddSystem(mission)
    has_rover = mission.HasOutputPort("rover.pose")
    loggers = {}
    if has_rover:
        for name in ROVER_PORTS:
            loggers[name] = LogVectorOutput(
                mission.GetOutputPort(name), builder, scenario.rover.log_period_s
            )
    writer = None
    if mission.HasOutputPort("camera.frame_index") and scenario.camera.save_frames:
        from pydrake.systems.sensors import ImageGrey8U

        from lunar_drake.systems.frame_writer import FrameWriter

        writer = builder.AddSystem(
            FrameWriter(
                names=["left", "right"],
                out_dir=out_dir / "frames",
                rate_hz=scenario.camera.rate_hz,
                preview_image_type=ImageGrey8U,
            )
        )
        builder.Connect(mission.GetOutputPort("camera.frame_index"), writer.frame_index_input)
        for n in ("left", "right"):
            builder.Connect(mission.GetOutputPort(f"camera.{n}.raw"), writer.raw_inputs[n])
            builder.Connect(mission.GetOutputPort(f"camera.{n}.preview"), writer.preview_inputs[n])
    diagram = builder.Build()
    diagram.set_name("run")
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    stop_reason = {"reason": "duration reached"}
    if has_rover:
        off_port = mission.GetOutputPort("rover.off_terrain")
        pose_port = mission.GetOutputPort("rover.pose")

        def monitor(root_context):
            ctx = mission.GetMyContextFromRoot(root_context)
            if off_port.Eval(ctx)[0] > 0.5:
                x, y = pose_port.Eval(ctx)[:2]
                b = heightfield.bounds
                stop_reason["reason"] = (
                    f"rover left the terrain at t = {root_context.get_time():.2f} s, "
                    f"chassis at ({x:.2f}, {y:.2f}) m; site x in [{b.left:g}, {b.right:g}], "
                    f"y in [{b.bottom:g}, {b.top:g}] m"
                )
                return EventStatus.ReachedTermination(diagram, stop_reason["reason"])
            return EventStatus.DidNothing()

        simulator.set_monitor(monitor)
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
    try:
        zc = float(heightfield.height(np.array([0.0]), np.array([0.0]))[0])
    except LunarDrakeError:
        zc = None
    summary = {
        "scenario": scenario_name,
        "random_seed": scenario.random_seed,
        "simulated_s": float(simulator.get_context().get_time()),
        "stop_reason": stop_reason["reason"],
        "diagram": mission.get_name(),
        "systems": sorted(re.sub(r"@[0-9a-f]+$", "", s.get_name()) for s in mission.GetSystems()),
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
    if has_rover:
        root = simulator.get_context()
        summary["rover"] = _write_rover_logs(out_dir, loggers, root, scenario)
    if writer is not None:
        summary["camera_frames"] = len(writer.frames_written)
    timing = {
        "site_s": t_site - t0,
        "site_cached": site.cached,
        "build_s": t_built - t_site,
        "simulate_s": t_sim - t_built,
        "realtime_factor": (
            simulator.get_context().get_time() / (t_sim - t_built) if t_sim > t_built else None
        ),
        "site_dir": str(site.directory or site.dem),
    }
    _write_text(out_dir / "scenario.yaml", dump_scenario(scenario))
    _write_text(out_dir / "summary.json", json.dumps(summary, indent=2, sort_keys=True) + "\n")
    _write_text(out_dir / "timing.json", json.dumps(timing, indent=2, sort_keys=True) + "\n")
    return MissionResult(out_dir=out_dir, summary=summary, timing=timing, meshcat_url=url)


_LOG_COLUMNS = {
    "rover.pose": BodyPoseVector.FIELDS,
    "rover.imu": (
        "gyro_x_radps",
        "gyro_y_radps",
        "gyro_z_radps",
        "accel_x_mps2",
        "accel_y_mps2",
        "accel_z_mps2",
    ),
    "rover.star_tracker": ("qw", "qx", "qy", "qz"),
    "rover.twist_command": ("vx_mps", "vy_mps", "wz_radps"),
    "rover.energy": ("energy_J",),
}
_LOG_FILES = {
    "rover.pose": "truth.csv",
    "rover.imu": "imu.csv",
    "rover.star_tracker": "star_tracker.csv",
    "rover.encoder_angles": "encoders.csv",
    "rover.wheel_state": "wheels.csv",
    "rover.twist_command": "route.csv",
    "rover.energy": "energy.csv",
}


def _write_csv(path: Path, columns, times, data) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w") as f:
        f.write(",".join(["t_s", *columns]) + "\n")
        for k, t in enumerate(times):
            f.write(",".join([f"{t:.6f}", *(f"{v:.9g}" for v in data[:, k])]) + "\n")
    os.replace(tmp, path)


def _write_rover_logs(out_dir: Path, loggers, root, scenario) -> dict:
    """Writes the rover CSV logs; returns a deterministic summary of the traverse."""
    from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS

    wheels = ("fl", "fr", "rl", "rr")
    cols = dict(_LOG_COLUMNS)
    cols["rover.encoder_angles"] = tuple(f"{w}_angle_rad" for w in wheels)
    cols["rover.wheel_state"] = tuple(f"{w}_{f}" for w in wheels for f in WHEEL_STATE_FIELDS)
    logs = {}
    for name, logger in loggers.items():
        log = logger.FindLog(root)
        logs[name] = (log.sample_times(), log.data())
        if name in _LOG_FILES:
            _write_csv(out_dir / _LOG_FILES[name], cols[name], *logs[name])
    t, pose = logs["rover.pose"]
    xy = pose[:2]
    dist = float(np.sum(np.linalg.norm(np.diff(xy, axis=1), axis=0))) if len(t) > 1 else 0.0
    _, ws = logs["rover.wheel_state"]
    nf = len(WHEEL_STATE_FIELDS)
    slip = ws[2::nf]
    moving = np.abs(pose[6]) + np.abs(pose[7]) > 0.02
    return {
        "distance_m": round(dist, 6),
        "final_pose": [round(float(v), 6) for v in pose[:6, -1]],
        "max_tilt_deg": round(float(np.degrees(np.max(np.hypot(pose[3], pose[4])))), 4),
        "max_sinkage_m": round(float(np.max(ws[0::nf])), 6),
        "mean_slip_moving": round(float(np.mean(slip[:, moving])), 6) if moving.any() else 0.0,
        "energy_J": round(float(logs["rover.energy"][1][0, -1]), 4),
        "logs": sorted(_LOG_FILES.values()),
    }


def _clear_previous_outputs(out_dir: Path) -> None:
    """Removes the files an earlier run wrote into ``out_dir`` (only those), so a shorter
    or camera-less rerun does not leave stale frames or logs next to its summary."""
    import shutil

    names = ["scenario.yaml", "summary.json", "timing.json", "meshcat.html", *_LOG_FILES.values()]
    for n in names:
        (out_dir / n).unlink(missing_ok=True)
    shutil.rmtree(out_dir / "frames", ignore_errors=True)
