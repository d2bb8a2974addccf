"""Hazard costmap and least-cost planning (autonomy/costmap.py, autonomy/planner.py) on
synthetic DEMs with known hazards."""

import math

import numpy as np
import pytest

from lunar_drake.autonomy.costmap import (
    HazardConfig,
    RoverEnvelope,
    build_costmap,
    hazard_layers,
    orbital_dem,
)
from lunar_drake.autonomy.planner import PlanningError, plan_path
from lunar_drake.errors import OutOfBoundsError
from lunar_drake.models.rover_description import rover_preset

RES = 0.1
N = 400  # 40 m x 40 m, origin at the centre
ROVER = RoverEnvelope.of(rover_preset("krex2_rp"))


def _grid():
    x = (np.arange(N) + 0.5 - N / 2) * RES
    y = (N / 2 - np.arange(N) - 0.5) * RES  # row 0 north
    return np.meshgrid(x, y)


def _costmap(z, **kw):
    return build_costmap(z, resolution_m=RES, x0_m=-N / 2 * RES, y1_m=N / 2 * RES,
                         rover=ROVER, config=HazardConfig(**kw))  # fmt: skip


def test_layers_of_a_planar_ramp_against_closed_forms():
    X, _ = _grid()
    z = X * math.tan(math.radians(10.0))
    slope, step, rough = hazard_layers(z, resolution_m=RES, baseline_m=1.2, step_window_m=0.5)
    inner = (slice(20, -20), slice(20, -20))
    assert np.allclose(slope[inner], 10.0, atol=1e-6)
    # A plane has no steps (the step is measured from the smoothed surface).
    assert np.allclose(step[inner], 0.0, atol=1e-9)
    assert np.allclose(rough[inner], 0.0, atol=1e-9)


def test_a_boulder_is_lethal_inflated_by_the_footprint_and_the_path_goes_round():
    X, Y = _grid()
    z = np.where(np.hypot(X, Y) < 0.5, 0.3, 0.0)  # a 0.3 m boulder, 1 m across
    cm = _costmap(z)
    assert cm.lethal_raw.sum() > 0
    r, c = cm.cell_of(0.0, 0.0)
    assert not np.isfinite(cm.cost[r, c])
    # Inflation: cells within the footprint radius + margin (0.7 + 0.2 m) of the rock
    # are lethal (0.5 m planning cells: to about 1.4 m from its centre).
    assert ROVER.footprint_radius_m == pytest.approx(0.7)
    r2, c2 = cm.cell_of(1.2, 0.0)
    assert not np.isfinite(cm.cost[r2, c2])
    r3, c3 = cm.cell_of(2.5, 0.0)
    assert np.isfinite(cm.cost[r3, c3])
    path = plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(15.0, 0.0))
    assert np.allclose(path.waypoints_xy[0], (-15.0, 0.0))
    assert np.allclose(path.waypoints_xy[-1], (15.0, 0.0))
    assert np.all(np.isfinite(cm.cost[path.cells[:, 0], path.cells[:, 1]]))
    assert 30.0 < path.length_m < 33.0  # a small detour
    # The detour clears the rock by the inflation radius.
    x, y = cm.centre_of(path.cells[:, 0], path.cells[:, 1])
    assert np.hypot(x, y).min() > 0.5 + ROVER.footprint_radius_m
    # Same inputs, same path.
    again = plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(15.0, 0.0))
    assert np.array_equal(again.cells, path.cells)


def test_a_goal_beside_a_rock_moves_to_the_nearest_free_cell_within_the_radius():
    """A goal 1.1 m from a boulder's centre lies in its inflation: refused without a
    radius; with one, the path ends at the free cell nearest the goal (found here by
    brute force over every cell), not farther than the radius; too small a radius is
    refused and says so."""
    X, Y = _grid()
    cm = _costmap(np.where(np.hypot(X, Y) < 0.5, 0.3, 0.0))
    goal = (1.1, 0.2)
    with pytest.raises(PlanningError, match="inside a hazard"):
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=goal)
    path = plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=goal, goal_free_radius_m=1.0)
    rr, cc = np.nonzero(np.isfinite(cm.cost))
    g = cm.cell_of(*goal)
    d = np.hypot(rr - g[0], cc - g[1]) * cm.resolution_m
    best = d.min()
    end = path.waypoints_xy[-1]
    end_cell = cm.cell_of(*end)
    assert np.isfinite(cm.cost[end_cell]) and best <= 1.0
    moved = math.hypot(end_cell[0] - g[0], end_cell[1] - g[1]) * cm.resolution_m
    assert moved == pytest.approx(best)
    assert tuple(path.cells[-1]) == end_cell
    with pytest.raises(PlanningError, match=r"no free cell lies within 0\.05 m"):
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=goal, goal_free_radius_m=0.05)


def _crater():
    X, Y = _grid()
    d = np.hypot(X, Y)
    # A 12 m crater with 30 deg walls from r = 4 to 6 m, flat floor 1.15 m deep.
    wall = np.clip(6.0 - d, 0.0, 2.0) * math.tan(math.radians(30.0))
    return -wall


