"""Benchmark: real-time factor of the default mission (plant, flight, ground, link).

    .venv/bin/python benchmarks/mission_rate.py --out bench_mission_rate.json
    .venv/bin/python benchmarks/mission_rate.py --no-cameras --out bench_mission_rate.json

Without flags (issue 14): the default mission with the mast stereo pair at
``--width`` x ``--height`` (1024 x 768) and ``--rate`` (1 Hz), every frame sent down
the image channel, and the ground's stereo, ICP visual odometry, mapping and planner on
what arrives (``ground.perception``). ``--no-cameras``: cameras off (issue 13). Same
measurement as :mod:`benchmarks.sim_rate` (``--repeats`` runs of ``--sim-s`` simulated
seconds from fresh contexts, the median): JSON ``{rtf, runs, ...}``; goals on this
2-core machine: rtf >= 1 with stereo (aim 2), >= 3 without cameras.
"""

from __future__ import annotations

import argparse
import sys

from sim_rate import main as sim_rate_main


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--no-cameras", action="store_true", help="cameras off")
    p.add_argument("--scenario", default="default")
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--height", type=int, default=768)
    p.add_argument("--rate", type=float, default=1.0, help="stereo frames per second")
    p.add_argument("--sim-s", type=float, default=None,
                   help="simulated seconds per run (30 without cameras, 60 with)")  # fmt: skip
    p.add_argument("--repeats", type=int, default=None, help="runs (3 without cameras, 2 with)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.no_cameras:
        text = "{sensors: {camera: {enabled: false}}}"
        sim_s, repeats = a.sim_s or 30.0, a.repeats or 3
    else:
        text = (
            f"{{sensors: {{camera: {{enabled: true, width: {a.width}, height: {a.height}, "
            f"rate_hz: {a.rate}}}}}, flight: {{images: {{enabled: true, every_n_frames: 1}}}}, "
            "ground: {perception: {enabled: true}}}"
        )
        sim_s, repeats = a.sim_s or 60.0, a.repeats or 2
    args = ["--scenario", a.scenario, "--sim-s", str(sim_s), "--repeats", str(repeats),
            "--scenario-text", text, "--goal", "3" if a.no_cameras else "1"]  # fmt: skip
    if a.out:
        args += ["--out", a.out, "--rtf-key", "rtf"]
    return sim_rate_main(args)


if __name__ == "__main__":
    sys.exit(main())
