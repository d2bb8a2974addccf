"""The mode manager and virtual bumper (flight) and ground operations (goals, replanning,
safing recovery, the operator API), from the pure cores to short missions."""

import itertools
import math

import numpy as np
import pytest

from lunar_drake.autonomy.commands import (
    DriveCommand,
    ExecutorState,
    GotoCommand,
    Heartbeat,
    MastCommand,
    ResumeCommand,
    StopCommand,
    executor_step,
)
from lunar_drake.autonomy.operations import (
    OperatorParams,
    OperatorState,
    Request,
    distance_to_path,
    ground_pose,
    operator_step,
    reach_radius_m,
)
from lunar_drake.autonomy.safety import SafetyConfig, bumper_step
from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS, pack_telemetry
from lunar_drake.comms.messages import Delivery, Message

RATE = 10.0


class Uplink:
    """Hands the executor uplink deliveries with increasing seq."""

    def __init__(self):
        self.seq = 0
        self.inbox = ()

    def send(self, *cmds):
        for c in cmds:
            self.inbox += (Delivery(Message("commands", self.seq, 0.0, c, c.size_bytes()), 0.0),)
            self.seq += 1


def _step(state, up, tick, **kw):
    return executor_step(state, up.inbox, tick=tick, rate_hz=RATE, brake_delay_s=0.5, **kw)


# ------------------------------------------------------------------ executor and modes


def test_a_trip_safes_drops_the_queue_brakes_and_ignores_driving_until_resume():
    up = Uplink()
    up.send(DriveCommand(10.0, vx_mps=0.2), DriveCommand(10.0, vx_mps=0.1))
    st, out = _step(ExecutorState(), up, 0)
    assert out.mode == "driving" and out.twist[0] == 0.2 and st.motion_seq == 1
    st, out = _step(st, up, 1, trip="stall")
    assert out.mode == "safed" and out.safed_reason == "stall"
    assert st.queue == () and st.active is None and np.all(out.twist == 0.0)
    for tick in range(2, 8):
        st, out = _step(st, up, tick)
    assert out.brake and out.mode == "safed"  # braked after brake_delay_s
    up.send(DriveCommand(5.0, vx_mps=0.3))  # ignored while safed: not acknowledged
    st, out = _step(st, up, 8)
    assert out.mode == "safed" and np.all(out.twist == 0.0) and st.ignored == 1
    assert st.motion_seq == 1 and st.last_seq == 2
    up.send(ResumeCommand(), DriveCommand(5.0, vx_mps=0.3))  # resume, then drive: one pass
    st, out = _step(st, up, 9)
    assert out.mode == "driving" and out.twist[0] == 0.3 and st.motion_seq == 4
    modes = [(m.before, m.after, m.reason) for m in st.transitions.items()]
    assert modes == [
        ("idle", "driving", ""),
        ("driving", "safed", "stall"),
        ("safed", "driving", ""),
    ]
    assert [m.t_s for m in st.transitions.items()] == [0.0, 0.1, 0.9]


def test_uplink_silence_safes_only_while_a_command_runs():
    up = Uplink()
    st, out = ExecutorState(), None
    for tick in range(0, 200):  # idle and silent for 20 s: nothing happens
        st, out = _step(st, up, tick, uplink_timeout_s=5.0)
    assert out.mode == "idle"
    up.send(DriveCommand(100.0, vx_mps=0.2))
    for tick in range(200, 251):
        st, out = _step(st, up, tick, uplink_timeout_s=5.0)
    assert out.mode == "driving"  # heard at tick 200; 5 s is 50 ticks
    st, out = _step(st, up, 251, uplink_timeout_s=5.0)
    assert out.mode == "safed" and out.safed_reason == "uplink_loss"
    up.send(Heartbeat())  # the link is back: a heartbeat alone does not resume
    st, out = _step(st, up, 252, uplink_timeout_s=5.0)
    assert out.mode == "safed"
    up.send(ResumeCommand())
    st, out = _step(st, up, 253, uplink_timeout_s=5.0)
    assert out.mode == "waiting"


def test_heartbeats_keep_a_long_drive_alive_and_mast_commands_hold_and_release():
    up = Uplink()
    up.send(DriveCommand(30.0, vx_mps=0.2), MastCommand(pan_rad=0.5, tilt_rad=0.2))
    st, out = _step(ExecutorState(), up, 0, uplink_timeout_s=5.0)
    assert out.mast == (0.5, 0.2)
    for tick in range(1, 300):
        if tick % 40 == 0:
            up.send(Heartbeat())
        st, out = _step(st, up, tick, uplink_timeout_s=5.0)
        assert out.mode == "driving", tick
    up.send(MastCommand(auto=True), StopCommand())
    st, out = _step(st, up, 300, uplink_timeout_s=5.0)
    assert out.mast is None and out.mode == "waiting"


