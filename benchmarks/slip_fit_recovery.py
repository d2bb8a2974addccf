"""Study: does ``slip-fit`` recover a known soil, end to end through the simulator?

    .venv/bin/python benchmarks/slip_fit_recovery.py --out bench_slip_fit.json
    .venv/bin/python benchmarks/slip_fit_recovery.py --plot docs/img/slip_fit.png

1. "Measured" data: the independent steady-state reference
   (:func:`lunar_drake.dynamics.wheel_reference.reference_slip`, quasi-static slope
   loads) with a known soil that differs from the base (lunar regolith with phi = 30 deg,
   K = 2.5 cm), at every slope the rover can climb with slip <= 80 % (step 2 deg),
   ``--repeats`` measurements per slope with ``--noise-pp`` (1 pp) Gaussian noise,
   seeded.
2. ``slip-fit`` (phi and K) on that data.
3. ``slip-study`` with the fitted soil (planar ramps, one seed), the data drawn on its
   plot: simulation, independent reference (fitted soil) and data in one figure.
4. The generating curve: the reference with the *known* soil at the loads the
   simulation measured on each slope; the table compares the simulated slip with it.

Prints a table; writes JSON. Not a timing benchmark (the fit takes ~2 s, the study
~1 min): it measures the issue-12 "Done when" figures.
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from lunar_drake import rng
from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics import wheel_reference as wr
from lunar_drake.files import atomic_write_text, check_output_file
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.studies.slip_fit import ROVER_CHOICES, run_slip_fit
from lunar_drake.studies.slip_study import run_slip_study

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rover", default="explicit", choices=sorted(ROVER_CHOICES))
    p.add_argument("--phi-deg", type=float, default=30.0, help="known soil friction angle")
    p.add_argument("--K-cm", type=float, default=2.5, help="known soil shear modulus")
    p.add_argument("--noise-pp", type=float, default=1.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--distance", type=float, default=3.0, help="metres per simulated climb")
    p.add_argument("--out", default=None, help="write results as JSON here")
    p.add_argument("--plot", default=None, help="copy the study's slip.png here")
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")

    desc = rover_preset(ROVER_CHOICES[a.rover])
    wheel = tm.WheelParams(radius_m=desc.wheel_radius_m, width_m=desc.wheel_width_m)
    truth = dc.replace(
        tm.LUNAR_REGOLITH,
        name="known",
        phi=math.radians(a.phi_deg),
        K=a.K_cm / 100.0,
        K_y=a.K_cm / 100.0,
    )

    def loads(slope_rad):
        return wr.slope_wheel_loads(description=desc, slope_rad=slope_rad)

    slopes = []
    clean = []
    for deg in np.arange(0.0, 30.0, 2.0):
        try:
            s = wr.reference_slip(
                slope_rad=math.radians(deg), wheel_loads_N=loads(math.radians(deg)),
                wheel=wheel, soil=truth,
            )  # fmt: skip
        except tm.ImmobilizedError:
            break
        if s > 0.8:
            break
        slopes.append(float(deg))
        clean.append(s)
    g = rng.generator(a.seed, "benchmarks/slip_fit_recovery")
    data_x = np.repeat(slopes, a.repeats)
    data_y = np.clip(
        np.repeat(clean, a.repeats) + g.normal(0.0, a.noise_pp / 100.0, data_x.size), 0.0, 0.99
    )
    work = Path(tempfile.mkdtemp(prefix="slip_fit_recovery_"))
    try:
        csv = work / "data.csv"
        csv.write_text(
            "slope_deg,slip\n"
            + "".join(f"{x:g},{y:.6f}\n" for x, y in zip(data_x, data_y, strict=True))
        )
        fit = run_slip_fit(data_path=csv, rover=a.rover, out_dir=work / "fit")
        rows = run_slip_study(
            rovers=[a.rover],
            slopes_deg=slopes,
            distance_m=a.distance,
            seeds=1,
            out_dir=work / "study",
            soil=str(work / "fit" / "soil.yaml"),
            data=(data_x, data_y),
            progress=True,
        )
        params = json.loads((work / "study" / "params.json").read_text())
        measured = {
            d["slope_deg"]: d["static_wheel_load_on_slope_N"] for d in params["slope_loads"]
        }
        table = []
        for r in rows:
            gen = wr.reference_slip(
                slope_rad=math.radians(r["slope_deg"]), wheel_loads_N=measured[r["slope_deg"]],
                wheel=wheel, soil=truth,
            )  # fmt: skip
            table.append(
                {
                    "slope_deg": r["slope_deg"],
                    "simulated_slip": r["slip"],
                    "reference_slip_fitted_soil": r["reference_slip"],
                    "generating_slip_known_soil": gen,
                    "sim_minus_generating_pp": 100.0 * (r["slip"] - gen),
                }
            )
        if a.plot:
            Path(a.plot).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(work / "study" / "slip.png", a.plot)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    worst = max(abs(t["sim_minus_generating_pp"]) for t in table)
    print(
        f"known soil: phi {a.phi_deg:.2f} deg, K {a.K_cm:.3f} cm; fitted: phi "
        f"{math.degrees(fit.soil.phi):.2f} deg, K {100 * fit.soil.K:.3f} cm; "
        f"RMS residual {fit.rms_pp:.2f} pp ({data_x.size} points, {len(slopes)} slopes)"
    )
    print(f"{'slope':>6} {'simulated':>10} {'ref(fit)':>9} {'generating':>11} {'sim-gen':>8}")
    for t in table:
        print(
            f"{t['slope_deg']:>6.1f} {100 * t['simulated_slip']:>9.2f}% "
            f"{100 * t['reference_slip_fitted_soil']:>8.2f}% "
            f"{100 * t['generating_slip_known_soil']:>10.2f}% {t['sim_minus_generating_pp']:>7.2f}"
        )
    print(f"worst |simulated - generating|: {worst:.2f} pp")
    if a.out:
        result = {
            "rover": a.rover,
            "known_soil": {"phi_deg": a.phi_deg, "K_cm": a.K_cm},
            "fitted_soil": {
                "phi_deg": math.degrees(fit.soil.phi),
                "K_cm": 100 * fit.soil.K,
            },
            "rms_residual_pp": fit.rms_pp,
            "noise_pp": a.noise_pp,
            "points": int(data_x.size),
            "slopes_deg": slopes,
            "table": table,
            "worst_sim_minus_generating_pp": worst,
        }
        record_speed_index(result)
        atomic_write_text(a.out, json.dumps(result, indent=2), what="results JSON")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
