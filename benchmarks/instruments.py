"""Benchmark: the prospecting scenario -- how well the ground's hydrogen map from the
neutron spectrometer matches the world model.

    .venv/bin/python benchmarks/instruments.py --out bench_instruments.json
    .venv/bin/python benchmarks/instruments.py --duration 600 --out quick.json   # part of it

Runs the ``prospect`` scenario (the default site, a lawn-mower of six 50 m lanes 10 m
apart over about 2500 m^2, NSS records down the link's science channel; the orbital map,
stereo and VO, as the default mission) and writes its run directory under ``--runs``.
Two scores of the same 2 m map (``summary.json`` ``science``, :func:`lunar_drake.metrics.science`):

* ``world_r`` (the map against the world): over the cells the ground's map publishes
  (:func:`lunar_drake.science.products.nss_grid`: a cell's pooled counts, where at least
  half of its records' detector response came from the cell), the correlation between
  the map's water-equivalent hydrogen and the world model's depth-weighted hydrogen
  column averaged over each cell (:func:`lunar_drake.science.scoring.nss_world`);
  ``world_rmse_wt_pct``, ``world_bias_wt_pct`` (map less world) over the same cells.
  Goal (issue 29): r >= 0.85.
* ``footprint_r`` (the instrument's performance): over 2 m cells holding at least 3
  records, the ground's pooled estimate against the footprint hydrogen the detector saw
  at its true positions (:func:`lunar_drake.science.products.nss_truth`). Goal (issue
  15): r >= 0.9.

Both are binned where the ground puts the records (the downlinked on-board estimate
moved by the ground's VO correction), so the placing error counts. ``area_m2`` is the
lawn-mower's bounding box.
``speed_index_s`` (``benchmarks/speed_index.py``: ``../shared/bench/speed_index.py`` run
in a child of this process) dates the machine. Prints a table; writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="prospect")
    p.add_argument("--scenario-text", default="{}", help="YAML overrides of the scenario")
    p.add_argument(
        "--duration", type=float, default=None, help="simulated s (default: the scenario's)"
    )
    p.add_argument("--runs", default="runs/instruments", help="run directory to write")
    p.add_argument("--out", default=None, help="write results as JSON here")
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out)
    from lunar_drake import metrics, outputs
    from lunar_drake.files import staged_directory
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    s = load_scenario(scenario_name=args.scenario, scenario_text=args.scenario_text)
    if args.duration is not None:
        s.simulation_duration = args.duration
    site = load_site(s, progress=True)
    t0 = time.perf_counter()
    logs = simulate(scenario=s, site=site, progress=True, stop_after_goals_s=20.0)
    wall = time.perf_counter() - t0
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    with staged_directory(Path(args.runs)) as tmp:
        outputs.write_run(tmp, scenario=s, logs=logs, summary=summary, timing=logs.wall, site=site)
    sci = summary["science"]
    speed = measure_speed_index()
    xs = [g.x_m for g in s.ground.goals] + [s.rover.spawn_x_m]
    ys = [g.y_m for g in s.ground.goals] + [s.rover.spawn_y_m]
    doc = {
        "world_r": sci.get("nss_world_r"),
        "world_cells": sci.get("nss_world_cells"),
        "world_rmse_wt_pct": sci.get("nss_world_rmse_wt_pct"),
        "world_bias_wt_pct": sci.get("nss_world_bias_wt_pct"),
        "cells_seen": sci.get("nss_cells_seen"),
        "footprint_r": sci.get("nss_footprint_r"),
        "footprint_cells": sci.get("nss_footprint_cells"),
        "footprint_rmse_wt_pct": sci.get("nss_footprint_rmse_wt_pct"),
        "footprint_bias_wt_pct": sci.get("nss_footprint_bias_wt_pct"),
        "lcs_world_r": sci.get("lcs_world_r"),
        "lcs_world_rmse_K": sci.get("lcs_world_rmse_K"),
        "lcs_spot_rmse_K": sci.get("lcs_spot_rmse_K"),
        "nirvss_world": sci.get("nirvss_world"),
        "area_m2": round((max(xs) - min(xs)) * (max(ys) - min(ys)), 1),
        "records": sci["nss_records"],
        "weh_est_mean_wt_pct": sci.get("weh_est_mean_wt_pct"),
        "weh_truth_mean_wt_pct": sci.get("weh_truth_mean_wt_pct"),
        "goals_reached": sum(1 for g in summary["goals"] if g["reached"]),
        "goals": len(summary["goals"]),
        "distance_m": summary["rover"]["distance_m"],
        "final_position_error_m": summary["localization"].get("final_position_error_m"),
        "simulated_s": summary["simulated_s"],
        "wall_s": round(wall, 1),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
        "run_dir": str(Path(args.runs).resolve()),
    }

    def f(v, fmt):
        return format(v, fmt) if v is not None else "-"

    print(f"{'score (2 m cells)':<34} {'r':>6} {'cells':>6} {'rmse wt%':>9} {'bias wt%':>9}")
    for label, k in (("map vs world column over the cell", "world"),
                     ("instrument: vs footprint at truth", "footprint")):  # fmt: skip
        print(f"{label:<34} {f(doc[k + '_r'], '.3f'):>6} {f(doc[k + '_cells'], 'd'):>6} "
              f"{f(doc[k + '_rmse_wt_pct'], '.3f'):>9} {f(doc[k + '_bias_wt_pct'], '+.3f'):>9}")
    print(f"cells seen {doc['cells_seen']}, records {doc['records']}, area "
          f"{doc['area_m2']:.0f} m2, goals {doc['goals_reached']}/{doc['goals']}, driven "
          f"{doc['distance_m']:.1f} m, LCS map vs world r {f(doc['lcs_world_r'], '.3f')}, "
          f"wall {doc['wall_s']} s")
    print(speed_index_line(speed))
    if args.out:
        atomic_write_text(args.out, json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("instruments.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.exit(main())