# ----------------------------------------------------------------------- bumper core


def _bumper(n, dt=0.1, config=None, **kw):
    cfg = config or SafetyConfig()
    args = dict(driving=True, roll_rad=0.0, pitch_rad=0.0, wheel_rate_cmd=[1.0] * 4,
                wheel_rate_meas=[1.0] * 4, yaw_rate_encoders=0.0, yaw_rate_gyro=0.0,
                tilt_limit_rad=math.radians(20.0))  # fmt: skip
    args.update(kw)
    t, reasons = np.zeros(3), []
    for _ in range(n):
        t, r = bumper_step(t, dt_s=dt, config=cfg, **args)
        reasons.append(r)
    return reasons


def test_bumper_trips_on_each_condition_after_its_persistence_only_while_driving():
    cfg = SafetyConfig(tilt_persist_s=0.5, stall_persist_s=3.0, slip_persist_s=2.0)
    assert _bumper(50, config=cfg) == [""] * 50  # nominal
    r = _bumper(6, config=cfg, pitch_rad=math.radians(21.0))
    assert r == [""] * 4 + ["tilt"] * 2  # 0.5 s at 10 Hz
    r = _bumper(31, config=cfg, wheel_rate_meas=[0.2] * 4)  # < 25 % of the command
    assert r.index("stall") == 29
    assert _bumper(40, config=cfg, wheel_rate_meas=[0.3] * 4) == [""] * 40  # 30 %: turning
    r = _bumper(21, config=cfg, yaw_rate_encoders=0.0, yaw_rate_gyro=-0.15)  # spun round
    assert r.index("slip") == 19
    r = _bumper(21, config=cfg, yaw_rate_encoders=0.2, yaw_rate_gyro=-0.1)  # the wrong way
    assert r.index("slip") == 19
    # A skid-steer turn at a quarter of its kinematic rate: within the allowance.
    assert _bumper(40, config=cfg, yaw_rate_encoders=0.2, yaw_rate_gyro=0.05) == [""] * 40
    # Not driving: nothing trips, whatever the sensors say.
    assert _bumper(40, config=cfg, driving=False, pitch_rad=1.0) == [""] * 40
    # A condition must hold without a break.
    t = np.zeros(3)
    base = dict(dt_s=0.1, driving=True, roll_rad=0.0, wheel_rate_cmd=[1.0] * 4,
                wheel_rate_meas=[1.0] * 4, yaw_rate_encoders=0.0, yaw_rate_gyro=0.0,
                tilt_limit_rad=math.radians(20.0), config=cfg)  # fmt: skip
    for k in range(20):
        t, r = bumper_step(t, pitch_rad=1.0 if k % 4 else 0.0, **base)
        assert r == ""


def test_low_state_of_charge_trips_while_driving_only_and_not_without_a_sensor():
    cfg = SafetyConfig(min_soc=0.2)
    assert _bumper(3, config=cfg, soc=0.19) == ["low_soc"] * 3  # at once
    assert _bumper(3, config=cfg, soc=0.21) == [""] * 3
    assert _bumper(3, config=cfg, soc=math.nan) == [""] * 3  # no power sensor
    assert _bumper(3, config=cfg, soc=0.1, driving=False) == [""] * 3
    assert _bumper(3, config=SafetyConfig(min_soc=0.0), soc=0.01) == [""] * 3  # off
    # A condition with its persistence met comes first.
    assert _bumper(6, config=cfg, soc=0.1, pitch_rad=1.0)[-1] == "tilt"


def test_a_low_soc_safing_waits_for_the_charge_before_its_resume():
    from lunar_drake.autonomy.commands import SAFE_REASONS

    g = Ground(params=OperatorParams(resume_soc=0.5, heartbeat_s=5.0))
    g.tick(0.0, Request("goal", (10.0, 0.0)))
    low = SAFE_REASONS.index("low_soc")
    for t, soc in ((5.0, 0.19), (60.0, 0.35), (120.0, 0.49)):
        g.telemetry(t, xy=(2, 0), mode="safed", motion_seq=g.goto_seq(), changes=2,
                    reason=low, power=(soc, 150.0, 60.0))  # fmt: skip
        assert g.tick(t + 0.1) == [], t  # parked, charging
    g.telemetry(180.0, xy=(2, 0), mode="safed", motion_seq=g.goto_seq(), changes=2,
                reason=low, power=(0.51, 150.0, 60.0))  # fmt: skip
    out = g.tick(180.1)
    assert isinstance(out[0], ResumeCommand) and out[1].waypoints[0] == (2.0, 0.0)
    kinds = [e.kind for e in g.state.events.items()]
    assert kinds.count("charging") == 1 and kinds.count("resume") == 1


