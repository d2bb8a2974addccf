"""``lunar-drake render``: one stereo pair of a scenario, written as image files
(:func:`render_stereo`)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from lunar_drake.cli._common import add_subcommand, load_named_scenario
from lunar_drake.errors import ConfigError
from lunar_drake.files import (
    atomic_path,
    atomic_write_text,
    check_replaceable,
    staged_directory,
)

#: The files of a render directory.
RENDER_FILES = (
    *(
        f"{n}{s}"
        for n in ("left", "right")
        for s in (".png", "_preview.png", "_label.png", "_depth.tiff")
    ),
    "render.json",
)


def render_stereo(*, scenario, time_s: float = 0.0, out_dir, progress: bool = True) -> list:
    """Simulates the scenario (the rover drives its route) to the first camera frame at
    or after ``time_s`` and writes that stereo pair into ``out_dir`` (replaced as a
    whole, only when complete): ``left.png``/``right.png`` (16-bit PNG of the 12-bit raw
    codes), ``*_preview.png`` (8-bit), ``*_depth.tiff`` (float32 m), ``*_label.png``
    (0 sky, 1 terrain, 2 rover) and ``render.json`` (time, camera, Sun, rover pose)."""
    import cv2
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.site import load_site
    from lunar_drake.systems.frame_writer import write_png

    if not 0.0 <= time_s <= 1.0e6:
        raise ConfigError(f"--time {time_s:g} s is out of range; allowed [0, 1e6] s")
    scenario = copy.deepcopy(scenario)
    c = scenario.sensors.camera
    c.enabled = True
    # The camera renders on its period; land exactly on a frame at or after time_s.
    period = 1.0 / c.rate_hz
    t_frame = float(np.ceil(time_s / period - 1e-9) * period)
    scenario.simulation_duration = max(t_frame + c.delay_s, 1.0) + period
    out = Path(out_dir)
    check_replaceable(out, allowed=RENDER_FILES, what="render directory")
    with staged_directory(out, what="render directory") as tmp:
        site = load_site(scenario, progress=progress)
        diagram = MakeMissionDiagram(scenario=scenario, site=site)
        sim = Simulator(diagram)
        sim.AdvanceTo(t_frame + c.delay_s + 1e-6)
        root = sim.get_context()
        cam = diagram.GetSubsystemByName("plant").GetSubsystemByName("camera")
        ctx = cam.GetMyContextFromRoot(root)
        for n in ("left", "right"):
            f = cam.frame(ctx, n)
            write_png(tmp / f"{n}.png", f.raw)
            write_png(tmp / f"{n}_preview.png", f.preview)
            write_png(tmp / f"{n}_label.png", f.label.astype(np.uint8))
            depth = np.where(np.isfinite(f.depth), f.depth, 0.0).astype(np.float32)
            with atomic_path(tmp / f"{n}_depth.tiff", what="depth image") as p:
                cv2.imwrite(str(p), depth)
        dctx = diagram.GetMyContextFromRoot(root)
        info = {
            "time_s": float(t_frame),
            "sun_direction_W": diagram.GetOutputPort("truth.sun_direction_W").Eval(dctx).tolist(),
            "sun_elevation_deg": float(
                diagram.GetOutputPort("truth.sun_elevation_deg").Eval(dctx)[0]
            ),
            "camera": {
                "width": c.width,
                "height": c.height,
                "fov_y_deg": c.fov_y_deg,
                "exposure_s": c.exposure_s,
                "gain": c.gain,
                "adc_bits": 12,
            },
            "rover_pose": diagram.GetOutputPort("truth.pose").Eval(dctx)[:6].tolist(),
        }
        atomic_write_text(tmp / "render.json", json.dumps(info, indent=2) + "\n")
    names = [f"{n}{s}" for n in ("left", "right") for s in (".png", "_preview.png")]
    return [out / n for n in names] + [out / "render.json"]


def command(args) -> int:
    scenario, _ = load_named_scenario(args)
    paths = render_stereo(
        scenario=scenario, time_s=args.time, out_dir=args.out, progress=not args.no_progress
    )
    for p in paths:
        print(p)
    return 0


def add_parser(sub) -> None:
    rd = add_subcommand(sub, "render", help="render the mast stereo pair of a scenario")
    rd.add_argument(
        "--scenario",
        default="default",
        help="scenario name in the packaged file, or FILE.yaml[:NAME]",
    )
    rd.add_argument("--scenario-text", default="{}", help="YAML overrides")
    rd.add_argument("--time", type=float, default=0.0, help="sim time of the frame (s)")
    rd.add_argument("--out", required=True, help="output directory")
    rd.add_argument("--no-progress", action="store_true")
    rd.set_defaults(func=command)
