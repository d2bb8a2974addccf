"""``lunar-drake render``: one stereo pair of a scenario, written as image files."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from lunar_drake.errors import ConfigError


def render_stereo(*, scenario, time_s: float = 0.0, out_dir, progress: bool = True) -> list:
    """Simulates the scenario to ``time_s`` (the rover drives its route) and writes the
    stereo pair rendered at that time: ``left.png``/``right.png`` (16-bit PNG of the
    12-bit raw codes), ``*_preview.png`` (8-bit), ``*_depth.tiff`` (float32 m),
    ``*_label.png`` (0 sky, 1 terrain, 2 rover) and ``render.json`` (camera, Sun)."""
    import cv2
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.mission import load_site_layers
    from lunar_drake.site import ensure_site
    from lunar_drake.systems.frame_writer import write_png

    if not scenario.rover.enabled:
        raise ConfigError("render needs a rover (rover.enabled: true) to carry the cameras")
    if not 0.0 <= time_s <= 1.0e6:
        raise ConfigError(f"--time {time_s!r} s; allowed [0, 1e6] s")
    c = scenario.camera
    c.enabled = True
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    hf, albedo = load_site_layers(ensure_site(scenario, progress=progress))
    # The camera renders on its period; land exactly on a frame at or after time_s.
    period = 1.0 / c.rate_hz
    t_frame = float(np.ceil(time_s / period - 1e-9) * period)
    diagram = MakeMissionDiagram(
        scenario=scenario, heightfield=hf, albedo=albedo, duration_s=max(t_frame, 1.0) + period
    )
    sim = Simulator(diagram)
    sim.AdvanceTo(t_frame + 1e-6)
    root = sim.get_context()
    cam = diagram.GetSubsystemByName("camera")
    ctx = cam.GetMyContextFromRoot(root)
    paths = []
    for n in ("left", "right"):
        f = cam.frame(ctx, n)
        write_png(out / f"{n}.png", f.raw)
        write_png(out / f"{n}_preview.png", f.preview)
        write_png(out / f"{n}_label.png", f.label.astype(np.uint8))
        tmp = out / f".{n}_depth.tmp-{os.getpid()}.tiff"
        cv2.imwrite(str(tmp), np.where(np.isfinite(f.depth), f.depth, 0.0).astype(np.float32))
        os.replace(tmp, out / f"{n}_depth.tiff")
        paths += [out / f"{n}.png", out / f"{n}_preview.png"]
    dctx = diagram.GetMyContextFromRoot(root)
    info = {
        "time_s": float(t_frame),
        "sun_direction_W": diagram.GetOutputPort("sun.direction_W").Eval(dctx).tolist(),
        "sun_elevation_deg": float(diagram.GetOutputPort("sun.elevation_deg").Eval(dctx)[0]),
        "camera": {
            "width": c.width,
            "height": c.height,
            "fov_y_deg": c.fov_y_deg,
            "exposure_s": c.exposure_s,
            "gain": c.gain,
            "adc_bits": 12,
        },
        "rover_pose": diagram.GetOutputPort("rover.pose").Eval(dctx)[:6].tolist(),
    }
    tmp = out / f".render.json.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(info, indent=2) + "\n")
    os.replace(tmp, out / "render.json")
    paths.append(out / "render.json")
    return paths