def test_safety_config_errors_name_the_field():
    from lunar_drake.errors import OutOfRangeError

    with pytest.raises(OutOfRangeError, match="stall_speed_fraction"):
        SafetyConfig(stall_speed_fraction=1.5).validate()
    with pytest.raises(OutOfRangeError, match="max_tilt_deg"):
        SafetyConfig(max_tilt_deg=0.0).validate()


# ----------------------------------------------------------------- ground operations


def test_ground_pose_carries_the_estimate_along_the_commanded_arc():
    """Against a fine Euler integration of the same body twist (its own quadrature)."""
    pose = [1.0, -2.0, 0.1, 0.01, 0.02, 0.7]
    for vx, vy, wz in ((0.2, 0.0, 0.0), (0.2, 0.05, 0.03), (0.0, 0.0, -0.2)):
        packet = pack_telemetry(pose_estimate=pose, twist_command=[vx, vy, wz], brake=0,
                                status=[1, 0, 0, 1, 0])  # fmt: skip
        got = ground_pose(packet, 10.0, 16.0, max_extrapolation_s=100.0)
        x, y, yaw = pose[0], pose[1], pose[5]
        n = 60000
        dt = 6.0 / n
        for _ in range(n):
            x += (vx * math.cos(yaw) - vy * math.sin(yaw)) * dt
            y += (vx * math.sin(yaw) + vy * math.cos(yaw)) * dt
            yaw += wz * dt
        np.testing.assert_allclose(got[:2], [x, y], atol=1e-4)
        assert math.isclose(got[5], (yaw + math.pi) % (2 * math.pi) - math.pi, abs_tol=1e-9)
        np.testing.assert_array_equal(got[2:5], pose[2:5])
    capped = ground_pose(packet, 10.0, 1000.0, max_extrapolation_s=5.0)
    np.testing.assert_allclose(capped, ground_pose(packet, 10.0, 15.0, max_extrapolation_s=9.0))
    braked = pack_telemetry(pose_estimate=pose, twist_command=[0.2, 0, 0], brake=1,
                            status=[2, 0, 0, 2, 0])  # fmt: skip
    np.testing.assert_array_equal(ground_pose(braked, 0.0, 5.0, max_extrapolation_s=9.0), pose)


def test_distance_to_path_matches_dense_sampling():
    rng = np.random.default_rng(3)
    path = rng.uniform(-10, 10, (6, 2))
    dense = np.concatenate([np.linspace(a, b, 20001) for a, b in itertools.pairwise(path)])
    for p in rng.uniform(-12, 12, (20, 2)):
        ref = np.min(np.hypot(*(dense - p).T))
        assert distance_to_path(p, path) == pytest.approx(ref, abs=2e-3)


class Ground:
    """Drives operator_step with fabricated telemetry and a straight-line planner."""

    def __init__(self, params=None, fail_goals=()):
        self.params = params or OperatorParams(heartbeat_s=5.0, ack_timeout_s=20.0)
        self.state = OperatorState()
        self.tel_seq = 0
        self.inbox = ()
        self.sent = []
        self.fail = set(fail_goals)

    def planner(self, start, goal):
        from lunar_drake.autonomy.planner import PlanningError

        if tuple(goal) in self.fail:
            raise PlanningError(f"goal {goal} is inside a hazard")
        return [tuple(start), tuple(goal)]

    def telemetry(self, t, *, xy, mode, command_seq=None, motion_seq=-1, changes=0,
                  reason=0, twist=(0, 0, 0), brake=1, power=None, latency=0.0):  # fmt: skip
        from lunar_drake.autonomy.commands import MODES

        cs = max(motion_seq, 0) if command_seq is None else command_seq
        status = [MODES.index(mode), cs, reason, changes, motion_seq]
        packet = pack_telemetry(pose_estimate=[xy[0], xy[1], 0, 0, 0, 0], twist_command=twist,
                                brake=brake, status=status, power=power)  # fmt: skip
        self.inbox += (Delivery(Message("telemetry", self.tel_seq, t - latency, packet, 0), t),)
        self.tel_seq += 1

    def tick(self, t, *requests, heartbeats=False, **kw):
        """The commands sent at ``t`` (heartbeats left out unless asked for)."""
        self.state = operator_step(self.state, self.inbox, now=t, params=self.params,
                                   planner=self.planner, start_pose=(0.0, 0.0, 0.0),
                                   requests=requests, **kw)  # fmt: skip
        self.sent += [(t, m.seq, m.payload) for m in self.state.outbox]
        out = [m.payload for m in self.state.outbox]
        return out if heartbeats else [c for c in out if not isinstance(c, Heartbeat)]

    def goto_seq(self):
        return self.state.goto_seq


