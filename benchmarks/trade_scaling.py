"""Benchmark: the trade-study runner's scaling and determinism (issue 30).

    .venv/bin/python benchmarks/trade_scaling.py --out bench_trade_scaling.json

Runs a study's quick form (default: the shipped ``comms`` study, 16 cases x 1
replicate) three times through ``lunar-drake trade``'s engine:

1. with 1 local worker, then with 2 (each from a fresh LocalCluster; wall times of the
   whole study, cluster start and report included): ``speedup`` = t1 / t2;
2. with 2 workers in a child process killed (SIGKILL to its process group: the
   scheduler, the workers and all) once about half the rows are journalled, then
   ``--resume`` d.

``results.csv`` must be the same bytes all three times (``identical_1_2``,
``identical_resume``). Goal on this 2-core machine: speedup >= 1.8. JSON + a table;
the machine's speed index beside the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


def _timed(study, out: Path, workers: int) -> float:
    from lunar_drake.trade.engine import run_study

    t0 = time.perf_counter()
    run_study(study=study, out=out, workers=workers, quick=True, progress=False,
              echo=lambda *_: None)  # fmt: skip
    return time.perf_counter() - t0


def _kill_and_resume(study_arg: str, study, out: Path, *, total: int) -> dict:
    from lunar_drake.trade.engine import run_study

    cmd = [sys.executable, "-m", "lunar_drake.cli", "trade", study_arg, "--quick",
           "--workers", "2", "--no-progress", "--out", str(out)]  # fmt: skip
    child = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)  # fmt: skip
    half = total // 2
    rows = 0
    while child.poll() is None:
        rows = len(list((out / "cases").glob("*/row.json"))) if (out / "cases").is_dir() else 0
        if rows >= half:
            os.killpg(child.pid, signal.SIGKILL)
            break
        time.sleep(0.2)
    child.wait()
    time.sleep(2.0)  # let orphaned workers notice
    kept = len(list((out / "cases").glob("*/row.json")))
    run = run_study(study=study, out=out, workers=2, quick=True, resume=True, progress=False,
                    echo=lambda *_: None)  # fmt: skip
    return {"killed_with_rows": kept, "resumed_runs": run.ran, "killed": rows >= half}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--study", default="comms", help="a shipped study's name or a STUDY.yaml")
    p.add_argument("--out", default=None, help="JSON results")
    p.add_argument("--keep", default=None, help="keep the three study directories here")
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")
    from lunar_drake.trade.study import expand_jobs, load_study

    study = load_study(a.study)
    total = len(expand_jobs(study, quick=True))
    with tempfile.TemporaryDirectory(prefix="trade_scaling_") as tmp:
        root = Path(a.keep) if a.keep else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        t1 = _timed(study, root / "w1", 1)
        t2 = _timed(study, root / "w2", 2)
        resume = _kill_and_resume(a.study, study, root / "killed", total=total)
        ref = (root / "w1" / "results.csv").read_bytes()
        same_12 = ref == (root / "w2" / "results.csv").read_bytes()
        same_resume = ref == (root / "killed" / "results.csv").read_bytes()
        failed = sum(",error," in ln for ln in ref.decode().splitlines()[1:])
    speed = measure_speed_index()
    result = {
        "benchmark": "trade_scaling",
        "study": study.name,
        "runs": total,
        "failed_runs": failed,
        "workers_1_s": round(t1, 2),
        "workers_2_s": round(t2, 2),
        "speedup": round(t1 / t2, 3),
        "goal_speedup": 1.8,
        "identical_1_2": same_12,
        "identical_resume": same_resume,
        **resume,
        "cpu_count": os.cpu_count(),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    print(f"{'study':<10} {'runs':>5} {'1 worker s':>11} {'2 workers s':>12} {'speedup':>8} "
          f"{'same 1/2':>9} {'same resume':>12}")  # fmt: skip
    print(f"{study.name:<10} {total:>5} {t1:>11.1f} {t2:>12.1f} {t1 / t2:>8.2f} "
          f"{same_12!s:>9} {same_resume!s:>12}")  # fmt: skip
    print(f"killed with {resume['killed_with_rows']} of {total} rows journalled; the resume ran "
          f"{resume['resumed_runs']}; failed runs {failed}")  # fmt: skip
    print(speed_index_line(speed))
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0 if same_12 and same_resume else 1


if __name__ == "__main__":
    sys.exit(main())
