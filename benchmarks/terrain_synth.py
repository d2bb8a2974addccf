"""Benchmark: synthesize a large site and load it into a mission diagram.

    .venv/bin/python benchmarks/terrain_synth.py --out bench_terrain.json
    .venv/bin/python benchmarks/terrain_synth.py --size 2048 --out small.json   # quick

Measures (one run each; the machine is shared, so quote the medians of --repeat runs):
synthesis seconds and peak resident memory (sampled with psutil every 50 ms, including
children), craters and rocks placed, and the seconds to open the site and build a
mission diagram ready to simulate (Simulator initialized). Prints a table; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


class PeakRSS:
    """Samples this process's resident set size in a thread; ``peak`` in bytes."""

    def __init__(self, period_s: float = 0.05):
        self.period_s = period_s
        self.peak = 0
        self._stop = threading.Event()
        self._proc = psutil.Process()

    def __enter__(self):
        self.base = self._proc.memory_info().rss
        self.peak = self.base
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._proc.memory_info().rss)
            time.sleep(self.period_s)

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, self._proc.memory_info().rss)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=int, default=8192)
    p.add_argument("--resolution", type=float, default=0.04)
    p.add_argument("--factor", type=int, default=128)
    p.add_argument("--min-crater-m", type=float, default=0.5)
    p.add_argument("--min-rock-m", type=float, default=0.1)
    p.add_argument("--tile", type=int, default=1024)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--keep", default=None, help="keep the site in this directory")
    p.add_argument("--out", default=None, help="write results JSON here")
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out, what="results JSON")

    import numpy as np
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.mission import load_site_layers
    from lunar_drake.scenario import Scenario
    from lunar_drake.site import Site
    from lunar_drake.terrain.synth import SynthConfig, synthesize_site

    config = SynthConfig(
        size_px=args.size,
        resolution_m=args.resolution,
        factor=args.factor,
        seed=args.seed,
        min_crater_m=args.min_crater_m,
        min_rock_m=args.min_rock_m,
        tile_px=args.tile,
        workers=args.workers,
    )
    runs = []
    for _i in range(args.repeat):
        tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-site-"))
        try:
            with PeakRSS() as mem:
                t0 = time.perf_counter()
                products = synthesize_site(
                    config=config, out_dir=tmp, progress=False, overview=False
                )
                synth_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            site = Site(
                dem=tmp / "dem.tif",
                albedo=tmp / "albedo.tif",
                directory=tmp,
                synthesized=True,
                cached=True,
            )
            hf, albedo = load_site_layers(site)
            diagram = MakeMissionDiagram(scenario=Scenario(), heightfield=hf, albedo=albedo)
            sim = Simulator(diagram)
            sim.Initialize()
            hf.height(np.array([0.0]), np.array([0.0]))
            load_s = time.perf_counter() - t0
            runs.append(
                {
                    "synth_s": synth_s,
                    "peak_rss_gb": mem.peak / 1e9,
                    "peak_rss_above_start_gb": (mem.peak - mem.base) / 1e9,
                    "craters": products.stats["craters"],
                    "rocks": products.stats["rocks"],
                    "load_to_diagram_s": load_s,
                    "stage_s": products.stats["timing_s"],
                }
            )
        finally:
            if not args.keep:
                shutil.rmtree(tmp, ignore_errors=True)
    med = {
        k: statistics.median(r[k] for r in runs)
        for k in ("synth_s", "peak_rss_gb", "peak_rss_above_start_gb", "load_to_diagram_s")
    }
    result = {
        "benchmark": "terrain_synth",
        "params": vars(args),
        "cpu_count": os.cpu_count(),
        "runs": runs,
        "median": med,
        "craters": runs[-1]["craters"],
        "rocks": runs[-1]["rocks"],
        "goals": {"synth_s": 30.0, "peak_rss_gb": 2.0, "load_to_diagram_s": 10.0},
    }
    rows = [
        ("site", f"{args.size}^2 px at {args.resolution} m (factor {args.factor})", ""),
        ("synthesis (s, median)", f"{med['synth_s']:.1f}", "<= 30"),
        ("peak RSS (GB)", f"{med['peak_rss_gb']:.2f}", "<= 2"),
        ("craters placed", str(result["craters"]), f">= {args.min_crater_m} m"),
        ("rocks placed", str(result["rocks"]), f">= {args.min_rock_m} m"),
        ("load into diagram (s)", f"{med['load_to_diagram_s']:.2f}", "<= 10"),
    ]
    w = max(len(r[0]) for r in rows)
    print(f"{'metric':<{w}}  {'value':>32}  goal")
    for name, val, goal in rows:
        print(f"{name:<{w}}  {val:>32}  {goal}")
    st = runs[-1]["stage_s"]
    print("stages (s): " + ", ".join(f"{k} {v:.1f}" for k, v in st.items()))
    record_speed_index(result)
    if args.out:
        atomic_write_text(args.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    sys.exit(main())
