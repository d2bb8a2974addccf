"""Study: driving to seeded goals through the link, scored on truth.

    .venv/bin/python benchmarks/autonomy.py --map truth --goals 10 --workers 2 \\
        --runs runs/autonomy_truth --out bench_autonomy_truth.json
    .venv/bin/python benchmarks/autonomy.py --map orbital --goals 10 --workers 2 \\
        --runs runs/autonomy_orbital --out bench_autonomy_orbital.json

N goals are drawn (seeded) 30-60 m from the scenario's spawn point, each free and
reachable on the *true* costmap (the site DEM with rocks). Each goal is its own mission
(the scenario with ``ground.goals: [goal]``, the ground's map ``--map``; with
``--stereo`` -- the default with ``--map orbital``, which lost the rocks -- the cameras
on, frames sent down and the ground's stereo perception mapping hazards into its costmap
and replanning; with ``--no-stereo`` -- the default with ``--map truth`` -- cameras off;
time for three times the straight-line distance at the drive speed plus two minutes,
ending 20 s after the ground has judged the goal reached or failed),
written as a run directory under ``--runs``. JSON: ``goals, reached, hazard_strikes,
mean_drift_pct, mean_position_nees, rtt_s, map, slip_calibration`` (the flight's
pre-flight calibrations; ``calibration_is_plant_soil`` true if any was the plant's soil,
an oracle) and ``runs`` (``goal_xy, reached, strikes, final_error_m, distance_m,
drift_pct, position_nees, slip_calibration, run_dir``; a goal the
ground could not plan to on its map is ``reached: false`` with ``error``).
``position_nees``: the on-board EKF's horizontal position NEES over the run, its mean
(2 for a consistent filter; ``metrics.position_nees``), scored on truth;
``speed_index_s`` (``benchmarks/speed_index.py``) dates the machine. Prints a table.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from pathlib import Path

import numpy as np

from lunar_drake import rng
from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


def sample_goals(*, scenario, site, n: int, seed: int, r_min=30.0, r_max=60.0) -> list:
    """``n`` goals (x, y) r_min..r_max m from the spawn, free and reachable on the true
    costmap."""
    from lunar_drake.autonomy.costmap import MapConfig, RoverEnvelope, costmap_for_site
    from lunar_drake.autonomy.planner import PlanningError, plan_path

    start = np.array([scenario.rover.spawn_x_m, scenario.rover.spawn_y_m])
    cm = costmap_for_site(
        heightfield=site.heightfield,
        points_xy=[start - r_max, start + r_max],
        rover=RoverEnvelope.of(scenario.rover.description),
        hazards=scenario.ground.hazards,
        map_config=MapConfig(source="truth", margin_m=5.0),
        seed=scenario.random_seed,
    )
    g = rng.generator(seed, "benchmarks/autonomy/goals")
    goals = []
    for _ in range(200 * n):
        if len(goals) == n:
            break
        r = g.uniform(r_min, r_max)
        a = g.uniform(-math.pi, math.pi)
        goal = start + r * np.array([math.cos(a), math.sin(a)])
        try:
            plan_path(costmap=cm, start_xy=start, goal_xy=goal)
        except (PlanningError, LookupError, ValueError):
            continue
        goals.append((round(float(goal[0]), 2), round(float(goal[1]), 2)))
    if len(goals) < n:
        raise SystemExit(f"only {len(goals)} reachable goals found on this site")
    return goals


def run_goal(scenario_name: str, goal, map_source: str, run_dir: str, text: str = "{}",
             stereo: bool = False) -> dict:  # fmt: skip
    """One mission to ``goal``; its run directory and scored row."""
    from lunar_drake import metrics, outputs
    from lunar_drake.errors import LunarDrakeError
    from lunar_drake.scenario import Goal
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    s = load_scenario(scenario_name=scenario_name, scenario_text=text)
    s = copy.deepcopy(s)
    s.sensors.camera.enabled = stereo
    s.flight.images.enabled = stereo
    s.ground.perception.enabled = stereo
    s.ground.goals = [Goal(x_m=goal[0], y_m=goal[1])]
    s.ground.map.source = map_source
    dist = math.hypot(goal[0] - s.rover.spawn_x_m, goal[1] - s.rover.spawn_y_m)
    s.simulation_duration = round(3.0 * dist / s.ground.drive_speed_mps + 120.0, 1)
    s.name = f"{scenario_name} goal ({goal[0]:.1f}, {goal[1]:.1f}) on the {map_source} map"
    site = load_site(s, progress=False)
    row = {"goal_xy": list(goal), "run_dir": run_dir}
    try:
        # ends 20 s after the ground judged its goal (the rover is braked by then)
        logs = simulate(scenario=s, site=site, progress=False, stop_after_goals_s=20.0)
    except LunarDrakeError as exc:  # the ground could not plan to it on its map
        return {**row, "reached": False, "strikes": 0, "error": f"{type(exc).__name__}: {exc}"}
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    outputs.write_run(Path(run_dir), scenario=s, logs=logs, summary=summary, timing=logs.wall)
    (g,) = summary["goals"]
    loc = summary["localization"]
    moved = summary["rover"]["distance_m"]
    cal = summary["flight"]["slip_calibration"]
    up = [r for r in logs.link if r.direction == "uplink" and math.isfinite(r.t_received)]
    down = [r for r in logs.link if r.direction == "downlink" and math.isfinite(r.t_received)]
    rtt = (np.mean([r.t_received - r.t_sent for r in up]) if up else math.nan) + (
        np.mean([r.t_received - r.t_sent for r in down]) if down else math.nan
    )
    return {
        **row,
        "reached": g["reached"],
        "strikes": summary["hazards"]["strikes"],
        "final_error_m": g["final_distance_m"],
        "distance_m": moved,
        "drift_pct": 100.0 * loc["final_position_error_m"] / moved if moved > 0 else None,
        "position_nees": (loc.get("position_nees") or {}).get("mean"),
        "safings": sum(summary["modes"]["safings"].values()),
        "replans": summary["ground"]["replans"],
        "rtt_s": float(rtt),
        # the flight's pre-flight slip calibration (soil, and whether it is the plant's)
        "slip_calibration": cal.get("slip_calibration"),
        "calibration_is_plant_soil": cal.get("is_plant_soil"),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="default")
    p.add_argument("--scenario-text", default="{}", help="YAML overrides of the scenario")
    p.add_argument("--map", choices=["truth", "orbital"], default="truth")
    p.add_argument("--goals", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--stereo", action=argparse.BooleanOptionalAction, default=None,
                   help="cameras on: stereo hazards from the downlinked frames (default: "
                        "on with --map orbital, off with --map truth)")  # fmt: skip
    p.add_argument("--runs", required=True, help="directory for the run directories")
    p.add_argument("--out", default=None, help="write results as JSON here")
    a = p.parse_args(argv)
    if a.stereo is None:
        a.stereo = a.map == "orbital"
    if a.out:
        check_output_file(a.out, what="results JSON")

    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name=a.scenario)
    site = load_site(scenario, progress=True)
    goals = sample_goals(scenario=scenario, site=site, n=a.goals, seed=a.seed)
    runs = Path(a.runs)
    runs.mkdir(parents=True, exist_ok=True)
    jobs = [
        (a.scenario, gl, a.map, str(runs / f"goal_{k:02d}"), a.scenario_text, a.stereo)
        for k, gl in enumerate(goals)
    ]
    if a.workers > 1:
        import dask

        rows = list(
            dask.compute(
                *[dask.delayed(run_goal)(*j) for j in jobs],
                scheduler="processes",
                num_workers=a.workers,
            )
        )
    else:
        from tqdm.auto import tqdm

        rows = [run_goal(*j) for j in tqdm(jobs, desc="goals", unit="run")]
    drifts = [r["drift_pct"] for r in rows if r.get("drift_pct") is not None]
    nees = [r["position_nees"] for r in rows if r.get("position_nees") is not None]
    rtts = [r["rtt_s"] for r in rows if "rtt_s" in r and math.isfinite(r["rtt_s"])]
    result = {
        "goals": len(rows),
        "reached": sum(bool(r["reached"]) for r in rows),
        "hazard_strikes": sum(r["strikes"] for r in rows),
        "mean_drift_pct": float(np.mean(drifts)) if drifts else None,
        "mean_position_nees": float(np.mean(nees)) if nees else None,
        "rtt_s": float(np.mean(rtts)) if rtts else None,
        "safings": sum(r.get("safings", 0) for r in rows),
        "map": a.map,
        "stereo": a.stereo,
        "slip_calibration": sorted({str(r["slip_calibration"]) for r in rows
                                    if "slip_calibration" in r}),
        "calibration_is_plant_soil": any(r.get("calibration_is_plant_soil") for r in rows),
        "scenario": a.scenario,
        "scenario_text": a.scenario_text,
        "runs": rows,
    }
    speed = measure_speed_index()
    result["speed_index_s"] = speed["speed_index_s"]
    result["speed_index"] = speed
    print(
        f"{'goal':>16} {'reached':>8} {'strikes':>8} {'final m':>8} {'driven m':>9} {'drift %':>8}"
        f" {'safed':>6} {'replans':>8} {'NEES xy':>8}"
    )
    for r in rows:
        fe = r.get("final_error_m")
        print(
            f"({r['goal_xy'][0]:6.1f},{r['goal_xy'][1]:6.1f}) {r['reached']!s:>8} "
            f"{r['strikes']:>8} {'-' if fe is None else f'{fe:.2f}':>8} "
            f"{r.get('distance_m', float('nan')):>9.1f} "
            f"{r.get('drift_pct') or float('nan'):>8.2f} "
            f"{r.get('safings', 0):>6} {r.get('replans', 0):>8} "
            f"{r.get('position_nees') or float('nan'):>8.2f}"
            + (f"  {r['error']}" if "error" in r else "")
        )
    print(
        f"{result['reached']}/{result['goals']} goals reached, {result['hazard_strikes']} hazard "
        f"strikes, {result['safings']} safings, mean drift {result['mean_drift_pct']}, "
        f"mean position NEES {result['mean_position_nees']} (2: consistent), "
        f"rtt {result['rtt_s']} s ({a.map} map)"
    )
    oracle = result["calibration_is_plant_soil"]
    print(f"slip calibration {', '.join(result['slip_calibration']) or '-'} "
          f"({'the plant soil: an oracle' if oracle else 'not the plant soil'})")  # fmt: skip
    print(speed_index_line(speed))
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("autonomy.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import run_main

    run_main(main, "autonomy.py")
