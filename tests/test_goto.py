"""Driving to an operator goal through the link: the ground plans on its map, sends the
path up, the rover follows it with its EKF estimate (autonomy/follower.py), truth
scores it."""

import math

import numpy as np
import pytest

from lunar_drake.autonomy.commands import ExecutorState, GotoCommand, executor_step
from lunar_drake.autonomy.follower import FollowerParams, aim_point, follow_step
from lunar_drake.comms.messages import Delivery, Message
from lunar_drake.errors import ConfigError


def test_pure_pursuit_aims_ahead_turns_in_place_and_stops_at_the_goal():
    wp = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    aim, k = aim_point((2.0, 0.0), wp, 0, 1.5)
    assert k == 0 and aim == pytest.approx([3.5, 0.0])
    aim, k = aim_point((9.5, 0.0), wp, 0, 1.5)  # past the corner: onto the next leg
    assert k == 1 and aim[0] == pytest.approx(10.0) and aim[1] > 0.0
    # Heading along the leg: straight ahead at the speed.
    tw, _, done = follow_step((2.0, 0.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5)
    assert not done and tw == pytest.approx([0.2, 0.0, 0.0])
    # Aim to the left: positive yaw rate, arc curvature 2 sin(a) / d (capped).
    tw, _, _ = follow_step((2.0, -0.5, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5)
    assert tw[0] > 0.0 and tw[2] > 0.0
    # Facing away: turn in place.
    tw, _, _ = follow_step((2.0, 0.0, math.pi), wp, 0, speed_mps=0.2, tolerance_m=0.5)
    assert tw[0] == 0.0 and abs(tw[2]) == pytest.approx(0.2)
    tw, _, done = follow_step((10.1, 9.7, 1.0), wp, 1, speed_mps=0.2, tolerance_m=0.5)
    assert done and np.all(tw == 0.0)


def test_pure_pursuit_arc_and_crab_by_hand():
    """The compiled step against the law worked out by hand: 0.5 m right of the first
    leg, the aim is where the 1.5 m circle meets it, (2 + sqrt(2), 0)."""
    wp = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    alpha = math.atan2(0.5, math.sqrt(2.0))
    v = 0.2 * math.cos(alpha)
    wz = min(2.0 * v * math.sin(alpha) / 1.5, 0.2)
    tw, k, done = follow_step((2.0, -0.5, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5)
    assert (k, done) == (0, False)
    assert tw == pytest.approx([v, 0.0, wz], rel=1e-12)
    # Crabbing back: -gain x (cross-track -0.5 m), at most half the forward speed.
    crab = FollowerParams(crab_gain_per_s=0.3)
    tw, _, _ = follow_step((2.0, -0.5, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5, params=crab)
    assert tw == pytest.approx([v, min(0.3 * 0.5, 0.5 * v), wz], rel=1e-12)
    with pytest.raises(ConfigError, match=r"waypoints have shape \(3,\)"):
        follow_step((0.0, 0.0, 0.0), [1.0, 2.0, 3.0], 0, speed_mps=0.2, tolerance_m=0.5)


def test_executor_runs_a_goto_until_the_estimate_is_at_the_goal_then_the_next():
    goto = GotoCommand(waypoints=((0.0, 0.0), (5.0, 0.0)), speed_mps=0.2, tolerance_m=0.3)
    msgs = [Delivery(Message(topic="commands", seq=0, t_sent_s=0.0, payload=goto,
                             size_bytes=goto.size_bytes()), 0.0)]  # fmt: skip
    st = ExecutorState()
    st, out = executor_step(st, msgs, tick=0, rate_hz=10.0, brake_delay_s=0.5, pose=(0, 0, 0))
    assert out.mode == "driving" and out.twist[0] == pytest.approx(0.2)
    st, out = executor_step(st, msgs, tick=1, rate_hz=10.0, brake_delay_s=0.5,
                            pose=(4.8, 0.0, 0.0))  # fmt: skip
    assert out.mode == "waiting" and np.all(out.twist == 0.0) and st.active is None
    with pytest.raises(ValueError, match="pose estimate"):
        executor_step(ExecutorState(), msgs, tick=0, rate_hz=10.0, brake_delay_s=0.5)


def test_mission_drives_to_the_goal_through_the_link(cache):
    """The `goto` scenario: light time each way, the ground's plan on the site DEM, the rover
    reaches the goal (truth within 1 m) without tipping; the link carried the plan."""
    from lunar_drake import metrics
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name="goto")
    site = load_site(scenario, progress=False)
    # ends 15 s after the ground judged its goal, before the scenario's 150 s
    logs = simulate(scenario=scenario, site=site, progress=False, stop_after_goals_s=15.0)
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    assert logs.stop_reason.startswith("the ground's goals done at t = ")
    t_done = float(logs.stop_reason.split("t = ")[1].split(" s")[0])
    assert logs.simulated_s == pytest.approx(t_done + 15.0, abs=0.6) and logs.simulated_s < 140
    (goal,) = summary["goals"]
    assert goal["reached"], goal
    assert goal["final_distance_m"] < 1.0
    assert summary["rover"]["max_tilt_deg"] < 15.0
    up = [r for r in logs.link if r.direction == "uplink"]
    gotos = [r for r in up if r.bytes > 4]  # the rest are 4-byte heartbeats
    assert len(gotos) == 1 and gotos[0].bytes >= 4 + 24 + 16 * 2  # the planned path went up
    assert 1.25 < gotos[0].t_received - gotos[0].t_sent < 1.40  # light time + processing
    heartbeats = [r.t_sent for r in up if r.bytes == 4]
    assert len(heartbeats) > 10 and max(np.diff(heartbeats)) <= 5.0 + 1e-9
    # The mode manager: idle -> driving -> waiting, and the ground saw both changes.
    assert [(m["before"], m["after"]) for m in summary["modes"]["transitions"]] == [
        ("idle", "driving"),
        ("driving", "waiting"),
    ]
    assert summary["modes"]["seen_by_ground"] == 2
    # The ground judged the goal reached from telemetry alone, and its pose estimate
    # (downlinked, carried forward) ends on the rover's.
    assert summary["ground"]["goals"] == [{"goal_xy_m": [9.0, 0.0], "status": "reached"}]
    ground_xy = logs.vectors["ground.pose_estimate"].data[-1, :2]
    truth_xy = logs.vectors["truth.pose"].data[-1, :2]
    assert np.hypot(*(ground_xy - truth_xy)) < 1.0
    # The default heading policy (`path`): on truth, the rover faces the way it drives
    # (the crab back onto the path and side slip: a few degrees; tests/test_heading.py
    # drives `sun`).
    truth, tw = logs.vectors["truth.pose"], logs.vectors["flight.twist_command"]
    v = truth.data[:, 6:8]  # world-frame velocity
    driving = (np.hypot(tw.column("vx_mps"), tw.column("vy_mps")) > 0) & (np.hypot(*v.T) > 0.1)
    crab = np.arctan2(v[:, 1], v[:, 0]) - truth.column("yaw_rad")
    crab = np.degrees(np.abs((crab + np.pi) % (2 * np.pi) - np.pi))[driving]
    assert len(crab) > 300 and np.median(crab) < 2.0 and np.max(crab) < 10.0


@pytest.mark.parametrize(
    ("goal", "match"),
    [("{x_m: 80.0, y_m: 0.0}", r"ground.goals\[0\]: goal .* off the map: x in .* cells"),
     ("{x_m: 8.0, y_m: 6.0}", r"ground.goals\[0\]: goal .* inside a hazard"),
     (None, r"ground.actions\[0\]: goal \(500.00, 0.00\) m is off the ground's map: "
            r"x in \[-12.8, \S+\], y in \[\S+, 12.8\] m \(whole \S+ m cells")],
)  # fmt: skip
def test_bad_goals_are_one_line_errors_and_write_nothing(cache, tmp_path, capsys, goal, match):
    import re

    from lunar_drake.cli import main

    out = tmp_path / "run"
    args = ["run", "--scenario", "goto", "--no-meshcat", "--no-progress", "--out", str(out)]
    # The rock at (8, 6) is under the orbital map's 2 m limit: only the true map has it.
    text = (
        f"{{ground: {{goals: [{goal}], map: {{source: truth}}}}}}" if goal
        else "{ground: {actions: [{t_s: 5, action: goal, x_m: 500, y_m: 0}]}}"
    )  # fmt: skip
    assert main([*args, "--scenario-text", text]) == 2
    err = capsys.readouterr().err
    assert re.search(match, err) and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_hazard_strikes_are_scored_on_truth():
    """Synthetic truth over a plane with a 0.6 m block: crossing it strikes the belly,
    a 30 deg roll is a tilt strike, 12 s commanded but still is immobilized."""
    from lunar_drake import metrics
    from lunar_drake.scenario import Scenario
    from lunar_drake.simulation import BodyPoseVector, SimulationLogs, VectorLog
    from lunar_drake.site import SiteData
    from lunar_drake.terrain.heightfield import Heightfield

    z = np.zeros((200, 200))
    z[90:110, 150:160] = 0.6  # a block at x = 5..6 m (res 0.1, origin at the centre)
    site = SiteData.from_heightfield(Heightfield.from_array(z, resolution_m=0.1))
    s = Scenario()
    h = 0.475  # chassis origin over level ground (underside 0.3 m up)
    t = np.arange(0.0, 40.0, 0.5)
    pose = np.zeros((len(t), 12))
    pose[:, 2] = h
    x = np.where(t < 10.0, -8.0 + t, 2.0)  # drives to x = 2 (clear of the block)
    pose[:, 0] = x
    pose[:, 6] = np.where(t < 10.0, 1.0, 0.0)
    pose[(t >= 5.0) & (t < 6.0), 0] = 5.5  # over the block
    pose[(t >= 20.0) & (t < 21.0), 3] = math.radians(30.0)  # rolled
    twist = np.zeros((len(t), 3))
    twist[:, 0] = 0.2  # commanded to move all along: still from t = 10 s
    vec = {
        "truth.pose": VectorLog(times=t, data=pose, columns=BodyPoseVector.FIELDS),
        "flight.twist_command": VectorLog(times=t, data=twist, columns=("vx", "vy", "wz")),
    }
    logs = SimulationLogs(simulated_s=40.0, stop_reason="", systems=[], vectors=vec,
                          telemetry=None, link=[], frames_written=0, wall={})  # fmt: skip
    hz = metrics.hazards(scenario=s, site=site, logs=logs)
    assert hz == {"belly": 1, "tilt": 1, "immobilized": 1, "strikes": 3}
    pose[(t >= 5.0) & (t < 6.0), 0] = 3.0  # never over the block
    assert metrics.hazards(scenario=s, site=site, logs=logs)["belly"] == 0


def test_explicit_steer_crabs_back_onto_the_path_and_skid_never_does():
    """1 m left of a leg along +x, heading along it: the crab velocity points right (-y
    in the body), proportional to the error, capped at max_crab_fraction of the speed;
    no crab by default (skid steer)."""
    from lunar_drake.autonomy.follower import FollowerParams

    wp = [(0.0, 0.0), (20.0, 0.0)]
    crab = FollowerParams(crab_gain_per_s=0.05)
    tw, _, _ = follow_step((5.0, 1.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.2, params=crab)
    assert tw[1] == pytest.approx(-0.05)
    tw, _, _ = follow_step((5.0, 0.4, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.2, params=crab)
    assert tw[1] == pytest.approx(-0.02)
    tw, _, _ = follow_step((5.0, -9.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.2,
                           params=FollowerParams(crab_gain_per_s=1.0))  # fmt: skip
    assert 0.0 < tw[1] <= 0.5 * tw[0] + 1e-12  # capped
    tw, _, _ = follow_step((5.0, 1.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.2)
    assert tw[1] == 0.0
    # On its leg next to a corner (the aim point already on the next leg): no crab.
    corner = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)]
    tw, _, _ = follow_step((9.0, 0.0, 0.5), corner, 0, speed_mps=0.2, tolerance_m=0.2,
                           params=crab)  # fmt: skip
    assert abs(tw[1]) < 1e-12