def test_goals_are_planned_from_the_estimate_judged_on_telemetry_and_replanned():
    g = Ground()
    out = g.tick(0.0, Request("goal", (10.0, 0.0)), Request("goal", (10.0, 10.0)))
    (goto,) = out
    assert isinstance(goto, GotoCommand) and goto.waypoints == ((0.0, 0.0), (10.0, 0.0))
    assert g.state.status == ("active", "pending")
    # Telemetry from before the goto arrived says waiting: not taken as done.
    g.telemetry(1.0, xy=(0, 0), mode="waiting")
    assert g.tick(1.0) == []
    # The rover drives (acknowledged), then stops 3 m short (timeout): replan from there.
    g.telemetry(3.0, xy=(1, 0), mode="driving", motion_seq=g.goto_seq(), brake=0,
                twist=(0.2, 0, 0))  # fmt: skip
    assert g.tick(3.1) == []
    g.telemetry(40.0, xy=(7.0, 0.5), mode="waiting", motion_seq=g.goto_seq())
    (replan,) = g.tick(40.1)
    assert replan.waypoints == ((7.0, 0.5), (10.0, 0.0)) and g.state.replans == 1
    # Arrived (estimate within goal_tolerance_m): the next goal is planned from there.
    g.telemetry(60.0, xy=(9.8, 0.1), mode="waiting", motion_seq=g.goto_seq())
    (nxt,) = g.tick(60.1)
    assert nxt.waypoints == ((9.8, 0.1), (10.0, 10.0))
    assert g.state.status == ("reached", "active") and g.state.replans == 0
    kinds = [e.kind for e in g.state.events.items()]
    assert kinds == ["goal", "goal", "plan", "plan", "goal_reached", "plan"]


@pytest.mark.parametrize("sigma, reached", [(0.0, True), (0.2, True), (0.5, False)])
def test_a_goal_is_judged_with_the_estimates_own_sigma(sigma, reached):
    """The rover parks with the estimate 0.7 m from the goal: reached while the
    tolerance (1 m) less the estimate's sigma still covers it, else a final approach
    from the estimate; the radius never drops below the on-board tolerance + 0.1 m."""
    p = OperatorParams()
    assert reach_radius_m(p, sigma) == pytest.approx(max(1.0 - sigma, p.goto_tolerance_m + 0.1))
    assert reach_radius_m(p, 5.0) == pytest.approx(p.goto_tolerance_m + 0.1)
    g = Ground()
    g.tick(0.0, Request("goal", (10.0, 0.0)), sigma_m=sigma)
    g.telemetry(30.0, xy=(9.3, 0.0), mode="waiting", motion_seq=g.goto_seq())
    out = g.tick(30.1, sigma_m=sigma)
    if reached:
        assert g.state.status == ("reached",) and out == []
    else:
        (approach,) = out
        assert approach.waypoints == ((9.3, 0.0), (10.0, 0.0))
        assert g.state.status == ("active",) and g.state.replans == 1


def test_a_final_approach_is_not_asked_for_when_it_cannot_help():
    """Within goal_tolerance_m but outside the sigma-shrunk radius: a goal the planner
    moved off a hazard (the path ends 0.5 m short of it) is reached once the rover stands
    at the path's end, and any goal is reached once the replans are spent. The radius
    stays within goal_tolerance_m and treats a NaN sigma as 0."""
    p = OperatorParams()
    assert reach_radius_m(p, math.nan) == pytest.approx(1.0)
    assert reach_radius_m(OperatorParams(goal_tolerance_m=0.25, goto_tolerance_m=0.2), 0.0) == 0.25
    g = Ground()
    g.planner = lambda start, goal: [tuple(start), (goal[0] - 0.5, goal[1])]
    g.tick(0.0, Request("goal", (10.0, 0.0)), sigma_m=0.6)
    g.telemetry(30.0, xy=(9.45, 0.0), mode="waiting", motion_seq=g.goto_seq())
    assert g.tick(30.1, sigma_m=0.6) == [] and g.state.status == ("reached",)
    g = Ground(params=OperatorParams(max_replans=0))
    g.tick(0.0, Request("goal", (10.0, 0.0)), sigma_m=0.6)
    g.telemetry(30.0, xy=(9.2, 0.0), mode="waiting", motion_seq=g.goto_seq())
    assert g.tick(30.1, sigma_m=0.6) == [] and g.state.status == ("reached",)


