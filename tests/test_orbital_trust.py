"""benchmarks/orbital_trust.py: the per-slope table of how much of a free orbital cell
truth calls lethal, on grids small enough to count by hand."""

import numpy as np
import pytest

from benchmarks.orbital_trust import crossing_deg, trust_table
from lunar_drake.autonomy.costmap import Costmap


def _cm(slope, lethal, res, unconfirmed=None):
    slope = np.asarray(slope, float)
    z = np.zeros_like(slope)
    return Costmap(cost=z + 1, slope_deg=slope, step_m=z, roughness_m=z,
                   lethal_raw=np.asarray(lethal, bool), x0_m=0.0, y1_m=2.0,
                   resolution_m=res, unconfirmed=unconfirmed)  # fmt: skip


def test_the_table_counts_truths_hazards_inside_each_free_orbital_cell():
    # Orbital 2 x 2 cells of 1 m: slopes 1, 11 / 13, 5 deg; the 5 deg one is lethal (a
    # step) and so left out. Truth at 0.5 m: of the 1 deg cell one quarter lethal, of
    # the 11 deg cell three quarters, of the 13 deg cell all.
    orbital = _cm([[1.0, 11.0], [13.0, 5.0]], [[0, 0], [0, 1]], 1.0)
    truth = _cm(np.zeros((4, 4)), [[1, 0, 1, 1], [0, 0, 0, 1], [1, 1, 0, 0], [1, 1, 0, 0]], 0.5)
    rows = trust_table(orbital=orbital, truth=truth, bin_deg=4.0)
    by_lo = {r["lo_deg"]: r for r in rows}
    assert [r["lo_deg"] for r in rows] == [0.0, 4.0, 8.0, 12.0]
    assert by_lo[0.0]["cells"] == 1 and by_lo[0.0]["lethal_fraction"] == 0.25
    assert by_lo[4.0]["cells"] == 0 and by_lo[4.0]["lethal_fraction"] is None
    assert by_lo[8.0]["lethal_fraction"] == 0.75 and by_lo[12.0]["lethal_fraction"] == 1.0
    assert all(r["any_lethal_fraction"] == 1.0 for r in rows if r["cells"])
    # An unconfirmed cell (lethal only by the steep-orbital rule) counts as free.
    ruled = _cm([[1.0, 11.0], [13.0, 5.0]], [[0, 1], [1, 1]], 1.0,
                unconfirmed=np.array([[0, 1], [1, 0]], bool))  # fmt: skip
    assert trust_table(orbital=ruled, truth=truth, bin_deg=4.0) == rows
    with pytest.raises(SystemExit, match="divide"):
        trust_table(orbital=orbital, truth=_cm(np.zeros((3, 3)), np.zeros((3, 3)), 0.4))


def test_the_crossing_is_interpolated_between_bin_centres():
    bins = [{"lo_deg": lo, "hi_deg": lo + 2.0, "cells": 100, "lethal_fraction": f}
            for lo, f in ((6.0, 0.1), (8.0, 0.3), (10.0, 0.7))]  # fmt: skip
    assert crossing_deg(bins) == pytest.approx(10.0)  # 9 deg: 0.3, 11 deg: 0.7
    bins[2]["cells"] = 5  # too few cells to count
    assert crossing_deg(bins) is None