def test_goal_in_a_hazard_unreachable_goal_and_off_map_are_clear_errors():
    cm = _costmap(_crater())
    with pytest.raises(PlanningError, match="inside a hazard"):
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(5.0, 0.0))
    with pytest.raises(PlanningError, match="no hazard-free path"):
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(0.0, 0.0))  # the walled floor
    with pytest.raises(OutOfBoundsError, match=r"goal .* is off the map"):
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(25.0, 0.0))
    path = plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=(15.0, 0.0))
    x, y = cm.centre_of(path.cells[:, 0], path.cells[:, 1])
    assert np.hypot(x, y).min() > 6.0  # round the rim, not through the crater


def test_orbital_map_loses_rocks_keeps_craters_and_is_seeded():
    X, Y = _grid()
    z = _crater() + np.where(np.hypot(X - 12.0, Y) < 0.15, 0.25, 0.0)  # a small rock
    truth = _costmap(z)
    r, c = truth.cell_of(12.0, 0.0)
    assert truth.lethal_raw[r, c]
    zo, res_o = orbital_dem(z, resolution_m=RES, orbital_resolution_m=1.0, noise_m=0.01, seed=3)
    assert res_o == pytest.approx(1.0) and zo.shape == (40, 40)
    orb = build_costmap(zo, resolution_m=res_o, x0_m=-20.0, y1_m=20.0, rover=ROVER,
                        config=HazardConfig(resolution_m=1.0))  # fmt: skip
    r, c = orb.cell_of(12.0, 0.0)
    assert not orb.lethal_raw[r, c]  # the rock is gone
    r, c = orb.cell_of(5.0, 0.0)
    assert orb.lethal_raw[r, c]  # the crater wall is not
    again, _ = orbital_dem(z, resolution_m=RES, orbital_resolution_m=1.0, noise_m=0.01, seed=3)
    other, _ = orbital_dem(z, resolution_m=RES, orbital_resolution_m=1.0, noise_m=0.01, seed=4)
    assert np.array_equal(zo, again) and not np.array_equal(zo, other)


def test_waypoint_legs_stay_on_free_cells():
    X, Y = _grid()
    z = np.where(np.hypot(X, Y) < 0.5, 0.3, 0.0) + np.where(np.hypot(X - 6, Y + 2) < 0.5, 0.3, 0.0)
    cm = _costmap(z)
    path = plan_path(costmap=cm, start_xy=(-15.0, 0.5), goal_xy=(15.0, -1.0))
    assert 2 <= len(path.waypoints_xy) < len(path.cells) / 4  # few legs
    for a, b in zip(path.waypoints_xy[:-1], path.waypoints_xy[1:], strict=True):
        t = np.linspace(0.0, 1.0, 200)[:, None]
        p = a + t * (b - a)
        rc = [cm.cell_of(x, y) for x, y in p]
        assert all(np.isfinite(cm.cost[r, c]) for r, c in rc)


def test_plan_command_writes_the_plot_path_and_summary(small_site, tmp_path, capsys):
    from lunar_drake.cli import main

    args = ["plan", "--scenario", "small", "--no-progress", "--goal", "9", "0"]
    assert main([*args, "--out", str(tmp_path / "p")]) == 0
    out = tmp_path / "p"
    assert (out / "plan.png").stat().st_size > 10_000
    rows = (out / "path.csv").read_text().splitlines()
    assert rows[0] == "x_m,y_m" and len(rows) >= 3
    import json

    doc = json.loads((out / "plan.json").read_text())
    # The ground's map by default: the orbital product.
    assert doc["map"] == "orbital" and doc["length_m"] >= doc["straight_line_m"]
    wp = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    assert doc["waypoint_length_m"] == pytest.approx(
        np.sum(np.hypot(*np.diff(wp, axis=0).T)), abs=1e-3)
    assert doc["waypoint_length_m"] >= doc["straight_line_m"] - 1e-3
    assert 0.0 <= doc["unconfirmed_fraction"] < 0.5 and doc["confirm_slope_deg"] == 11.0
    capsys.readouterr()
    # Bad goals: one line, exit 2, nothing written.
    assert main([*args[:-2], "80", "0", "--out", str(tmp_path / "q")]) == 2
    err = capsys.readouterr().err
    assert "OutOfBoundsError" in err and "off the map" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "q").exists()
    assert main([*args, "--map", "orbital", "--out", str(tmp_path / "o")]) == 0
    orb = json.loads((tmp_path / "o" / "plan.json").read_text())
    assert orb["map"] == "orbital" and orb["confirm_slope_deg"] == 11.0
    assert 0.0 <= orb["unconfirmed_fraction"] <= orb["lethal_fraction"]


def test_nan_and_off_site_points_are_clear_errors(small_site):
    from lunar_drake.autonomy.costmap import MapConfig, costmap_for_site
    from lunar_drake.errors import OutOfRangeError

    X, _ = _grid()
    cm = _costmap(np.zeros_like(X))
    with pytest.raises(OutOfRangeError, match="goal = \\(nan"):
        plan_path(costmap=cm, start_xy=(0.0, 0.0), goal_xy=(math.nan, 0.0))
    _, site = small_site
    kw = {"heightfield": site.heightfield, "rover": ROVER, "hazards": HazardConfig(),
          "map_config": MapConfig(), "seed": 0}  # fmt: skip
    with pytest.raises(OutOfBoundsError, match="lie off the site"):
        costmap_for_site(points_xy=[(400.0, 400.0), (500.0, 500.0)], **kw)
    with pytest.raises(OutOfRangeError, match="must be finite"):
        costmap_for_site(points_xy=[(0.0, math.inf)], **kw)
