"""The machine's speed index, measured beside a benchmark's own figures.

``../shared/bench/speed_index.py`` (next to the repository; ``LUNAR_DRAKE_SPEED_INDEX``
names another copy) times a fixed single-threaded CPU workload: ``speed_index_s``,
lower is faster. Machines here differ by up to 3x from day to day, so every benchmark
JSON records it, measured in the same process tree (a child of the benchmark), to make
figures from different days comparable. Without the script the index is None and the
reason is recorded.

The index is measured with glibc's default allocator settings (``GLIBC_TUNABLES``
removed from the child's environment), as on the days before
:mod:`lunar_drake.allocator`; the benchmark's own setting is recorded beside it
(``glibc_tunables``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

DEFAULT_SCRIPT = Path(__file__).resolve().parents[1].parent / "shared" / "bench" / "speed_index.py"


def script_path() -> Path:
    """The speed-index script: ``$LUNAR_DRAKE_SPEED_INDEX`` or ``../shared/bench/``."""
    return Path(os.environ.get("LUNAR_DRAKE_SPEED_INDEX") or DEFAULT_SCRIPT)


def measure_speed_index(*, repeats: int = 3) -> dict:
    """Runs the script in a child process: ``{"speed_index_s": s or None, "parts": {...},
    "script": path, "glibc_tunables": this process's GLIBC_TUNABLES or None}``
    (``"error"`` says why when the index is None)."""
    path = script_path()
    out: dict = {"speed_index_s": None, "parts": {}, "script": str(path),
                 "glibc_tunables": os.environ.get("GLIBC_TUNABLES")}  # fmt: skip
    if not path.is_file():
        out["error"] = f"{path} not found (set LUNAR_DRAKE_SPEED_INDEX)"
        return out
    env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    proc = subprocess.run([sys.executable, str(path), "--repeats", str(int(repeats))],
                          capture_output=True, text=True, check=False, env=env)  # fmt: skip
    try:
        res = json.loads(proc.stdout.strip().splitlines()[-1])
        out["speed_index_s"] = float(res["speed_index_s"])
        out["parts"] = res.get("parts", {})
    except (IndexError, KeyError, TypeError, ValueError):
        out["error"] = f"exit {proc.returncode}: {(proc.stderr or proc.stdout).strip()[-300:]}"
    return out


def speed_index_line(result: dict) -> str:
    """One line for a benchmark's printed table."""
    s = result.get("speed_index_s")
    if s is None:
        return f"speed index: not measured ({result.get('error', 'unknown')})"
    return f"speed index: {s:.3f} s (lower is faster; {result['script']})"


def record_speed_index(result: dict) -> dict:
    """Measures the speed index (after a benchmark's timed work, so it disturbs none of
    it), prints its line and adds ``speed_index_s`` and ``speed_index`` (the whole
    measurement) to ``result``, a benchmark's JSON document; returns ``result``."""
    speed = measure_speed_index()
    print(speed_index_line(speed))
    result["speed_index_s"] = speed["speed_index_s"]
    result["speed_index"] = speed
    return result
