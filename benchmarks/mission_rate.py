"""Benchmark: real-time factor of the default mission (plant, flight, ground, link).

    .venv/bin/python benchmarks/mission_rate.py --no-cameras --out bench_mission_rate.json

The issue-13 form of :mod:`benchmarks.sim_rate` (same measurement: ``--repeats`` runs of
``--sim-s`` simulated seconds from fresh contexts, the median): JSON ``{rtf, runs,
...}``; goal rtf >= 3 without cameras on this 2-core machine.
"""

from __future__ import annotations

import argparse
import sys

from sim_rate import main as sim_rate_main


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--no-cameras", action="store_true", help="(the only mode timed today)")
    p.add_argument("--scenario", default="default")
    p.add_argument("--sim-s", type=float, default=30.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if not a.no_cameras:
        p.error("only --no-cameras is timed (benchmarks/render.py times the cameras)")
    args = ["--scenario", a.scenario, "--sim-s", str(a.sim_s), "--repeats", str(a.repeats)]
    if a.out:
        args += ["--out", a.out, "--rtf-key", "rtf"]
    return sim_rate_main(args)


if __name__ == "__main__":
    sys.exit(main())
