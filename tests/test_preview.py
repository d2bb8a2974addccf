"""Command preview (autonomy/preview.py): the on-board follower run forward by the ground.
References: a fine Euler integration of the twist, the path's own geometry."""

import math

import numpy as np
import pytest

from lunar_drake.autonomy.follower import FollowerParams
from lunar_drake.autonomy.preview import _arc, preview_goto


@pytest.mark.parametrize("twist", [(0.2, 0.0, 0.0), (0.2, 0.05, 0.1), (0.0, 0.0, -0.2)])
def test_each_tick_is_the_exact_arc_of_its_twist(twist):
    x, y, yaw = 1.0, -2.0, 0.7
    n = 100000
    dt = 2.0 / n
    for _ in range(n):  # Euler, chassis twist rotated into the site frame
        c, s = math.cos(yaw), math.sin(yaw)
        x += (twist[0] * c - twist[1] * s) * dt
        y += (twist[0] * s + twist[1] * c) * dt
        yaw += twist[2] * dt
    np.testing.assert_allclose(_arc(1.0, -2.0, 0.7, *twist, 2.0), (x, y, yaw), atol=1e-4)


def test_a_straight_goto_ends_at_its_goal_at_the_drive_speed():
    p = preview_goto(pose=(0.0, 0.0, 0.0), waypoints=[(0.0, 0.0), (10.0, 0.0)],
                     speed_mps=0.2, tolerance_m=0.2, rate_hz=10.0)  # fmt: skip
    assert math.hypot(p[-1, 1] - 10.0, p[-1, 2]) <= 0.2 + 0.02
    assert p[-1, 0] == pytest.approx(9.8 / 0.2, abs=0.5)
    assert np.abs(p[:, 2]).max() < 1e-9 and np.all(np.diff(p[:, 0]) > 0)


def test_a_turned_rover_turns_in_place_then_follows_an_l_shaped_path_near_its_corner():
    wp = [(0.0, 0.0), (6.0, 0.0), (6.0, 6.0)]
    p = preview_goto(pose=(0.0, 0.0, math.pi), waypoints=wp, speed_mps=0.2, tolerance_m=0.2,
                     rate_hz=20.0, params=FollowerParams(crab_gain_per_s=0.3),
                     height=lambda x, y: 0.1 * np.asarray(x))  # fmt: skip
    assert np.hypot(p[1, 1], p[1, 2]) < 0.05  # turning in place first
    assert math.hypot(p[-1, 1] - 6.0, p[-1, 2] - 6.0) <= 0.25
    corner = np.hypot(p[:, 1] - 6.0, p[:, 2]).min()
    assert corner < FollowerParams().lookahead_m  # cuts the corner by < the look-ahead
    # never far from the path (distance to the two legs)
    d = np.minimum(np.abs(p[:, 2]) + np.clip(p[:, 1] - 6.0, 0, None),
                   np.abs(p[:, 1] - 6.0) + np.clip(-p[:, 2], 0, None))  # fmt: skip
    assert d.max() < 1.0
    np.testing.assert_allclose(p[:, 3], 0.1 * p[:, 1])
