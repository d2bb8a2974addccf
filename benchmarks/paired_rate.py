"""Benchmark: two source trees' no-camera missions side by side, one on each core.

    .venv/bin/python benchmarks/paired_rate.py --a ../before --b . --out bench_paired.json
    .venv/bin/python benchmarks/paired_rate.py --a ../before --b . --rounds 2 --sim-s 20

A before/after of a speed change on a shared machine. Run one after the other, the
same code's real-time factor moves by up to 15 % within minutes here (other tenants),
more than most changes it is asked to judge. So each *pair* runs tree A and tree B at
the same time, each pinned to one core (``os.sched_setaffinity``), and the next pair
swaps the cores; whatever load the machine carries then falls on both sides alike.

Each side is a child process started in its tree (``cwd``, and the tree first on
``PYTHONPATH``, so it imports that tree's ``lunar_drake``): it builds the scenario's mission
diagram, runs ``--warmup-s`` untimed, then ``--runs`` runs of ``--sim-s`` simulated
seconds from fresh contexts, and reports each run's CPU seconds of the simulating thread
(``time.thread_time``) and wall seconds, and where the rover ended. A pair's figure is
the ratio of the two sides' median thread CPU times, B / A (< 1: B is faster). The
summary is the median over pairs, the pairs in which B was faster, and the real-time
factors of each side (simulated / median wall seconds). The rovers' end points are
compared too: equal to the bit when the change is meant not to change results.

Both trees need ``lunar_drake.diagrams.mission.MakeMissionDiagram``,
``lunar_drake.scenario_files.load_scenario``, ``lunar_drake.site.load_site`` and
``lunar_drake.files`` (imported by ``benchmarks/sim_rate.py``, whose
:func:`~sim_rate.fresh_run` times the runs). A side
fails, named, when any ``lunar_drake`` module it loaded comes from outside its tree (an
editable install of another checkout would otherwise fill in what the tree lacks). The
children inherit this process's allocator setting (:mod:`lunar_drake.allocator`) and
the site cache (one site for both, built by whichever tree built it first); the speed
index is measured once, before the pairs. Only the simulating thread is pinned and timed
(a change that moves work to other threads would look faster than it is). On a machine
with one core the sides share it (recorded as ``cores``).

JSON ``{pairs: [{a_core, b_core, a: {...}, b: {...}, ratio_cpu}], median_ratio_cpu,
b_faster_pairs, a_rtf, b_rtf, a_rev, b_rev, same_end, speed_index_s, ...}``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from sim_rate import fresh_run  # benchmarks/ is on sys.path: this file runs as a script

NO_CAMERAS = "{sensors: {camera: {enabled: false}}}"


def child(*, scenario_name: str, text: str, sim_s: float, runs: int, warmup_s: float,
          core: int | None) -> dict:  # fmt: skip
    """One side of a pair, in the tree under test (its ``lunar_drake`` imported here)."""
    if core is not None:
        os.sched_setaffinity(0, {core})
    tree = Path.cwd().resolve()
    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    _check_own_modules(tree)
    scenario = load_scenario(scenario_name=scenario_name, scenario_text=text)
    site = load_site(scenario, progress=False)
    diagram = MakeMissionDiagram(scenario=scenario, site=site)

    def advance(t_s: float):
        return fresh_run(diagram, scenario, t_s, cpu_clock=time.thread_time)

    if warmup_s > 0:
        advance(warmup_s)
    out = []
    for _ in range(runs):
        sim, wall, cpu = advance(sim_s)
        ctx = diagram.GetMyContextFromRoot(sim.get_context())
        pose = diagram.GetOutputPort("truth.pose").Eval(ctx)
        out.append({"wall_s": wall, "cpu_s": cpu, "end_xyz_m": [float(v) for v in pose[:3]]})
    _check_own_modules(tree)  # and those the run imported on the way
    return {"runs": out, "cpu_med_s": statistics.median(r["cpu_s"] for r in out),
            "wall_med_s": statistics.median(r["wall_s"] for r in out)}  # fmt: skip


def _check_own_modules(tree: Path) -> None:
    """Raises when a loaded ``lunar_drake`` module comes from outside ``tree``: a module
    the tree lacks may be found elsewhere (an editable install of another checkout), and
    the side would not be the tree it claims to be."""
    foreign = sorted(
        name for name, m in sys.modules.items()
        if (name == "lunar_drake" or name.startswith("lunar_drake."))
        and getattr(m, "__file__", None)
        and not Path(m.__file__).resolve().is_relative_to(tree)
    )  # fmt: skip
    if foreign:
        raise RuntimeError(
            f"{len(foreign)} lunar_drake module(s) loaded from outside {tree}, e.g. "
            f"{', '.join(foreign[:3])}: the tree lacks them"
        )


def _revision(tree: Path) -> str:
    """``git describe``-like: the commit and ``+dirty`` when the tree has changes."""

    def git(*a):
        cmd = ["git", "-C", str(tree), *a]
        p = subprocess.run(cmd, capture_output=True, text=True, check=False)
        return p.stdout.strip() if p.returncode == 0 else ""

    rev = git("rev-parse", "--short", "HEAD") or "not a git tree"
    return rev + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "")


def _launch(tree: Path, args, core: int | None, out_path: Path) -> subprocess.Popen:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child",
           "--scenario", args.scenario, "--scenario-text", args.scenario_text,
           "--sim-s", str(args.sim_s), "--runs", str(args.runs),
           "--warmup-s", str(args.warmup_s), "--child-out", str(out_path)]  # fmt: skip
    if core is not None:
        cmd += ["--core", str(core)]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(tree), env.get("PYTHONPATH")) if p)
    return subprocess.Popen(cmd, cwd=str(tree), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--a", help="tree A (before): a checkout of lunar_drake")
    p.add_argument("--b", help="tree B (after)")
    p.add_argument("--rounds", type=int, default=3, help="rounds of two pairs (cores swapped)")
    p.add_argument("--runs", type=int, default=3, help="timed runs per side and pair")
    p.add_argument("--sim-s", type=float, default=30.0, help="simulated seconds per run")
    p.add_argument("--warmup-s", type=float, default=2.0, help="untimed first run (s)")
    p.add_argument("--scenario", default="default")
    p.add_argument("--scenario-text", default=NO_CAMERAS, help="YAML overrides (cameras off)")
    p.add_argument("--out", default=None, help="write results JSON here")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--core", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--child-out", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    for name, lo in (("--rounds", 1), ("--runs", 1)):
        if getattr(args, name[2:]) < lo:
            p.error(f"{name} = {getattr(args, name[2:])}; at least {lo}")
    if not (args.sim_s > 0 and args.warmup_s >= 0):
        p.error(f"--sim-s = {args.sim_s}, --warmup-s = {args.warmup_s}; need > 0 and >= 0")
    if args.child:
        res = child(scenario_name=args.scenario, text=args.scenario_text, sim_s=args.sim_s,
                    runs=args.runs, warmup_s=args.warmup_s, core=args.core)  # fmt: skip
        Path(args.child_out).write_text(json.dumps(res))
        return 0
    if not args.a or not args.b:
        p.error("--a and --b (two source trees) are required")
    trees = {}
    for side in ("a", "b"):
        tree = Path(getattr(args, side)).resolve()
        if not (tree / "lunar_drake" / "__init__.py").is_file():
            p.error(f"--{side} = {getattr(args, side)!r} is not a lunar_drake source tree "
                    f"(no lunar_drake/__init__.py there)")  # fmt: skip
        trees[side] = tree
    # the parent's own imports (the children import only their trees' lunar_drake)
    from lunar_drake.files import atomic_write_text, check_output_file

    try:
        from benchmarks.speed_index import measure_speed_index, speed_index_line
    except ImportError:  # run as a script: benchmarks/ itself is on sys.path
        from speed_index import measure_speed_index, speed_index_line

    if args.out:
        check_output_file(args.out, what="results JSON")

    cores = sorted(os.sched_getaffinity(0))
    speed = measure_speed_index()
    pairs = []
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    stamp = f"{os.getpid()}_{time.time_ns()}"
    print(f"A {trees['a']} ({_revision(trees['a'])}), B {trees['b']} ({_revision(trees['b'])}); "
          f"{args.rounds * 2} pairs of {args.runs} x {args.sim_s:g} s")  # fmt: skip
    print(f"{'pair':>4} {'A core':>6} {'B core':>6} {'A cpu (s)':>9} {'B cpu (s)':>9} {'B/A':>6}")
    for k in range(2 * args.rounds):
        if len(cores) >= 2:
            ca, cb = (cores[0], cores[1]) if k % 2 == 0 else (cores[1], cores[0])
        else:
            ca = cb = None
        outs = {s: tmp / f"paired_rate_{stamp}_{k}_{s}.json" for s in ("a", "b")}
        procs = {}
        res = {}
        failed = None
        try:
            procs = {"a": _launch(trees["a"], args, ca, outs["a"]),
                     "b": _launch(trees["b"], args, cb, outs["b"])}  # fmt: skip
            for s, proc in procs.items():
                _, err = proc.communicate()
                if proc.returncode != 0 and failed is None:
                    last = (err or "").strip().splitlines()[-1:] or ["(no output)"]
                    failed = (f"side {s.upper()} ({trees[s]}) exited {proc.returncode}: "
                              f"{last[0]}")  # fmt: skip
                    break
                res[s] = json.loads(outs[s].read_text())
        finally:  # a side still running (the other failed, or Ctrl-C) stops with us
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            for f in outs.values():
                f.unlink(missing_ok=True)
        if failed:
            print(f"paired_rate.py: error: {failed}", file=sys.stderr)
            return 2
        ratio = res["b"]["cpu_med_s"] / res["a"]["cpu_med_s"]
        pairs.append({"a_core": ca, "b_core": cb, "a": res["a"], "b": res["b"], "ratio_cpu": ratio})
        print(f"{k + 1:>4} {ca!s:>6} {cb!s:>6} {res['a']['cpu_med_s']:>9.3f} "
              f"{res['b']['cpu_med_s']:>9.3f} {ratio:>6.3f}", flush=True)  # fmt: skip

    ratios = [q["ratio_cpu"] for q in pairs]
    med = statistics.median(ratios)
    faster = sum(r < 1.0 for r in ratios)
    rtf = {s: args.sim_s / statistics.median(q[s]["wall_med_s"] for q in pairs) for s in ("a", "b")}
    ends = {s: {tuple(r["end_xyz_m"]) for q in pairs for r in q[s]["runs"]} for s in ("a", "b")}
    same_end = len(ends["a"]) == 1 and ends["a"] == ends["b"]
    ends_said = (
        "equal to the bit" if same_end
        else "A's runs disagree among themselves" if len(ends["a"]) > 1
        else "B's runs disagree among themselves" if len(ends["b"]) > 1
        else "A and B end at different points"
    )  # fmt: skip
    result = {
        "benchmark": "paired_rate",
        "a": str(trees["a"]), "b": str(trees["b"]),
        "a_rev": _revision(trees["a"]), "b_rev": _revision(trees["b"]),
        "scenario": args.scenario, "scenario_text": args.scenario_text,
        "sim_s": args.sim_s, "runs": args.runs, "cores": cores,
        "pairs": pairs,
        "median_ratio_cpu": med,
        "b_faster_pairs": faster,
        "a_rtf": rtf["a"], "b_rtf": rtf["b"],
        "same_end": same_end,
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }  # fmt: skip
    print(f"B / A thread CPU, median of {len(pairs)} pairs: {med:.3f} ({(med - 1) * 100:+.1f} %); "
          f"B faster in {faster} of {len(pairs)}")  # fmt: skip
    print(f"real-time factor side by side: A {rtf['a']:.2f}x, B {rtf['b']:.2f}x; end points "
          + ends_said)  # fmt: skip
    print(speed_index_line(speed))
    if args.out:
        atomic_write_text(args.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    if "--child" in sys.argv[1:]:  # it inherits the parent's allocator setting; its tree
        sys.exit(main())  # may predate lunar_drake.allocator and benchmarks.run_main
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("paired_rate.py")  # as lunar-drake runs (lunar_drake/allocator.py)
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from benchmarks import run_main

    run_main(main, "paired_rate.py")  # bad input: one line, exit 2
