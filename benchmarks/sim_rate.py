"""Benchmark: real-time factor of the default mission without cameras.

    .venv/bin/python benchmarks/sim_rate.py --out bench_sim_rate.json

Builds the default scenario's mission diagram (site from the cache; built first if
needed, not timed), then times ``--repeats`` runs of ``--sim-s`` simulated seconds of
the rover driving its route, each from a fresh context (wall and CPU seconds of this
process), after an untimed ``--warmup-s`` run (the first frames set the renderer up and
numba loads its kernels: once a process, 80-120 CPU s with cameras on a loaded 2-core
machine; recorded as ``warmup``). Prints a table; writes JSON with ``speed_index_s``
(:mod:`benchmarks.speed_index`, measured in a child after the runs). Goal (issue 3):
>= 5x real time on this 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


def fresh_run(diagram, scenario, t_s: float, *, cpu_clock=time.process_time):
    """Simulates ``diagram`` for ``t_s`` simulated seconds from a fresh context under
    ``scenario``'s simulator config: ``(simulator, wall s, CPU s by cpu_clock)``."""
    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

    sim = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, sim)
    sim.Initialize()
    t0, c0 = time.perf_counter(), cpu_clock()
    sim.AdvanceTo(t_s)
    return sim, time.perf_counter() - t0, cpu_clock() - c0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="default")
    p.add_argument("--sim-s", type=float, default=30.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--warmup-s", type=float, default=2.0,
                   help="simulated seconds of an untimed first run (0: none)")  # fmt: skip
    p.add_argument("--out", default=None)
    p.add_argument("--rtf-key", default="median_rtf", help="JSON key of the median rtf")
    p.add_argument("--goal", type=float, default=5.0, help="the real-time factor aimed at")
    p.add_argument("--scenario-text", default="{sensors: {camera: {enabled: false}}}",
                   help="YAML overrides (default: cameras off)")  # fmt: skip
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out, what="results JSON")

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name=args.scenario, scenario_text=args.scenario_text)
    site = load_site(scenario, progress=False)
    diagram = MakeMissionDiagram(scenario=scenario, site=site)

    def advance(t_s: float):
        return fresh_run(diagram, scenario, t_s)

    warmup = None
    if args.warmup_s > 0:
        _, wall, cpu = advance(args.warmup_s)
        warmup = {"sim_s": args.warmup_s, "wall_s": wall, "cpu_s": cpu}
    runs = []
    for _ in range(args.repeats):
        sim, wall, cpu = advance(args.sim_s)
        ctx = diagram.GetMyContextFromRoot(sim.get_context())
        pose = diagram.GetOutputPort("truth.pose").Eval(ctx)
        run = {"wall_s": wall, "cpu_s": cpu, "rtf": args.sim_s / wall,
               "final_xy_m": [float(pose[0]), float(pose[1])]}  # fmt: skip
        ground = diagram.GetSubsystemByName("ground")
        if ground.HasSubsystemNamed("ground.perception"):
            gp = ground.GetSubsystemByName("ground.perception")
            recs = gp.perception_state(sim.get_context()).records.items()
            rx = ground.GetSubsystemByName("ground.images")
            run["frames_received"] = len(rx.received(rx.GetMyContextFromRoot(sim.get_context())))
            run["keyframes"] = len(recs)
            run["vo_accepted"] = sum(r.vo == "accepted" for r in recs)
        runs.append(run)
    med = statistics.median(r["rtf"] for r in runs)
    speed = measure_speed_index()
    result = {
        "benchmark": "sim_rate",
        "scenario": args.scenario,
        "scenario_text": args.scenario_text,
        "sim_s": args.sim_s,
        "plant_time_step_s": scenario.plant_config.time_step,
        "cpu_count": os.cpu_count(),
        "warmup": warmup,
        "runs": runs,
        args.rtf_key: med,
        "goal_rtf": args.goal,
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    print(f"{'run':>4} {'wall (s)':>9} {'cpu (s)':>8} {'real-time factor':>17}")
    for k, r in enumerate(runs):
        print(f"{k:>4} {r['wall_s']:>9.2f} {r['cpu_s']:>8.2f} {r['rtf']:>16.2f}x")
    print(
        f"median real-time factor: {med:.2f}x (goal >= {args.goal:g}x; {args.sim_s:g} s simulated, "
        f"plant step {scenario.plant_config.time_step * 1e3:g} ms)"
    )
    print(speed_index_line(speed))
    if args.out:
        atomic_write_text(args.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("sim_rate.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.exit(main())
