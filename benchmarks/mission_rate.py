"""Benchmark: real-time factor of the default mission (plant, flight, ground, link).

    .venv/bin/python benchmarks/mission_rate.py --out bench_mission_rate.json
    .venv/bin/python benchmarks/mission_rate.py --no-cameras --out bench_mission_rate.json
    .venv/bin/python benchmarks/mission_rate.py --no-cameras --whole --out bench_whole.json

Without flags (issue 14): the default mission with the mast stereo pair at
``--width`` x ``--height`` (1024 x 768) and ``--rate`` (1 Hz), every frame sent down
the image channel, and the ground's stereo, ICP visual odometry, mapping and planner on
what arrives (``ground.perception``). ``--no-cameras``: cameras off (issue 13). Same
measurement as :mod:`benchmarks.sim_rate` (``--repeats`` runs of ``--sim-s`` simulated
seconds from fresh contexts after an untimed warm-up run, the median): JSON ``{rtf,
runs, speed_index_s, ...}``.
``--whole``: one whole mission through :func:`lunar_drake.simulation.simulate` (the
scenario's duration, 700 s for the default; what ``lunar-drake run`` simulates, logging
and the renderer's set-up included, without writing files): ``rtf`` = simulated /
simulating seconds. Goals on this 2-core machine (issue 29): rtf >= 2 with stereo, >= 10
without cameras.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from sim_rate import main as sim_rate_main

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


def whole_mission(*, scenario_name: str, text: str, goal: float, out: str | None) -> int:
    """Times one whole mission (``simulate``); prints a line, writes JSON."""
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name=scenario_name, scenario_text=text)
    site = load_site(scenario, progress=False)
    c0 = time.process_time()
    logs = simulate(scenario=scenario, site=site)
    cpu = time.process_time() - c0
    pose = logs.vectors["truth.pose"].data[-1]
    rtf = logs.wall["realtime_factor"]
    speed = measure_speed_index()
    result = {
        "benchmark": "mission_rate_whole",
        "scenario": scenario_name,
        "scenario_text": text,
        "simulated_s": logs.simulated_s,
        "stop_reason": logs.stop_reason,
        "build_s": logs.wall["build_s"],
        "simulate_s": logs.wall["simulate_s"],
        "cpu_s": cpu,
        "rtf": rtf,
        "goal_rtf": goal,
        "final_xy_m": [float(pose[0]), float(pose[1])],
        "goals": [st for _, st in logs.ground_goals],
        "keyframes": len(logs.keyframes),
        "cpu_count": os.cpu_count(),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    print(f"whole mission: {logs.simulated_s:g} s simulated in {logs.wall['simulate_s']:.1f} s "
          f"(cpu {cpu:.1f} s): real-time factor {rtf:.2f}x (goal >= {goal:g}x); "
          f"{logs.stop_reason}; goals {result['goals']}")  # fmt: skip
    print(speed_index_line(speed))
    if out:
        atomic_write_text(out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--no-cameras", action="store_true", help="cameras off")
    p.add_argument("--whole", action="store_true",
                   help="one whole mission (simulate(), the scenario's duration)")  # fmt: skip
    p.add_argument("--scenario", default="default")
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--height", type=int, default=768)
    p.add_argument("--rate", type=float, default=1.0, help="stereo frames per second")
    p.add_argument("--sim-s", type=float, default=None,
                   help="simulated seconds per run (30 without cameras, 60 with)")  # fmt: skip
    p.add_argument("--repeats", type=int, default=None, help="runs (3 without cameras, 2 with)")
    p.add_argument("--warmup-s", type=float, default=2.0,
                   help="simulated seconds of an untimed first run (0: none)")  # fmt: skip
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")
    goal = 10.0 if a.no_cameras else 2.0
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
    if a.whole:
        return whole_mission(scenario_name=a.scenario, text=text, goal=goal, out=a.out)
    args = ["--scenario", a.scenario, "--sim-s", str(sim_s), "--repeats", str(repeats),
            "--scenario-text", text, "--goal", str(goal),
            "--warmup-s", str(a.warmup_s)]  # fmt: skip
    if a.out:
        args += ["--out", a.out, "--rtf-key", "rtf"]
    return sim_rate_main(args)


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("mission_rate.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.exit(main())