def test_a_goal_fails_after_max_replans_or_when_the_planner_refuses_it():
    g = Ground(params=OperatorParams(max_replans=2), fail_goals={(5.0, 5.0)})
    g.tick(0.0, Request("goal", (10.0, 0.0)), Request("goal", (5.0, 5.0)),
           Request("goal", (0.0, 10.0)))  # fmt: skip
    for k in range(3):
        g.telemetry(10.0 * (k + 1), xy=(2, 0), mode="waiting", motion_seq=g.goto_seq())
        g.tick(10.0 * (k + 1) + 0.1)
    # Given up on goal 0; goal 1 refused by the planner; goal 2 is being driven.
    assert g.state.status == ("failed", "failed", "active")
    details = [e.detail for e in g.state.events.items() if e.kind == "goal_failed"]
    assert "after 2 replans" in details[0] and "inside a hazard" in details[1]


def test_a_safed_rover_is_resumed_and_replanned_and_lost_commands_are_resent():
    g = Ground(params=OperatorParams(max_resumes=1, ack_timeout_s=20.0, heartbeat_s=5.0,
                                     max_resends=3))  # fmt: skip
    g.tick(0.0, Request("goal", (10.0, 0.0)))
    first = g.goto_seq()
    g.telemetry(5.0, xy=(1, 0), mode="safed", motion_seq=first, changes=2, reason=1)
    out = g.tick(5.1)
    assert isinstance(out[0], ResumeCommand) and isinstance(out[1], GotoCommand)
    assert out[1].waypoints[0] == (1.0, 0.0)
    # The same safing seen again (the resume is still on its way): nothing new.
    g.telemetry(6.0, xy=(1, 0), mode="safed", motion_seq=first, changes=2, reason=1)
    assert g.tick(6.1) == []
    # Neither acknowledged (lost on the way up): after the timeout the resume goes again,
    # then a stop (a stale copy may yet run) and the replanned goto.
    g.telemetry(20.0, xy=(1, 0), mode="safed", motion_seq=first, changes=2, reason=1)
    assert g.tick(20.0) == []
    out = g.tick(25.2)
    assert [type(c) for c in out] == [ResumeCommand, StopCommand, GotoCommand]
    # A second safing: max_resumes (1) is spent: the ground leaves it to a person, and
    # resends nothing to a rover that would ignore it.
    g.telemetry(40.0, xy=(3, 0), mode="safed", motion_seq=g.goto_seq(), changes=4, reason=2)
    assert g.tick(40.1) == []
    assert g.tick(70.0) == [] and g.tick(100.0) == []
    kinds = [e.kind for e in g.state.events.items()]
    assert kinds.count("safed") == 2 and kinds.count("resume") == 2  # auto, sent again
    out = g.tick(101.0, Request("resume"))  # the operator's own resume replans
    assert isinstance(out[0], ResumeCommand) and out[1].waypoints[0] == (3.0, 0.0)
    # That resume is lost too: sent again every ack_timeout_s, max_resends (3) times.
    g.telemetry(130.0, xy=(3, 0), mode="safed", motion_seq=first, changes=4, reason=2)
    again = [t for t in np.arange(130.0, 400.0, 0.5)
             if ResumeCommand() in g.tick(float(t))]  # fmt: skip
    assert len(again) == 3 and np.all(np.diff(again) > 20.0)


def test_a_goto_never_acknowledged_fails_its_goal_after_max_resends():
    """An uplink that drops every goto (too big for its bucket): stop and resend,
    max_resends times, then the goal fails and the next one starts."""
    g = Ground(params=OperatorParams(ack_timeout_s=10.0, max_resends=2, heartbeat_s=5.0))
    g.tick(0.0, Request("goal", (10.0, 0.0)), Request("goal", (0.0, 10.0)))
    g.telemetry(1.0, xy=(0, 0), mode="idle")
    for t in np.arange(1.0, 35.0, 0.5):  # no acknowledgement at 10.5, 21, 31.5 s
        g.tick(float(t))
    kinds = [e.kind for e in g.state.events.items()]
    assert kinds.count("no_ack") == 3
    assert g.state.status == ("failed", "active")
    assert "not acknowledged after 2 resends" in next(
        e.detail for e in g.state.events.items() if e.kind == "goal_failed"
    )


def test_the_acknowledgement_timeout_waits_for_the_round_trip():
    """A 10 s one-way delay: telemetry arrives 10 s old, so a goto's acknowledgement
    cannot come back before 20 s plus the telemetry period; the ground waits
    ack_timeout_s plus twice the measured latency before taking the goto as lost."""
    g = Ground(params=OperatorParams(ack_timeout_s=20.0, heartbeat_s=5.0, max_resends=3))
    g.tick(0.0, Request("goal", (10.0, 0.0)))
    for t in np.arange(10.0, 40.0, 1.0):  # the rover idle, the goto not yet there
        g.telemetry(float(t), xy=(0, 0), mode="idle", latency=10.0)
        assert g.tick(float(t) + 0.05) == [], t
    g.telemetry(40.0, xy=(0, 0), mode="idle", latency=10.0)
    out = g.tick(40.1)  # 20 s + 2 x 10 s: now it is lost
    assert [type(c) for c in out] == [StopCommand, GotoCommand]


