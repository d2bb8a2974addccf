"""Benchmark: the prospecting scenario -- how well the ground's hydrogen map from the
neutron spectrometer matches the world model.

    .venv/bin/python benchmarks/instruments.py --out bench_instruments.json
    .venv/bin/python benchmarks/instruments.py --duration 600 --out quick.json   # part of it

Runs the ``prospect`` scenario (the default site, a lawn-mower of six 50 m lanes 10 m
apart over about 2500 m^2, NSS records down the link's science channel; cameras off)
and writes its run directory under ``--runs``. ``nss_truth_r`` is the correlation, over
2 m cells along the path, between the ground's water-equivalent hydrogen (each cell's
epithermal counts pooled and inverted, placed at the downlinked on-board estimate) and
the world model's footprint hydrogen at the detector's true positions; ``rmse_wt_pct``
and ``bias_wt_pct`` (mean estimate less truth) over the same cells
(:func:`lunar_drake.science.products.nss_truth`); ``area_m2`` the lawn-mower's
bounding box. Goal (issue 15): r >= 0.9 over the 2500 m^2 area with default noise.
Prints a table; writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from lunar_drake.files import atomic_write_text, check_output_file


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
    xs = [g.x_m for g in s.ground.goals] + [s.rover.spawn_x_m]
    ys = [g.y_m for g in s.ground.goals] + [s.rover.spawn_y_m]
    doc = {
        "nss_truth_r": sci.get("nss_truth_r"),
        "area_m2": round((max(xs) - min(xs)) * (max(ys) - min(ys)), 1),
        "records": sci["nss_records"],
        "cells": sci.get("nss_cells"),
        "rmse_wt_pct": sci.get("nss_rmse_wt_pct"),
        "bias_wt_pct": sci.get("nss_bias_wt_pct"),
        "weh_est_mean_wt_pct": sci.get("weh_est_mean_wt_pct"),
        "weh_truth_mean_wt_pct": sci.get("weh_truth_mean_wt_pct"),
        "goals_reached": sum(1 for g in summary["goals"] if g["reached"]),
        "goals": len(summary["goals"]),
        "distance_m": summary["rover"]["distance_m"],
        "simulated_s": summary["simulated_s"],
        "wall_s": round(wall, 1),
        "run_dir": str(Path(args.runs).resolve()),
    }
    print(
        f"{'r':>6} {'area m2':>8} {'records':>8} {'cells':>6} {'rmse wt%':>9} {'bias wt%':>9} "
        f"{'goals':>6} {'driven m':>9}"
    )
    r = doc["nss_truth_r"] if doc["nss_truth_r"] is not None else float("nan")
    print(
        f"{r:>6.3f} {doc['area_m2']:>8.0f} {doc['records']:>8} "
        f"{doc['cells'] or 0:>6} {doc['rmse_wt_pct'] or float('nan'):>9.3f} "
        f"{doc['bias_wt_pct'] if doc['bias_wt_pct'] is not None else float('nan'):>+9.3f} "
        f"{doc['goals_reached']:>3}/{doc['goals']:<2} {doc['distance_m']:>9.1f}"
    )
    if args.out:
        atomic_write_text(args.out, json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
