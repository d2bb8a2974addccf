"""The heading policy (flight.heading; autonomy/follower.py): ``path`` faces the way the
rover drives; ``sun`` (explicit steer) crabs along the path with the solar panel turned to
the Sun's azimuth, which the ground computes from its ephemeris and sends with each goto.
Drake-free cores first, then the ground's azimuth against the plant's ephemeris and a
short mission."""

import dataclasses as dc
import math

import numpy as np
import pytest

from lunar_drake.autonomy.commands import ExecutorState, GotoCommand, executor_step
from lunar_drake.autonomy.follower import (
    FollowerParams,
    HeadingConfig,
    follow_step,
    sun_heading,
)
from lunar_drake.autonomy.operations import OperatorParams, OperatorState, Request, operator_step
from lunar_drake.autonomy.preview import _arc, preview_goto
from lunar_drake.comms.messages import Delivery, Message
from lunar_drake.errors import ConfigError, OutOfRangeError

SUN = FollowerParams(heading="sun", panel_azimuth_rad=math.pi / 2, crab_gain_per_s=0.3)
D80 = math.radians(80.0)


def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _drive(params, wp, pose, sun=None, rate_hz=20.0, max_s=600.0):
    """Follows ``wp`` from ``pose`` with exact arcs (no slip): (poses, twists) per tick."""
    x, y, yaw = pose
    index, poses, twists = 0, [], []
    for _ in range(int(max_s * rate_hz)):
        tw, index, done = follow_step((x, y, yaw), wp, index, speed_mps=0.2, tolerance_m=0.2,
                                      params=params, sun_azimuth_rad=sun)  # fmt: skip
        if done:
            break
        x, y, yaw = _arc(x, y, yaw, *tw, 1.0 / rate_hz)
        poses.append((x, y, yaw))
        twists.append(tw)
    return np.array(poses), np.array(twists), done


def test_sun_heading_is_yaw_des_when_the_crab_is_feasible_else_the_nearest_feasible():
    # Any crab angle: always yaw_des.
    assert sun_heading(0.0, 1.0, math.pi / 2) == pytest.approx(1.0)
    assert sun_heading(2.0, -2.5, math.pi) == pytest.approx(-2.5)
    # Leg along +x, panel wants yaw -58 deg: a 58 deg crab, feasible within 80 deg.
    assert sun_heading(0.0, math.radians(-58.0), D80) == pytest.approx(math.radians(-58.0))
    # Backwards is feasible too: crab 150 deg (30 deg off -x).
    assert sun_heading(0.0, math.radians(-150.0), D80) == pytest.approx(math.radians(-150.0))
    # A crab of 87 deg is in the wrap band (80..100): the nearest feasible, 80 deg.
    assert sun_heading(0.0, math.radians(-87.0), D80) == pytest.approx(math.radians(-80.0))
    # 95 deg: nearer the backward side, 100 deg (a wheel at -80 deg, reversed).
    assert sun_heading(0.0, math.radians(-95.0), D80) == pytest.approx(math.radians(-100.0))
    # A 30 deg steering limit: crab 70 deg is driven at 30 deg (the panel 40 deg off),
    # never by turning round (the panel has one face).
    lim = math.radians(30.0)
    yaw = sun_heading(0.5, 0.5 + math.radians(70.0), lim)
    assert _wrap(0.5 - yaw) == pytest.approx(-lim)
    yaw = sun_heading(0.5, 0.5 + math.radians(120.0), lim)  # nearer backwards: 150 deg
    assert _wrap(0.5 - yaw) == pytest.approx(-math.radians(150.0))
    # Wrapping: a leg along -x and yaw_des near +-pi.
    assert sun_heading(math.pi, -math.pi + 0.1, D80) == pytest.approx(-math.pi + 0.1)