def test_stop_pauses_goals_resume_replans_and_deviation_replans():
    g = Ground(params=OperatorParams(replan_deviation_m=2.0, heartbeat_s=5.0))
    g.tick(0.0, Request("goal", (20.0, 0.0)))
    g.telemetry(5.0, xy=(3.0, 2.5), mode="driving", motion_seq=g.goto_seq(), brake=0,
                twist=(0.0, 0.0, 0.0))  # fmt: skip
    out = g.tick(5.1)
    assert isinstance(out[0], StopCommand) and out[1].waypoints[0] == (3.0, 2.5)
    out = g.tick(6.0, Request("stop"))
    assert isinstance(out[0], StopCommand) and len(out) == 1 and g.state.paused
    assert g.tick(30.0) == []  # paused: no goto, only heartbeats
    out = g.tick(40.0, Request("resume"))
    assert isinstance(out[0], ResumeCommand) and isinstance(out[1], GotoCommand)
    out = g.tick(41.0, Request("drive_arc", (-0.1, 0.5, 0.4)), Request("point_mast", (0.3, 0.1)))
    arc, mast = out
    assert arc == DriveCommand(duration_s=4.0, vx_mps=-0.1, wz_radps=-0.05)
    assert mast == MastCommand(pan_rad=0.3, tilt_rad=0.1)


def test_a_new_hazard_on_the_path_stops_and_replans_once_per_map_version():
    g = Ground(params=OperatorParams(max_replans=1, heartbeat_s=5.0))
    g.tick(0.0, Request("goal", (20.0, 0.0)))
    g.telemetry(5.0, xy=(3.0, 0.0), mode="driving", motion_seq=g.goto_seq(), brake=0,
                twist=(0.2, 0.0, 0.0))  # fmt: skip
    checked = []

    def blocked(path, xy):
        checked.append(tuple(xy))
        return True

    assert g.tick(5.1, map_version=0, blocked=blocked) == []  # the version it started with
    assert checked == []
    out = g.tick(5.2, map_version=1, blocked=blocked)
    assert isinstance(out[0], StopCommand)
    assert out[1].waypoints[0] == pytest.approx((3.04, 0.0))  # carried 0.2 s at 0.2 m/s
    assert g.state.replans == 0  # not counted against max_replans
    assert "a new hazard" in g.state.events.items()[-1].detail
    # Same version again: not checked; a new version whose hazard is off the path: no replan.
    g.telemetry(6.0, xy=(3.1, 0.0), mode="driving", motion_seq=g.goto_seq(), brake=0,
                twist=(0.2, 0.0, 0.0))  # fmt: skip
    assert g.tick(6.1, map_version=1, blocked=blocked) == [] and len(checked) == 1
    assert g.tick(6.2, map_version=2, blocked=lambda path, xy: False) == []


def test_the_pose_correction_moves_the_estimate_the_ground_plans_from():
    """The ground plans in its own (VO-corrected) frame from its corrected estimate and
    sends the waypoints up in the rover's on-board frame (where its follower works):
    the rover, at (2, 1) by its own estimate, is sent from there to the goal's place in
    its frame; the ground keeps the plan in its frame."""
    g = Ground()
    g.telemetry(1.0, xy=(2.0, 1.0), mode="idle")
    (goto,) = g.tick(1.1, Request("goal", (10.0, 0.0)), correction=(0.5, -0.25, 0.0))
    assert np.allclose(g.state.path, ((2.5, 0.75), (10.0, 0.0)), atol=1e-12)
    assert np.allclose(goto.waypoints, ((2.0, 1.0), (9.5, 0.25)), atol=1e-12)
    # with a rotation: p_ground = Rz(a) p_onboard + d, inverted here with a matrix
    a, d = 0.3, np.array([1.0, -2.0])
    g = Ground()
    g.telemetry(1.0, xy=(2.0, 1.0), mode="idle")
    (goto,) = g.tick(1.1, Request("goal", (10.0, 0.0)), correction=(*d, a))
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    expect = [np.linalg.solve(R, np.array(p) - d) for p in g.state.path]
    assert np.allclose(goto.waypoints, expect, atol=1e-12)
    assert np.allclose(goto.waypoints[0], (2.0, 1.0), atol=1e-12)  # where the rover is


def test_the_command_preview_of_each_goto_is_kept_with_its_seq():
    from lunar_drake.autonomy.preview import preview_goto

    g = Ground()

    def preview(pose, wp):
        return preview_goto(pose=(pose[0], pose[1], pose[5]), waypoints=wp, speed_mps=0.2,
                            tolerance_m=0.2, rate_hz=10.0)  # fmt: skip

    g.tick(0.0, Request("goal", (5.0, 0.0)), preview=preview)
    seq, path = g.state.preview
    assert seq == g.goto_seq() and path[-1, 1] == pytest.approx(5.0, abs=0.2)


