"""Benchmark: per-step cost of the terramechanics core for one rover (4-6 wheels).

    .venv/bin/python benchmarks/terramechanics.py --out bench_terramechanics.json
    .venv/bin/python benchmarks/terramechanics.py --wheels 6 --calls 5000

Times single calls (median and 90th percentile over --calls calls, after a warm-up) of
``wheel_forces`` (forward model, and with the travel-direction blend), ``normal_force``
and, for comparison, one independent ``wheel_reference.reference_slip`` solve (adaptive
quadrature and root finding). Prints a table; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time

import numpy as np

from lunar_drake.dynamics.terramechanics import (
    LUNAR_REGOLITH,
    WheelParams,
    equilibrium_sinkage,
    normal_force,
    wheel_forces,
)
from lunar_drake.dynamics.wheel_reference import reference_slip
from lunar_drake.files import atomic_write_text, check_output_file
from lunar_drake.moon import GRAVITY_MPS2

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def _time(fn, calls: int) -> dict:
    for _ in range(min(calls, 200)):
        fn()
    t = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        t[i] = time.perf_counter() - t0
    return {
        "median_us": float(np.median(t) * 1e6),
        "p90_us": float(np.percentile(t, 90) * 1e6),
        "calls": calls,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--wheels", type=int, default=4)
    p.add_argument("--calls", type=int, default=1000)
    p.add_argument("--out", default=None, help="write results as JSON here")
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")

    wheel = WheelParams(radius_m=0.25, width_m=0.2)
    soil = LUNAR_REGOLITH
    n = a.wheels
    rng = np.random.default_rng(0)
    W = np.full(n, 50.0 * GRAVITY_MPS2)
    z = equilibrium_sinkage(W, wheel=wheel, soil=soil) * rng.uniform(0.8, 1.2, n)
    z_dot = rng.normal(0.0, 0.01, n)
    slip = rng.uniform(0.0, 0.4, n)
    beta = rng.normal(0.0, 0.05, n)
    direction = np.ones(n)

    rows = {
        "wheel_forces": _time(
            lambda: wheel_forces(slip=slip, slip_angle=beta, z=z, wheel=wheel, soil=soil),
            a.calls,
        ),
        "wheel_forces(direction=)": _time(
            lambda: wheel_forces(
                slip=slip, slip_angle=beta, z=z, wheel=wheel, soil=soil, direction=direction
            ),
            a.calls,
        ),
        "normal_force": _time(
            lambda: normal_force(z, z_dot, vertical=W, wheel=wheel, soil=soil), a.calls
        ),
        "reference_slip(10 deg)": _time(
            lambda: reference_slip(
                slope_rad=math.radians(10.0), wheel_loads_N=W, wheel=wheel, soil=soil
            ),
            max(a.calls // 20, 10),
        ),
    }
    print(f"{'function':<28} {'wheels':>6} {'median us':>10} {'p90 us':>10}")
    for name, r in rows.items():
        print(f"{name:<28} {n:>6} {r['median_us']:>10.1f} {r['p90_us']:>10.1f}")
    if a.out:
        result = {
            "wheels": n,
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "machine": platform.machine(),
            "processor": platform.processor(),
            "results": rows,
        }
        record_speed_index(result)
        atomic_write_text(a.out, json.dumps(result, indent=2), what="results JSON")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