def test_the_sun_policy_crabs_towards_the_aim_and_turns_the_panel_to_the_sun():
    wp = [(0.0, 0.0), (10.0, 0.0)]
    sun = math.radians(30.0)  # yaw_des = 30 - 90 = -60 deg: a 60 deg crab to the left
    yaw_des = sun - math.pi / 2
    # At yaw_des: the velocity points along the path (world +x), no yaw rate.
    tw, _, done = follow_step((2.0, 0.0, yaw_des), wp, 0, speed_mps=0.2, tolerance_m=0.5,
                              params=SUN, sun_azimuth_rad=sun)  # fmt: skip
    c, s = math.cos(yaw_des), math.sin(yaw_des)
    world = (c * tw[0] - s * tw[1], s * tw[0] + c * tw[1])
    assert not done and world == pytest.approx((0.2, 0.0), abs=1e-12) and tw[2] == 0.0
    # 10 deg short of it: turn at yaw_gain_per_s times the error, still driving the path.
    tw, _, _ = follow_step((2.0, 0.0, yaw_des + math.radians(10.0)), wp, 0, speed_mps=0.2,
                           tolerance_m=0.5, params=SUN, sun_azimuth_rad=sun)  # fmt: skip
    assert tw[2] == pytest.approx(-math.radians(10.0)) and math.hypot(tw[0], tw[1]) == 0.2
    # Facing the path (today's heading): 60 deg off, beyond turn_in_place_rad: turn first.
    tw, _, _ = follow_step((2.0, 0.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5,
                           params=SUN, sun_azimuth_rad=sun)  # fmt: skip
    assert tw == pytest.approx([0.0, 0.0, -0.2])
    # Off the path: the velocity points at the aim point, 1.5 m ahead on the path.
    tw, _, _ = follow_step((2.0, 0.9, yaw_des), wp, 0, speed_mps=0.2, tolerance_m=0.5,
                           params=SUN, sun_azimuth_rad=sun)  # fmt: skip
    world = (c * tw[0] - s * tw[1], s * tw[0] + c * tw[1])
    assert math.atan2(world[1], world[0]) == pytest.approx(math.atan2(-0.9, 1.2))
    # Without an azimuth (a goto the ground sent for `path`), or with `path`: today's.
    for params, az in ((SUN, None), (dc.replace(SUN, heading="path"), sun)):
        tw, _, _ = follow_step((2.0, 0.0, 0.0), wp, 0, speed_mps=0.2, tolerance_m=0.5,
                               params=params, sun_azimuth_rad=az)  # fmt: skip
        assert tw == pytest.approx([0.2, 0.0, 0.0])


def test_driving_an_l_shaped_path_the_sun_policy_holds_the_panel_on_the_sun():
    """Exact arcs: ``path`` faces each leg; ``sun`` reaches the goal holding yaw_des on
    both legs (60 and -30 deg crabs); a leg straight at the Sun is driven with the crab
    10 deg short of the wheels' wrap."""
    wp = [(0.0, 0.0), (8.0, 0.0), (8.0, 8.0)]
    sun = math.radians(30.0)
    yaw_des = sun - math.pi / 2
    poses, _, done = _drive(dc.replace(SUN, heading="path"), wp, (0.0, 0.0, 0.0), sun)
    leg1 = (poses[:, 0] > 2.0) & (poses[:, 0] < 6.0)
    leg2 = (poses[:, 1] > 3.0) & (poses[:, 1] < 6.0)
    assert done and np.degrees(np.max(np.abs(poses[leg1, 2]))) < 1.0  # facing each leg
    assert np.degrees(np.max(np.abs(poses[leg2, 2] - math.pi / 2))) < 1.0
    poses, _, done = _drive(SUN, wp, (0.0, 0.0, 0.0), sun)
    assert done and math.hypot(poses[-1, 0] - 8.0, poses[-1, 1] - 8.0) <= 0.2
    err = np.degrees(np.abs(_wrap(poses[:, 2] - yaw_des)))
    settled = int(np.argmax(err < 1.0))
    assert settled * 0.05 < 15.0 and np.max(err[settled:]) < 1.0
    # The Sun along the first leg (yaw_des -90: crab 90 deg): held at 80 deg, then,
    # on the second leg (crab 180 deg: backwards), the panel on the Sun.
    poses, _, done = _drive(SUN, wp, (0.0, 0.0, 0.0), 0.0)
    assert done
    first = poses[:, 0] < 6.0  # the aim still on the first leg
    steady = first & (np.arange(len(poses)) > 200)
    assert np.degrees(poses[steady, 2]) == pytest.approx(-80.0, abs=0.5)
    second = poses[:, 1] > 2.0
    assert np.degrees(np.abs(_wrap(poses[second, 2] + math.pi / 2))) == pytest.approx(0.0, abs=0.5)
    # The preview the ground shows runs the same follower: it reaches the goal.
    p = preview_goto(pose=(0.0, 0.0, 0.0), waypoints=wp, speed_mps=0.2, tolerance_m=0.2,
                     rate_hz=10.0, params=SUN, sun_azimuth_rad=sun)  # fmt: skip
    assert math.hypot(p[-1, 1] - 8.0, p[-1, 2] - 8.0) <= 0.2


def test_a_goto_carries_the_sun_azimuth_and_the_executor_uses_it():
    wp = ((0.0, 0.0), (5.0, 0.0))
    plain = GotoCommand(waypoints=wp)
    sunny = GotoCommand(waypoints=wp, sun_azimuth_rad=0.5)
    assert plain.size_bytes() == 4 + 24 + 32 and sunny.size_bytes() == plain.size_bytes() + 8
    out = {}
    for name, cmd in (("plain", plain), ("sunny", sunny)):
        msgs = (Delivery(Message("commands", 0, 0.0, cmd, cmd.size_bytes()), 0.0),)
        yaw_des = 0.5 - math.pi / 2
        _, o = executor_step(ExecutorState(), msgs, tick=0, rate_hz=10.0, brake_delay_s=0.5,
                             pose=(0.0, 0.0, yaw_des), follower=SUN)  # fmt: skip
        out[name] = o.twist
    # No azimuth: pure pursuit turns the rover to the path (over 50 deg off: in place).
    assert out["plain"] == pytest.approx([0.0, 0.0, 0.2])
    # With it: a crab along the path at yaw_des.
    assert out["sunny"][1] > 0.1 and out["sunny"][2] == pytest.approx(0.0, abs=1e-12)


def test_the_ground_sends_the_azimuth_for_mid_drive_in_the_rovers_frame():
    calls = []

    def sun_azimuth(t):
        calls.append(t)
        return 3.0

    def planner(start, goal):
        return [tuple(start), tuple(goal)]

    def goto_of(**kw):
        st = operator_step(OperatorState(), (), now=2.0, params=OperatorParams(),
                           planner=planner, start_pose=(0.0, 0.0, 0.0),
                           requests=(Request("goal", (10.0, 0.0)),), **kw)  # fmt: skip
        (goto,) = [m.payload for m in st.outbox if isinstance(m.payload, GotoCommand)]
        return goto, st

    goto, _ = goto_of()
    assert goto.sun_azimuth_rad is None and goto.size_bytes() == 4 + 24 + 32
    previews = []

    def preview(pose, wp, sun_azimuth_rad=None):
        previews.append(sun_azimuth_rad)
        return np.zeros((1, 4))

    goto, st = goto_of(sun_azimuth=sun_azimuth, correction=(1.0, -2.0, 0.3), preview=preview)
    (start, goal) = st.path  # from the corrected estimate, (1, -2)
    assert start == pytest.approx((1.0, -2.0))
    length = math.hypot(goal[0] - start[0], goal[1] - start[1])
    assert calls == [pytest.approx(2.0 + 0.5 * length / 0.2)]  # the middle of the drive
    # Turned into the rover's frame like the waypoints; the preview gets the ground's.
    assert goto.sun_azimuth_rad == pytest.approx(_wrap(3.0 - 0.3))
    assert previews == [3.0] and st.preview[0] == st.goto_seq


def test_the_grounds_sun_azimuth_is_the_plants_ephemeris(cache):
    """The ground's azimuth (its ephemeris, before launch) is the Sun the plant lights
    the site with (the plant's EphemerisSource, site polar grid frame)."""
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.ground import sun_azimuth_source
    from lunar_drake.ephemeris.sun_earth import SiteLocation
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.systems.ephemeris_source import EphemerisSource

    s = load_scenario(scenario_name="goto", scenario_text="{flight: {heading: {policy: sun}}}")
    az = sun_azimuth_source(s)
    assert sun_azimuth_source(load_scenario(scenario_name="goto")) is None  # path
    src = EphemerisSource(site=SiteLocation(s.site.latitude_deg, s.site.longitude_deg),
                          epoch_utc=s.site.epoch_utc, update_period_s=900.0,
                          world_frame="polar_grid")  # fmt: skip
    sim = Simulator(src)
    for t in (0.0, 1800.0):
        sim.AdvanceTo(t + 1e-3)  # past the update at t
        v = src.sun_direction_output.Eval(sim.get_context())
        assert az(t) == pytest.approx(math.atan2(v[1], v[0]), abs=1e-9)
    # The Sun moves ~0.5 deg an hour at the pole (a goto carries one azimuth).
    assert math.degrees(_wrap(az(3600.0) - az(0.0))) == pytest.approx(0.5, abs=0.1)


def test_heading_config_checks_and_skid_steer_refuses_sun():
    from lunar_drake.diagrams.flight import follower_params
    from lunar_drake.models.rover_description import husky_rp, krex2_rp
    from lunar_drake.scenario_files import load_scenario

    with pytest.raises(ConfigError, match=r"^policy = 'sunny' is unknown; choose one of"):
        HeadingConfig(policy="sunny").validate()
    with pytest.raises(OutOfRangeError, match=r"^crab_margin_deg = 50"):
        HeadingConfig(crab_margin_deg=50.0).validate()
    with pytest.raises(ConfigError) as err:
        load_scenario(scenario_name="skid", scenario_text="{flight: {heading: {policy: sun}}}")
    msg = str(err.value)
    assert "flight.heading.policy = 'sun' needs an explicit-steer rover" in msg
    assert "allows only 'path'" in msg and len(msg.splitlines()) == 1
    # `path` (the default) leaves the follower's settings as they were.
    assert follower_params(krex2_rp(), HeadingConfig()) == follower_params(krex2_rp())
    assert follower_params(husky_rp(), HeadingConfig()) == FollowerParams()
    p = follower_params(krex2_rp(), HeadingConfig(policy="sun"))
    assert p.heading == "sun" and p.panel_azimuth_rad == krex2_rp().solar_panel_azimuth_rad
    assert p.max_crab_rad == pytest.approx(D80)  # steering limit 1.6 rad: the wrap decides
    d = dc.replace(krex2_rp(), steering_limit_rad=0.5)
    assert follower_params(d, HeadingConfig(policy="sun")).max_crab_rad == 0.5


def test_mission_sun_policy_keeps_the_panel_on_the_sun_and_reaches_the_goal(cache):
    """The `goto` mission (15 m east) with `sun` on 2027-11-09, when the panel (on the
    rover's left) faces the Sun at a yaw of -58 deg: the rover turns, crabs 58 deg along
    the path, reaches the goal; on truth its yaw stays within 3 deg of the Sun heading
    while it drives. The goto went up with the azimuth (8 bytes more)."""
    from lunar_drake import metrics
    from lunar_drake.diagrams.ground import sun_azimuth_source
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    text = "{site: {epoch_utc: '2027-11-09T00:00:00'}, flight: {heading: {policy: sun}}}"
    scenario = load_scenario(scenario_name="goto", scenario_text=text)
    site = load_site(scenario, progress=False)
    logs = simulate(scenario=scenario, site=site, progress=False, stop_after_goals_s=5.0)
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    (goal,) = summary["goals"]
    assert goal["reached"] and goal["final_distance_m"] < 1.0, goal
    up = [r for r in logs.link if r.direction == "uplink" and r.bytes > 4]
    assert [r.bytes for r in up] == [4 + 24 + 16 * 2 + 8]
    # The Sun heading for the middle of the drive (what the goto carried).
    panel = scenario.rover.description.solar_panel_azimuth_rad
    yaw_des = sun_azimuth_source(scenario)(37.5) - panel
    assert math.degrees(yaw_des) == pytest.approx(-58.0, abs=1.0)
    truth = logs.vectors["truth.pose"]
    tw = logs.vectors["flight.twist_command"]
    assert np.array_equal(truth.times, tw.times)
    err = np.degrees(np.abs(_wrap(truth.column("yaw_rad") - yaw_des)))
    crabbing = np.hypot(tw.column("vx_mps"), tw.column("vy_mps")) > 0.0
    settled = int(np.argmax(err < 2.0))
    assert truth.times[settled] < 15.0
    driving = crabbing & (np.arange(len(err)) >= settled)
    assert driving.sum() * scenario.logging.period_s > 50.0
    assert np.max(err[driving]) < 3.0
    # ... sideways: the body's velocity is about 58 deg off its x axis.
    v_world = truth.data[driving][:, [6, 7]]
    yaw = truth.column("yaw_rad")[driving]
    crab = np.degrees(_wrap(np.arctan2(v_world[:, 1], v_world[:, 0]) - yaw))
    fast = np.hypot(*v_world.T) > 0.1
    assert np.median(crab[fast]) == pytest.approx(58.0, abs=5.0)


def test_cross_track_compiled_gives_the_vectorized_bits():
    """``cross_track`` (one compiled pass over the legs) against the vectorized numpy
    formulation it replaced: the same distance and heading bits, corners, repeated
    waypoints and ties included; a path needs two waypoints."""
    from lunar_drake.autonomy.follower import cross_track

    def numpy_cross_track(p, wp):
        a, b = wp[:-1], wp[1:]
        d = b - a
        L2 = np.maximum(np.sum(d * d, axis=1), 1e-18)
        t = np.clip(np.sum((p - a) * d, axis=1) / L2, 0.0, 1.0)
        q = a + t[:, None] * d
        k = int(np.argmin(np.hypot(q[:, 0] - p[0], q[:, 1] - p[1])))
        e = (d[k, 0] * (p[1] - a[k, 1]) - d[k, 1] * (p[0] - a[k, 0])) / math.sqrt(float(L2[k]))
        return float(e), math.atan2(d[k, 1], d[k, 0])

    rng = np.random.default_rng(2)
    for n in (2, 3, 7, 40):
        wp = np.cumsum(rng.normal(0.0, 3.0, (n, 2)), axis=0)
        wp[n // 2] = wp[n // 2 - 1]  # a repeated waypoint: a zero-length leg
        for p in np.r_[rng.uniform(wp.min() - 5, wp.max() + 5, (50, 2)), wp]:
            assert cross_track(p, wp) == numpy_cross_track(p, wp)
    with pytest.raises(ConfigError, match="n >= 2"):
        cross_track((0.0, 0.0), [[1.0, 2.0]])