def test_heartbeats_fill_the_silence():
    g = Ground(params=OperatorParams(heartbeat_s=5.0))
    sent = [t for t in np.arange(0.0, 30.0, 0.1) if g.tick(float(round(t, 1)), heartbeats=True)]
    assert sent == pytest.approx([0.0, 5.0, 10.0, 15.0, 20.0, 25.0])


def test_telemetry_fields_carry_the_executor_status():
    p = pack_telemetry(pose_estimate=np.arange(6), twist_command=[1, 2, 3], brake=1,
                       status=[3, 7, 4, 9, 5])  # fmt: skip
    f = dict(zip(TELEMETRY_FIELDS, p, strict=True))
    assert (f["mode"], f["command_seq"], f["safe_reason"], f["mode_changes"], f["motion_seq"]) == (
        3, 7, 4, 9, 5)  # fmt: skip


# ------------------------------------------------------------------- short missions


#: These missions test the link and the mode manager, not mapping: cameras off and the
#: ground on the true map (the oracle).
ORACLE_MAP = "{sensors: {camera: {enabled: false}}, ground: {map: {source: truth}}}"


def _goto_mission(cache_text):
    from lunar_drake import metrics
    from lunar_drake.scenario_files import apply_overrides, load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name="goto", scenario_text=cache_text)
    scenario = apply_overrides(scenario, ORACLE_MAP, source="the test's oracle map")
    site = load_site(scenario, progress=False)
    logs = simulate(scenario=scenario, site=site, progress=False)
    return logs, metrics.summarize(scenario=scenario, site=site, logs=logs)


def test_uplink_outage_safes_the_rover_and_the_ground_recovers_it(cache):
    """The uplink is down from 10 s to 40 s: after 5 s of silence (heartbeats every 2 s
    before it) the rover safes; the
    ground, seeing it, resumes and replans (lost on the way up, then resent after the
    outage) and the goal is reached."""
    logs, summary = _goto_mission(
        "{simulation_duration: 160, flight: {safety: {uplink_timeout_s: 5}},"
        " ground: {heartbeat_s: 2}, comms: {uplink: {outages: [{start_s: 10, end_s: 40}]}}}"
    )
    modes = summary["modes"]
    assert modes["safings"] == {"uplink_loss": 1}
    safed = next(m for m in modes["transitions"] if m["after"] == "safed")
    heartbeat_before = max(r.t_received for r in logs.link
                           if r.direction == "uplink" and r.t_sent < 10.0)  # fmt: skip
    assert safed["t_s"] == pytest.approx(heartbeat_before + 5.0, abs=0.1)
    kinds = [e.kind for e in logs.ground_events]
    assert "safed" in kinds and "no_ack" in kinds and kinds[-1] == "goal_reached"
    assert summary["goals"][0]["reached"] and summary["hazards"]["strikes"] == 0
    dropped = [r for r in logs.link if r.dropped]
    assert dropped and all(10.0 <= r.t_sent < 40.0 and r.reason == "outage" for r in dropped)


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("{rover: {description: {drive_effort_limit_nm: 0.3}}}", "stall"),
        ("{flight: {safety: {max_tilt_deg: 0.3}}}", "tilt"),
    ],
)
def test_the_virtual_bumper_safes_a_stalled_or_tilted_rover(cache, text, reason):
    """Motors too weak to turn the wheels: stall; a tilt limit below the terrain's
    slopes: tilt. The ground resumes it max_resumes (1) times, then leaves it safed."""
    base = "{simulation_duration: 30, ground: {max_resumes: 1}}"
    logs, summary = _goto_mission(base[:-1] + ", " + text[1:])
    assert summary["modes"]["safings"] == {reason: 2}
    assert summary["ground"]["resumes"] == 1 and summary["ground"]["safings_seen"] == 2
    status = logs.vectors["flight.status"]
    assert status.column("mode")[-1] == 3  # safed at the end
    assert logs.vectors["flight.brake_command"].data[-1, 0] == 1.0
    assert summary["hazards"]["strikes"] == 0


