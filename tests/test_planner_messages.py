"""The goal-in-a-hazard error says which limit the goal's cell breaks, or which hazard
(where, what it breaks) the goal lies within the rover's footprint plus inflation of;
synthetic DEMs whose hazards are known by construction."""

import math
import re

import numpy as np
import pytest

from lunar_drake.autonomy.costmap import Costmap, HazardConfig, RoverEnvelope, build_costmap
from lunar_drake.autonomy.planner import PlanningError, hazard_reason, plan_path
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


def _refused(cm, goal) -> str:
    with pytest.raises(PlanningError) as exc:
        plan_path(costmap=cm, start_xy=(-15.0, 0.0), goal_xy=goal)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"goal ({goal[0]:.2f}, {goal[1]:.2f}) m is inside")
    return msg


def test_a_goal_on_a_steep_wall_names_the_slope_limit():
    X, Y = _grid()
    d = np.hypot(X, Y)
    # A 12 m crater with 30 deg walls from r = 4 to 6 m: the wall's slope is 30 deg.
    z = -np.clip(6.0 - d, 0.0, 2.0) * math.tan(math.radians(30.0))
    msg = _refused(_costmap(z), (0.0, 5.0))
    m = re.search(r"its cell breaks slope (\d+\.\d) deg > max 14 deg", msg)
    assert m, msg
    assert 25.0 < float(m.group(1)) <= 30.5  # the wall, smoothed over the wheelbase
    assert "footprint" not in msg


def test_a_goal_beside_a_boulder_names_the_boulder_and_its_step():
    X, Y = _grid()
    z = np.where(np.hypot(X, Y) < 0.5, 0.3, 0.0)  # a 0.3 m boulder, 1 m across, at (0, 0)
    cm = _costmap(z)
    radius = ROVER.footprint_radius_m + HazardConfig().inflation_m
    assert cm.inflation_radius_m == pytest.approx(radius)
    goal = (1.1, 0.0)  # off the rock (level ground), within its inflation
    gr, gc = cm.cell_of(*goal)
    assert not cm.lethal_raw[gr, gc] and not np.isfinite(cm.cost[gr, gc])
    msg = _refused(cm, goal)
    m = re.search(
        r"within the rover's footprint plus inflation \((\d+\.\d+) m\) of a hazard "
        r"(\d+\.\d+) m away at \((-?\d+\.\d+), (-?\d+\.\d+)\) m, which breaks "
        r"step (\d+\.\d+) m > max (\d+\.\d+) m",
        msg,
    )
    assert m, msg
    r_m, dist, hx, hy, step, max_step = (float(v) for v in m.groups())
    assert r_m == pytest.approx(radius, abs=0.005)
    assert dist <= radius + 1e-9
    # The hazard named is the boulder: its cell centre within a planning cell of the rock.
    assert math.hypot(hx, hy) < 0.5 + cm.resolution_m
    assert dist == pytest.approx(math.hypot(hx - (gc + 0.5) * cm.resolution_m - cm.x0_m,
                                            hy - (cm.y1_m - (gr + 0.5) * cm.resolution_m)),
                                 abs=1e-2)  # fmt: skip
    # The step limit: 0.8 x the smaller of wheel radius and ground clearance.
    expected = 0.8 * min(ROVER.wheel_radius_m, ROVER.ground_clearance_m)
    assert max_step == pytest.approx(expected, abs=0.005)
    assert max_step < step <= 0.3 + 1e-9
    assert "slope" not in msg  # the rock's edge is a step; level ground round it


def test_reason_without_limits_gives_the_layers():
    # A hand-made costmap (no limits known): a lethal cell's layers, no limit claimed.
    lethal = np.zeros((5, 5), bool)
    lethal[2, 2] = True
    cm = Costmap(cost=np.where(lethal, np.inf, 1.0), slope_deg=np.full((5, 5), 3.0),
                 step_m=np.full((5, 5), 0.05), roughness_m=np.zeros((5, 5)),
                 lethal_raw=lethal, x0_m=0.0, y1_m=5.0, resolution_m=1.0)  # fmt: skip
    assert hazard_reason(cm, (2, 2)) == "its cell is marked lethal (slope 3.0 deg, step 0.05 m)"
    cm = Costmap(**{**cm.__dict__, "cost": np.where(lethal, np.inf, 1.0)})
    cm.cost[2, 3] = np.inf  # inflated by hand
    assert hazard_reason(cm, (2, 3)) == (
        "within the rover's footprint plus inflation (0.00 m) of a hazard 1.00 m away at "
        "(2.50, 2.50) m, which is marked lethal (slope 3.0 deg, step 0.05 m)"
    )
