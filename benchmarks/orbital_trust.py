"""Study: how far an orbital map's slope can be trusted, scored on truth.

    .venv/bin/python benchmarks/orbital_trust.py --out bench_orbital_trust.json

The ground's orbital costmap (``ground.map``: the site DEM averaged to
``orbital_resolution_m`` plus its noise; slope, step and roughness at that pixel) is set
beside the *true* costmap (the site DEM with its rocks, at ``ground.hazards.resolution_m``)
over the whole site. For each bin of orbital slope (cells the orbital map calls free), the
fraction of the cell's area that truth calls lethal (before inflation) and the fraction of
cells holding any true hazard. Where more than half an orbital cell is lethal in truth, the
orbital map's "free" is more likely wrong than right: that is where
``ground.map.confirm_slope_deg`` (lethal until stereo has seen it) belongs. JSON: ``bins``
(``lo_deg, hi_deg, cells, lethal_fraction, any_lethal_fraction``), ``crossing_deg`` (the
slope where ``lethal_fraction`` crosses 0.5, interpolated between bin centres),
``hazard_fraction`` / ``unconfirmed_fraction`` (of the orbital cells: hazards, and the
steep cells the rule adds), ``blocked_fraction`` / ``blocked_trusting_fraction`` (of the
cells of the grid the ground plans on, ``ground.hazards.resolution_m``: lethal after
inflation by the rover's footprint, with the rule and without),
``scenario``. Prints a table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def trust_table(*, orbital, truth, bin_deg: float = 2.0) -> list[dict]:
    """Rows per orbital-slope bin: how much of each free orbital cell truth calls lethal.
    ``truth``'s grid must divide ``orbital``'s by a whole factor, edges aligned."""
    k = round(orbital.resolution_m / truth.resolution_m)
    if k < 1 or abs(k * truth.resolution_m - orbital.resolution_m) > 1e-9:
        raise SystemExit("the truth grid must divide the orbital one")
    if abs(orbital.x0_m - truth.x0_m) > 1e-9 or abs(orbital.y1_m - truth.y1_m) > 1e-9:
        raise SystemExit("the grids' edges differ")
    rows, cols = orbital.shape
    rows, cols = min(rows, truth.shape[0] // k), min(cols, truth.shape[1] // k)
    lethal = np.asarray(truth.lethal_raw, np.float64)[: rows * k, : cols * k]
    frac = lethal.reshape(rows, k, cols, k).mean(axis=(1, 3))
    slope = np.asarray(orbital.slope_deg)[:rows, :cols]
    free = ~np.asarray(orbital.lethal_raw, bool)[:rows, :cols]
    if orbital.unconfirmed is not None:
        free |= np.asarray(orbital.unconfirmed, bool)[:rows, :cols]  # free before the rule
    out = []
    top = float(np.ceil(slope[free].max() / bin_deg) * bin_deg) if free.any() else bin_deg
    for lo in np.arange(0.0, top, bin_deg):
        m = free & (slope >= lo) & (slope < lo + bin_deg)
        n = int(m.sum())
        out.append({
            "lo_deg": float(lo), "hi_deg": float(lo + bin_deg), "cells": n,
            "lethal_fraction": float(frac[m].mean()) if n else None,
            "any_lethal_fraction": float((frac[m] > 0).mean()) if n else None,
        })  # fmt: skip
    return out


def crossing_deg(bins, level: float = 0.5) -> float | None:
    """The slope (deg) where ``lethal_fraction`` first reaches ``level``, linear between
    bin centres; None if it never does."""
    pts = [(0.5 * (b["lo_deg"] + b["hi_deg"]), b["lethal_fraction"]) for b in bins
           if b["lethal_fraction"] is not None and b["cells"] >= 20]  # fmt: skip
    for (x0, f0), (x1, f1) in itertools.pairwise(pts):
        if f0 < level <= f1:
            return float(x0 + (level - f0) / (f1 - f0) * (x1 - x0))
    return None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="default")
    p.add_argument("--bin-deg", type=float, default=2.0)
    p.add_argument("--out", default=None, help="write results as JSON here")
    a = p.parse_args(argv)
    if not 0.0 < a.bin_deg <= 90.0:  # NaN fails too
        p.error(f"--bin-deg = {a.bin_deg!r} deg; allowed (0, 90]")
    if a.out:
        check_output_file(a.out, what="results JSON")
    import dataclasses as dc

    from lunar_drake.autonomy.costmap import MapConfig, RoverEnvelope, costmap_for_site
    from lunar_drake.perception.elevation_map import refined_costmap
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    s = load_scenario(scenario_name=a.scenario)
    site = load_site(s, progress=True)
    b = site.heightfield.bounds
    corners = [(b.left, b.bottom), (b.right, b.top)]
    rover = RoverEnvelope.of(s.rover.description)
    kw = {"heightfield": site.heightfield, "points_xy": corners, "rover": rover,
          "hazards": s.ground.hazards, "seed": s.random_seed}  # fmt: skip
    orbital = costmap_for_site(map_config=dc.replace(s.ground.map, source="orbital",
                                                     margin_m=0.0), **kw)  # fmt: skip
    truth = costmap_for_site(map_config=MapConfig(source="truth", margin_m=0.0), **kw)
    bins = trust_table(orbital=orbital, truth=truth, bin_deg=a.bin_deg)
    trusting = costmap_for_site(map_config=dc.replace(s.ground.map, source="orbital",
                                                      margin_m=0.0, confirm_slope_deg=0.0),
                                **kw)  # fmt: skip
    unconfirmed = orbital.unconfirmed
    if unconfirmed is None:
        unconfirmed = np.zeros(orbital.shape, bool)

    def blocked(cm):  # on the grid the ground plans on (ground.hazards.resolution_m)
        fine = refined_costmap(cm, resolution_m=s.ground.hazards.resolution_m, rover=rover,
                               hazards=s.ground.hazards)  # fmt: skip
        return float(np.mean(np.isinf(fine.cost)))

    result = {
        "hazard_fraction": float(np.mean(trusting.lethal_raw)),
        "unconfirmed_fraction": float(np.mean(unconfirmed)),
        "blocked_fraction": blocked(orbital),
        "blocked_trusting_fraction": blocked(trusting),
        "scenario": a.scenario,
        "orbital_resolution_m": orbital.resolution_m,
        "truth_resolution_m": truth.resolution_m,
        "confirm_slope_deg": s.ground.map.confirm_slope_deg,
        "crossing_deg": crossing_deg(bins),
        "bins": bins,
    }
    print(f"{'orbital slope':>14} {'cells':>7} {'truth lethal':>13} {'any lethal':>11}")
    for r in bins:
        if r["cells"]:
            print(f"{r['lo_deg']:5.1f}-{r['hi_deg']:5.1f} deg {r['cells']:>7} "
                  f"{r['lethal_fraction']:>13.2f} {r['any_lethal_fraction']:>11.2f}")  # fmt: skip
    print(f"lethal fraction crosses 0.5 at {result['crossing_deg']} deg "
          f"(confirm_slope_deg {result['confirm_slope_deg']:g})")  # fmt: skip
    pct = {k: 100.0 * v for k, v in result.items() if k.endswith("_fraction")}
    print(f"orbital cells: {pct['hazard_fraction']:.1f} % hazards, "
          f"{pct['unconfirmed_fraction']:.1f} % unconfirmed; blocked after inflation: "
          f"{pct['blocked_fraction']:.1f} % ({pct['blocked_trusting_fraction']:.1f} % "
          "trusting the orbital map)")  # fmt: skip
    record_speed_index(result)
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import run_main

    run_main(main, "orbital_trust.py")