def test_a_flat_battery_safes_the_rover_and_the_ground_waits_for_the_charge(cache):
    """A battery at its floor (a tiny pack and a near-dead array): the first drive trips
    low_soc at once; the ground parks the rover to charge instead of resuming it, and
    telemetry carries the state of charge down."""
    text = ("{simulation_duration: 30, power: {battery: {capacity_Wh: 0.5, initial_soc: 0.2005},"
            " array: {cell_efficiency: 0.001}}}")  # fmt: skip
    logs, summary = _goto_mission(text)
    assert summary["modes"]["safings"] == {"low_soc": 1}
    assert summary["ground"]["resumes"] == 0 and summary["ground"]["safings_seen"] == 1
    kinds = [e.kind for e in logs.ground_events]
    assert "charging" in kinds and "resume" not in kinds
    assert logs.vectors["flight.status"].column("mode")[-1] == 3  # still safed
    soc = logs.telemetry.packets[:, logs.telemetry.columns.index("soc")]
    assert 0.0 <= soc.min() < 0.2 and soc[0] == pytest.approx(0.2005, abs=1e-3)


def test_the_operator_api_drives_the_mission_between_advances(cache):
    """send_goal / stop / resume / drive_arc / point_mast from Python, between
    AdvanceTo calls, each going up the link as a command."""
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram, ground_operator
    from lunar_drake.errors import OutOfBoundsError, OutOfRangeError
    from lunar_drake.scenario_files import apply_overrides, load_scenario
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name="goto", scenario_text="{ground: {goals: []}}")
    scenario = apply_overrides(scenario, ORACLE_MAP, source="the test's oracle map")
    scenario.ground.route = []
    site = load_site(scenario, progress=False)
    mission = MakeMissionDiagram(scenario=scenario, site=site)
    sim = Simulator(mission)
    root = sim.get_mutable_context()
    ops = ground_operator(mission)
    pose = mission.GetOutputPort("truth.pose")
    ctx = mission.GetMyContextFromRoot(root)
    sim.AdvanceTo(2.0)
    with pytest.raises(OutOfBoundsError, match="off the ground's map"):
        ops.send_goal(root, x_m=500.0, y_m=0.0)
    with pytest.raises(OutOfRangeError, match="speed_mps"):
        ops.drive_arc(root, speed_mps=0.0, distance_m=1.0)
    x0 = pose.Eval(ctx)[0]
    ops.send_goal(root, x_m=2.0, y_m=0.0)
    sim.AdvanceTo(20.0)
    ops.stop(root)
    sim.AdvanceTo(25.0)
    x_stop = pose.Eval(ctx)[0]
    assert x_stop > x0 + 1.0  # it drove towards the goal
    sim.AdvanceTo(35.0)
    assert abs(pose.Eval(ctx)[0] - x_stop) < 0.05  # and stopped
    ops.point_mast(root, pan_rad=0.4, tilt_rad=0.3)
    ops.resume(root)
    sim.AdvanceTo(80.0)
    st = ops.operator_state(root)
    assert st.status == ("reached",)
    assert math.hypot(pose.Eval(ctx)[0] - 2.0, pose.Eval(ctx)[1]) < 1.0
    flight = mission.GetSubsystemByName("flight")
    gimbal = flight.GetOutputPort("rover.gimbal_command").Eval(flight.GetMyContextFromRoot(root))
    np.testing.assert_allclose(gimbal, [0.4, 0.3])  # the mast command reached the gimbal
    ops.drive_arc(root, speed_mps=-0.1, curvature_per_m=0.0, distance_m=0.5)
    x_before = pose.Eval(ctx)[0]
    sim.AdvanceTo(95.0)
    assert pose.Eval(ctx)[0] < x_before - 0.3  # backed up
    kinds = [e.kind for e in st.events.items()]
    assert kinds[:2] == ["goal", "plan"] and "stop" in kinds and "resume" in kinds


def test_a_safed_rover_with_no_resumes_left_is_left_to_the_operator():
    g = Ground(params=OperatorParams(max_resumes=0, ack_timeout_s=20.0, heartbeat_s=5.0))
    g.tick(0.0, Request("goal", (10.0, 0.0)))
    g.telemetry(5.0, xy=(0, 0), mode="safed", motion_seq=-1, changes=2, reason=4)
    assert g.tick(5.1) == []
    assert g.tick(20.5) == [] and g.tick(60.0) == [] and g.tick(200.0) == []
    kinds = [e.kind for e in g.state.events.items()]
    assert kinds.count("no_ack") == 1 and kinds.count("left_safed") == 1
    assert [e.detail for e in g.state.events.items() if e.kind == "safed"] == ["uplink_loss"]


def test_the_ground_settings_come_from_the_scenario_field_by_field():
    """Every OperatorParams field is the GroundConfig field of that name (OneOfEverything
    sets each to a non-default value, so a field dropped on the way would show)."""
    import dataclasses as dc

    from lunar_drake.diagrams.ground import operator_params
    from lunar_drake.scenario_files import load_scenario

    s = load_scenario(scenario_name="OneOfEverything")
    got = operator_params(s)
    for f in dc.fields(OperatorParams):
        assert getattr(got, f.name) == getattr(s.ground, f.name), f.name
        assert getattr(got, f.name) != f.default, f.name
