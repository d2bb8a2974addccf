"""Mission control: the telemetry dictionary and store, commands, the aiohttp server
(history, realtime WebSocket, bad requests, vanishing clients, binding), the live
observer in a real mission (a command from the network is driven and ``scenario.yaml``
reproduces it) and ``run.mcap``."""

import asyncio
import json
import math
import queue

import numpy as np
import pytest

from lunar_drake.autonomy.commands import MODES, SAFE_REASONS
from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS
from lunar_drake.mission_control import dictionary as dic
from lunar_drake.mission_control.commands import CommandError, as_action, parse_command
from lunar_drake.mission_control.server import BindError, MissionControl, check_host, make_app
from lunar_drake.mission_control.store import TelemetryStore, UnknownPointError


def _packet(**kw):
    p = np.zeros(len(TELEMETRY_FIELDS))
    p[TELEMETRY_FIELDS.index("soc")] = math.nan
    p[TELEMETRY_FIELDS.index("array_W")] = math.nan
    for k, v in kw.items():
        p[TELEMETRY_FIELDS.index(k)] = v
    return p


# ------------------------------------------------------------------ dictionary, store


def _items(conv, **kw):
    return [(k, v) for k, _, v in conv.packet(**kw)]


def test_converter_derives_speed_slip_losses_and_cautions_from_received_packets():
    conv = dic.Converter(telemetry_period_s=1.0, min_soc=0.2)
    a = dict(_items(conv, seq=0, t_sent=10.0, t_received=11.3,
                               packet=_packet(x_m=1.0, vx_cmd_mps=0.2, soc=0.5)))  # fmt: skip
    assert a["link.delay"] == pytest.approx(1.3)
    assert a["rover.soc"] == pytest.approx(50.0) and a["cw.low_soc"] == 0
    assert "rover.speed" not in a  # no packet before it
    # seq 1 lost; seq 2 two seconds later, 0.3 m on: no speed across a gap
    b = dict(_items(conv, seq=2, t_sent=12.0, t_received=13.3,
                               packet=_packet(x_m=1.3, vx_cmd_mps=0.2, soc=0.1)))  # fmt: skip
    assert b["link.lost"] == 1 and "rover.speed" not in b and b["cw.low_soc"] == 1
    # seq 3 one second later, 0.15 m on at 0.2 m/s commanded: 25 % slip
    c = dict(_items(conv, seq=3, t_sent=13.0, t_received=14.3,
                               packet=_packet(x_m=1.45, vx_cmd_mps=0.2,
                                              mode=MODES.index("safed"),
                                              safe_reason=SAFE_REASONS.index("uplink_loss"))))
    assert c["rover.speed"] == pytest.approx(0.15) and c["rover.slip"] == pytest.approx(25.0)
    assert c["cw.safed"] == 1 and c["cw.uplink_loss"] == 1 and c["link.received"] == 3
    assert conv.tick(now_s=16.0, last_received_s=14.3) == []  # 1.7 s: fine
    assert conv.tick(now_s=17.5, last_received_s=14.3) == [("cw.loss_of_signal", 17.5, 1)]
    assert conv.tick(now_s=18.0, last_received_s=14.3) == []  # raised once
    d = dict(_items(conv, seq=4, t_sent=17.0, t_received=18.3, packet=_packet(x_m=1.45)))
    assert d["cw.loss_of_signal"] == 0


def test_every_datum_has_a_dictionary_point_and_units():
    conv = dic.Converter()
    keys = {k for k, _, _ in conv.packet(seq=0, t_sent=0.0, t_received=1.0,
                                         packet=_packet(soc=0.9, array_W=100.0))}  # fmt: skip
    keys |= {k for k, _, _ in conv.packet(seq=1, t_sent=1.0, t_received=2.0,
                                          packet=_packet(x_m=0.2, vx_cmd_mps=0.2))}  # fmt: skip
    keys |= {k for k, _, _ in conv.packet(seq=2, t_sent=2.0, t_received=3.0,
                                          packet=_packet(x_m=0.35, vx_cmd_mps=0.2))}  # fmt: skip
    assert keys == dic.PACKET_KEYS | {"cw.safed", "cw.uplink_loss", "cw.low_soc"}
    keys |= {k for k, _, _ in dic.ground_pose_datums(1.0, [0, 0, 0, 0, 0, 0.1])}
    assert keys <= set(dic.BY_KEY)
    assert all(p.units or p.format in ("enum", "int", "string") for p in dic.POINTS)


def test_operator_and_keyframe_datums_follow_the_ground_state():
    import types

    from lunar_drake.perception.ground_pipeline import KeyframeRecord

    ops = types.SimpleNamespace(active=0, replans=1, resends=0, resumes=2, next_seq=5,
                                packet=_packet(command_seq=2), t_received=9.0,
                                goals=((3.0, 4.0), (9.0, 9.0)),
                                path=((0.0, 0.0), (3.0, 0.0), (3.0, 4.0)))  # fmt: skip
    d = {k: v for k, _, v in dic.operator_datums(10.0, ops, (0.0, 0.0, 0.0, 0, 0, 0))}
    assert d["ground.active_goal"] == 1 and d["ground.replans"] == 1
    assert d["ground.auto_resumes"] == 2 and d["link.commands_sent"] == 5
    assert d["link.uplink_queue"] == 2  # seqs 3 and 4 not handled yet
    assert d["link.packet_age"] == pytest.approx(1.0)
    assert d["ground.goal_distance"] == pytest.approx(5.0)
    assert d["ground.plan_left"] == pytest.approx(7.0)  # 3 m east, then 4 m north
    ops.active, ops.path, ops.packet = -1, (), None
    d = {k: v for k, _, v in dic.operator_datums(10.0, ops, (0.0, 0.0, 0.0, 0, 0, 0))}
    assert d["ground.active_goal"] == 0 and d["link.uplink_queue"] == 5
    assert "ground.goal_distance" not in d and "ground.plan_left" not in d

    def rec(vo, lethal):
        nan = math.nan
        return KeyframeRecord(1.0, 1, 10, vo, "", nan, nan, nan, nan, nan, nan, 0.0, 0.0,
                              0.0, 0.1, lethal)  # fmt: skip

    kc = dic.KeyframeCounter()
    kc.datums(1.0, [rec("none", 3)], sigma_m=0.0, version=1)
    d = {k: v for k, _, v in kc.datums(2.0, [rec("accepted", 0), rec("gated", 2),
                                             rec("rejected", 0)], sigma_m=0.2, version=2)}
    assert (d["ground.keyframes"], d["ground.vo_accepted"], d["ground.vo_rejected"],
            d["ground.stereo_lethal"], d["ground.map_version"]) == (4, 1, 2, 5, 2)
    assert d["ground.sigma"] == 0.2


def test_the_earth_is_predicted_behind_a_ridge_of_the_ground_map(cache):
    """A ring ridge 10 m high, 49-51 m from the rover, on a flat map: the horizon rises
    to atan((10 - 1) / 49) = 10.4 deg (antenna 1 m up) in every azimuth, so the
    predicted margin is the Earth's elevation less that; the flat map's horizon sits
    at its edge, 0.4-0.6 deg below the level (the antenna's 1 m over 100-141 m)."""
    import types

    from lunar_drake.mission_control.sky import SkyPrediction
    from lunar_drake.scenario_files import load_scenario

    sc = load_scenario(scenario_name="goto")
    res, n = 0.5, 400  # 200 m square, centred on the rover
    xs = (np.arange(n) + 0.5) * res - 100.0
    r = np.hypot(*np.meshgrid(xs, xs))
    flat = np.zeros((n, n))
    ridge = np.where((r >= 49.0) & (r <= 51.0), 10.0, 0.0)

    def margin(z, pose=(0.0, 0.0)):
        mp = types.SimpleNamespace(z=z, resolution_m=res, x0_m=-100.0, y1_m=100.0)
        d = {k: v for k, _, v in SkyPrediction(scenario=sc, map_product=mp).datums(0.0, pose)}
        return d

    d = margin(ridge)
    el = d["sky.earth_elevation"]
    assert d["sky.earth_margin"] == pytest.approx(el - math.degrees(math.atan(9.0 / 49.0)),
                                                  abs=0.15)  # fmt: skip
    assert d["cw.earth_below_horizon"] == int(d["sky.earth_margin"] <= 0.0)
    flat_margin = margin(flat)["sky.earth_margin"]
    assert el + 0.39 < flat_margin < el + 0.6
    assert "sky.earth_margin" not in margin(flat, pose=(500.0, 0.0))  # off the map


def test_science_records_become_datums_and_heat_samples_at_the_estimate():
    from lunar_drake.comms.science import ScienceRecord
    from lunar_drake.science.nirvss import BANDS
    from lunar_drake.science.nss import NSSConfig

    pose = (2.0, -1.0, 0.0, 0.0, 0.0, 0.3)
    bands = [0.0] * len(BANDS)
    bands[BANDS.index("ice")], bands[BANDS.index("oh")] = 0.05, 0.02
    nir = ScienceRecord("nirvss", 3, 10.0, (*bands, 110.0), 0.0, pose)
    datums, heat = dic.science_datums(12.5, nir)
    assert dict((k, v) for k, _, v in datums) == {"nirvss.ice": 0.05, "nirvss.oh": 0.02,
                                                  "lcs.temperature": 110.0}  # fmt: skip
    assert heat == {"nirvss_ice": (2.0, -1.0, 0.05), "lcs_temperature": (2.0, -1.0, 110.0)}
    cfg = NSSConfig()
    dry = cfg.epithermal_dry_cps * 10.0  # counts of dry regolith over 10 s: 0 wt%
    nss = ScienceRecord("nss", 1, 10.0, (dry, 5.0), 10.0, pose)
    datums, heat = dic.science_datums(12.5, nss, nss_config=cfg)
    assert dict((k, v) for k, _, v in datums)["nss.weh"] == pytest.approx(0.0, abs=1e-9)
    assert heat["nss_weh"][:2] == (2.0, -1.0) and set(heat) <= set(dic.HEAT_LAYERS)


def test_store_history_is_inclusive_ordered_and_refuses_unknown_keys():
    s = TelemetryStore()
    got = []
    s.listeners.append(got.extend)
    s.add([("rover.x", 2.0, 2.0), ("rover.x", 1.0, 1.0), ("rover.x", 3.0, 3.0),
           ("no.such", 1.0, 0.0), ("rover.y", 1.0, math.nan)])  # fmt: skip
    assert s.history("rover.x") == [(1.0, 1.0), (2.0, 2.0), (3.0, 3.0)]
    assert s.history("rover.x", start_s=2.0, end_s=3.0) == [(2.0, 2.0), (3.0, 3.0)]
    assert s.history("rover.y") == [] and len(got) == 3  # the unknown key and NaN dropped
    with pytest.raises(UnknownPointError, match=r"no\.such"):
        s.history("no.such")


def test_commands_are_checked_with_one_line_each():
    assert parse_command({"action": "goal", "x_m": 1, "y_m": 2.5}) == {
        "action": "goal", "x_m": 1.0, "y_m": 2.5}  # fmt: skip
    assert parse_command({"action": "point_mast"}) == {"action": "point_mast"}
    for bad, msg in [
        ([1, 2], "JSON object"),
        ({"action": "fly"}, "'fly' is unknown"),
        ({"action": "goal", "x_m": 1}, "'y_m' is required"),
        ({"action": "goal", "x_m": "a", "y_m": 0}, "must be a number"),
        ({"action": "goal", "x_m": 1, "y_m": 0, "z": 1}, "unknown argument 'z'"),
        ({"action": "drive_arc", "speed_mps": 3, "distance_m": 1}, r"in \[-1, 1\]"),
        ({"action": "point_mast", "pan_deg": 10}, "both"),
        ({"action": "drill", "depth_m": float("nan")}, "finite"),
        ({"action": "goal", "x_m": 1e308, "y_m": 0}, r"x_m = 1e\+308 must be in"),
        ({"action": "goal", "x_m": 10**400, "y_m": 0}, "finite"),
    ]:
        with pytest.raises(CommandError, match=msg) as err:
            parse_command(bad)
        assert "\n" not in str(err.value)
    a = as_action({"action": "point_mast"}, t_s=3.0)
    assert a.action == "point_mast" and a.auto and a.t_s == 3.0


def test_the_server_binds_loopback_unless_asked():
    assert check_host("127.0.0.1", allow_remote=False) == "127.0.0.1"
    assert check_host("::1", allow_remote=False) == "::1"
    with pytest.raises(BindError, match=r"0\.0\.0\.0"):
        check_host("0.0.0.0", allow_remote=False)
    assert check_host("0.0.0.0", allow_remote=True) == "0.0.0.0"


# ------------------------------------------------------------------------- the server


def _with_client(mc, body):
    from aiohttp.test_utils import TestClient, TestServer

    async def main():
        client = TestClient(TestServer(make_app(mc)))
        await client.start_server()
        try:
            await body(client)
        finally:
            await client.close()

    asyncio.run(main())


def _replay_mc():
    mc = MissionControl()
    mc.set_site({"kind": "site", "epoch_utc": "2027-11-15T00:00:00", "name": "t",
                 "extent_m": [-10, 10, -10, 10], "hillshade_png": b"\x89PNG"})  # fmt: skip
    mc.store.add([("rover.x", 1.0, 0.5), ("rover.x", 2.0, 0.7), ("rover.mode", 2.0, 1)])
    return mc


def test_history_dictionary_and_json_errors():
    mc = _replay_mc()
    t0 = mc.epoch_ms

    async def body(c):
        d = await (await c.get("/api/dictionary")).json()
        assert {p["key"] for p in d["points"]} == set(dic.BY_KEY)
        r = await c.get(f"/api/history/rover.x?start={t0 + 1500}&end={t0 + 2000}")
        assert await r.json() == [{"id": "rover.x", "timestamp": t0 + 2000.0, "value": 0.7}]
        r = await c.get("/api/history/rover.x?strategy=latest")
        assert [d["value"] for d in await r.json()] == [0.7]
        r = await c.get("/api/history/rover.nope")
        assert r.status == 404 and "rover.nope" in (await r.json())["error"]
        r = await c.get("/api/history/rover.x?start=yesterday")
        assert r.status == 400 and "start" in (await r.json())["error"]
        r = await c.post("/api/command", data="{not json",
                         headers={"Content-Type": "application/json"})  # fmt: skip
        assert r.status == 400 and "not valid JSON" in (await r.json())["error"]
        r = await c.post("/api/command", data='{"action": "stop"}')  # text/plain
        assert r.status == 415 and "application/json" in (await r.json())["error"]
        r = await c.post("/api/command", json={"action": "stop"},
                         headers={"Origin": "http://evil.example"})  # fmt: skip
        assert r.status == 403 and "evil.example" in (await r.json())["error"]
        r = await c.get("/api/realtime", headers={"Origin": "http://evil.example"})
        assert r.status == 403
        r = await c.post("/api/command", json={"action": "stop"})
        assert r.status == 409 and "replay" in (await r.json())["error"]
        r = await c.post("/api/command", json={"action": "warp"})
        assert r.status == 400
        assert (await c.get("/api/map/hillshade.png")).status == 200
        assert (await c.get("/api/camera/latest.png")).status == 404
        info = await (await c.get("/api/info")).json()
        assert info["state"] == "replay" and info["epoch_ms"] == t0

    _with_client(mc, body)


def test_a_drive_command_while_safed_is_sent_with_a_visible_warning():
    """The rover ignores driving while safed: the reply to a goal or an arc says so (the
    page shows it in red); a stop or a resume, and anything while nominal, carry none."""
    import types

    from lunar_drake.mission_control.live import LiveObserver

    def run_with(packet):
        ops = types.SimpleNamespace(packet=packet)
        return types.SimpleNamespace(operator=types.SimpleNamespace(operator_state=lambda r: ops))

    obs = LiveObserver(outbox=queue.Queue(), inbox=queue.Queue())
    safed = run_with(_packet(mode=MODES.index("safed"),
                             safe_reason=SAFE_REASONS.index("uplink_loss")))  # fmt: skip
    goal = {"action": "goal", "x_m": 1.0, "y_m": 0.0}
    w = obs._safed_warning(safed, None, goal)
    assert "safed (uplink_loss)" in w and "resume" in w
    assert "safed" in obs._safed_warning(safed, None, {"action": "drive_arc"})
    assert obs._safed_warning(safed, None, {"action": "resume"}) == ""
    nominal = run_with(_packet(mode=MODES.index("driving")))
    assert obs._safed_warning(nominal, None, goal) == ""
    assert obs._safed_warning(run_with(None), None, goal) == ""


def test_the_instructor_overlay_is_off_unless_asked_and_never_telemetry():
    """Truth reaches the map only with ``instructor`` set (``run --serve --instructor``);
    without it a truth message is dropped, and truth is never a telemetry point."""

    def map_after(instructor):
        mc = MissionControl()
        mc.set_site({"kind": "site", "epoch_utc": "2027-11-15T00:00:00", "name": "t",
                     "extent_m": [-10, 10, -10, 10], "hillshade_png": b"\x89PNG",
                     "instructor": instructor})  # fmt: skip
        for t in (1.0, 2.0):
            mc.ingest({"kind": "batch", "t_s": t, "datums": [("ground.x", t, t)],
                       "truth_pose": [t, 0.9 * t, 0.1, 0.0]})  # fmt: skip
        got = {}

        async def body(c):
            got.update(await (await c.get("/api/map")).json())

        _with_client(mc, body)
        return got, mc

    off, mc = map_after(False)
    assert off["instructor"] is None and mc.store.map.truth == []
    on, mc = map_after(True)
    assert on["instructor"]["track"] == [[0.9, 0.1], [1.8, 0.1]]
    assert on["instructor"]["rover"] == [1.8, 0.1, 0.0]
    assert not any(k.startswith("truth") for k in dic.BY_KEY)


def test_realtime_subscribers_get_their_points_and_bad_messages_leave_the_socket_open():
    mc = _replay_mc()

    async def body(c):
        ws = await c.ws_connect("/api/realtime")
        await ws.send_str("{oops")
        assert "error" in json.loads((await ws.receive()).data)
        await ws.send_str(json.dumps({"subscribe": ["rover.nope"]}))
        assert "rover.nope" in json.loads((await ws.receive()).data)["error"]
        await ws.send_str(json.dumps({"subscribe": ["rover.y"]}))
        quitter = await c.ws_connect("/api/realtime")
        await quitter.send_str(json.dumps({"subscribe": ["rover.y"]}))
        await asyncio.sleep(0.05)
        await quitter.close()  # a client that vanishes mid-stream
        mc.ingest({"kind": "batch", "t_s": 3.0, "datums": [("rover.x", 3.0, 1.0),
                                                            ("rover.y", 3.0, 2.0)]})
        got = []
        while len(got) < 2:
            got.append(json.loads((await ws.receive()).data))
        msg = next(m for m in got if "datums" in m)
        assert msg["datums"] == [{"id": "rover.y", "timestamp": mc.ms(3.0), "value": 2.0}]
        assert msg["sim_s"] == 3.0
        assert any("clock" in m for m in got)
        await ws.close()

    _with_client(mc, body)


# ------------------------------------------------------------------ a live mission


def _live_scenario(cache):
    from lunar_drake.scenario_files import load_scenario

    return load_scenario(scenario_name="goto", scenario_text=(
        "{simulation_duration: 12.0, sensors: {camera: {enabled: false}}, "
        "ground: {goals: []}}"))  # fmt: skip


class _FakeMeshcat:
    """Drake's Meshcat control API, with clicks at set simulation times."""

    def __init__(self, click_at_s):
        self.click_at_s, self.buttons, self.sliders = click_at_s, {}, {}

    def AddButton(self, name):
        self.buttons[name] = 0

    def AddSlider(self, name, lo, hi, step, value):
        self.sliders[name] = -0.1 if "speed" in name else value

    def GetSliderValue(self, name):
        return self.sliders[name]

    def GetButtonClicks(self, name):
        t = self.click_at_s.get(name)
        return int(t is not None and self.run() >= t - 1e-9)


class _Scripted:
    """Sends requests to the observer's inbox at set simulation times."""

    def __init__(self, inbox, script):
        self.inbox, self.script = inbox, list(script)

    def __call__(self, run):
        while self.script and run.time_s >= self.script[0][0] - 1e-9:
            req = self.script.pop(0)[1]
            self.inbox.put(req(run) if callable(req) else req)


def _preview_in_a_hazard(run):
    """A preview request at the centre of a lethal cell of the ground's a-priori map whose
    nearest free cell is farther than the ground may move a goal."""
    from scipy.ndimage import distance_transform_edt

    from lunar_drake.autonomy.operations import goal_shift_limit_m

    cm = run.operator.prior_costmap
    depth = distance_transform_edt(~np.isfinite(cm.cost)) * cm.resolution_m
    r, c = np.argwhere(depth > goal_shift_limit_m(run.operator.params) + 1e-6)[0]
    x, y = cm.centre_of(r, c)
    return {"id": 4, "op": "preview", "x_m": float(x), "y_m": float(y)}


def test_a_command_from_the_network_is_driven_and_scenario_yaml_reproduces_the_run(cache):
    from lunar_drake import metrics
    from lunar_drake.cli.run import OBSERVE_AFTER_TICK_S, with_actions
    from lunar_drake.mission_control.live import LiveObserver
    from lunar_drake.mission_control.meshcat_controls import MeshcatControls
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = _live_scenario(cache)
    site = load_site(scenario, progress=False)
    outbox, inbox = queue.Queue(), queue.Queue()
    obs = LiveObserver(outbox=outbox, inbox=inbox, instructor=True)
    script = _Scripted(inbox, [
        (1.0, {"id": 1, "op": "preview", "x_m": 3.0, "y_m": 0.0}),
        (1.0, {"id": 2, "op": "command", "command": {"action": "goal", "x_m": 3.0, "y_m": 0.0}}),
        (1.5, {"id": 3, "op": "command", "command": {"action": "goal", "x_m": 1e4, "y_m": 0.0}}),
        (2.0, _preview_in_a_hazard),
    ])  # fmt: skip
    meshcat = _FakeMeshcat(click_at_s={"Drive arc (2 m)": 8.0})
    controls = MeshcatControls(meshcat, echo=lambda *_: None)
    meshcat.run = lambda: run_time[0]
    run_time = [0.0]

    def clock(run):
        run_time[0] = run.time_s

    logs = simulate(scenario=scenario, site=site, observers=(script, obs, clock, controls),
                    observe_period_s=0.1, observe_offset_s=OBSERVE_AFTER_TICK_S)  # fmt: skip
    assert [(a.action, a.speed_mps, a.distance_m) for a in controls.actions] == [
        ("drive_arc", -0.1, 2.0)]  # fmt: skip
    assert controls.actions[0].t_s == pytest.approx(8.0, abs=0.11)
    msgs = []
    while not outbox.empty():
        msgs.append(outbox.get())
    assert msgs[0]["kind"] == "site" and msgs[0]["hillshade_png"][:4] == b"\x89PNG"
    assert msgs[0]["instructor"] is True
    truth_msgs = [m["truth_pose"] for m in msgs if "truth_pose" in m]
    assert len(truth_msgs) >= 20 and truth_msgs[-1][1] > truth_msgs[0][1] + 0.5
    replies = {m["id"]: m for m in msgs if m["kind"] == "reply"}
    assert replies[1]["ok"] and len(replies[1]["path"]) >= 2
    assert replies[1]["path"][-1] == pytest.approx([3.0, 0.0])
    assert replies[2]["ok"] and replies[2]["t_s"] == pytest.approx(1.1)  # the next tick
    assert not replies[3]["ok"] and "off the ground's map" in replies[3]["error"]
    assert not replies[4]["ok"] and "inside a hazard" in replies[4]["error"], replies[4]
    assert [a.action for a in obs.actions] == ["goal"]
    # the goal went up the link and the rover moved towards it
    assert logs.ground_goals and logs.ground_goals[0][0] == (3.0, 0.0)
    truth = logs.vectors["truth.pose"]
    assert truth.data[-1, 0] - truth.data[0, 0] > 0.5
    datums = [d for m in msgs if m["kind"] == "batch" for d in m["datums"]]
    keys = {d[0] for d in datums}
    assert {"rover.x", "link.delay", "ground.x", "ground.event", "mission.time",
            "ground.active_goal", "ground.goal_distance", "ground.plan_left",
            "link.uplink_queue", "link.packet_age", "sky.earth_elevation",
            "sky.earth_margin", "cw.earth_below_horizon"} <= keys  # fmt: skip
    assert keys <= set(dic.BY_KEY)

    def series(key):
        return [(t, v) for k, t, v in datums if k == key]

    # the goal went up at 1.1 s and was handled after the uplink's delay: the queue
    # rose to 1 and fell back to 0; goal 1 was active and its distance shrank
    queue_ = series("link.uplink_queue")
    assert max(v for _, v in queue_) >= 1 and queue_[-1][1] == 0
    assert any(v == 1 for _, v in series("ground.active_goal"))
    dist = [v for _, v in series("ground.goal_distance")]
    assert dist and min(dist) < dist[0] - 0.3
    # the wiring, not the ephemeris (tests/test_ephemeris.py checks SPICE against
    # independent references): the observer predicts for the scenario's epoch and site
    from lunar_drake.ephemeris.sun_earth import SiteLocation, sun_earth_enu

    _, el = series("sky.earth_elevation")[-1]
    ref = sun_earth_enu(utc=scenario.site.epoch_utc, site=SiteLocation(
        scenario.site.latitude_deg, scenario.site.longitude_deg))  # fmt: skip
    assert el == pytest.approx(float(ref.earth_elevation_deg), abs=0.01)  # 12 s later
    assert any("plan" in m and m["plan"]["path"] for m in msgs if m["kind"] == "batch")
    # the same scenario with the command written down as ground.actions: same run
    again = with_actions(scenario, sorted([*obs.actions, *controls.actions],
                                          key=lambda a: a.t_s))  # fmt: skip
    logs2 = simulate(scenario=again, site=site)
    s1 = metrics.summarize(scenario=again, site=site, logs=logs)
    s2 = metrics.summarize(scenario=again, site=site, logs=logs2)
    assert json.dumps(s1, sort_keys=True) == json.dumps(s2, sort_keys=True)
    np.testing.assert_array_equal(logs.vectors["truth.pose"].data,
                                  logs2.vectors["truth.pose"].data)  # fmt: skip


# ---------------------------------------------------------------------------- run.mcap


def test_run_mcap_holds_the_expected_channels_and_counts(cache, tmp_path):
    import csv

    from mcap.reader import make_reader

    from lunar_drake.cli import main
    from lunar_drake.mission_control.recording import write_run_mcap

    out = tmp_path / "run"
    assert main(["run", "--scenario", "goto", "--duration", "12", "--no-meshcat",
                 "--no-progress", "--out", str(out)]) == 0  # fmt: skip

    def rows(name):
        with open(out / name, newline="") as f:
            return list(csv.DictReader(f))

    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.id: c.topic for c in summary.channels.values()}
        counts = {topics[k]: n for k, n in summary.statistics.channel_message_counts.items()}
        schemas = {topics[c.id]: summary.schemas[c.schema_id].name if c.schema_id else ""
                   for c in summary.channels.values()}  # fmt: skip
        times = [m.log_time for _, _, m in reader.iter_messages()]
        clouds = [(m.log_time, m.data)
                  for _, _, m in reader.iter_messages(topics=["/ground/points"])]
    tel = rows("telemetry.csv")
    assert counts["/rover/pose_estimate"] == counts["/telemetry"] == len(tel) > 5
    assert counts["/ground/events"] == len(rows("ground_events.csv")) > 0
    assert counts["/camera/left/compressed"] == len(rows("images.csv")) > 0
    assert counts["/ground/pose"] == counts["/tf"] > 0
    assert counts["/ground/costmap"] == 1 and counts["/ground/keyframes"] == 1
    assert schemas["/rover/pose_estimate"] == "foxglove.PoseInFrame"
    assert schemas["/camera/left/compressed"] == "foxglove.CompressedImage"
    assert schemas["/ground/costmap"] == "foxglove.Grid"
    assert times == sorted(times)
    _check_ground_points(out, clouds, schemas, rows)
    # stamped with reception time: the first packet's, from the epoch of the scenario
    from lunar_drake.mission_control.server import epoch_ms

    first = float(tel[0]["t_received_s"])
    assert min(times) <= round(epoch_ms("2027-11-15T00:00:00") * 1e6 + first * 1e9)
    # the same run served for replay: the datums the live mission would have published
    from lunar_drake.mission_control.replay import load_run

    mc = MissionControl()
    load_run(mc, out)
    assert len(mc.store.history("rover.x")) == len(tel)
    assert mc.store.history("link.delay")[0][1] == pytest.approx(
        float(tel[0]["t_received_s"]) - float(tel[0]["t_sent_s"]))  # fmt: skip
    assert mc.info["state"] == "replay" and mc.hillshade_png[:4] == b"\x89PNG"
    assert [g[:2] for g in mc.store.map.goals] == [[9.0, 0.0]]
    # exporting again gives the same bytes (no wall clock inside)
    again = write_run_mcap(out, out=tmp_path / "again.mcap", costmap=None)
    assert again.stat().st_size > 0
    third = write_run_mcap(out, out=tmp_path / "third.mcap", costmap=None)
    assert again.read_bytes() == third.read_bytes()


def _protobuf_fields(buf: bytes) -> dict:
    """A protobuf message's top-level fields: number -> values (varints as int, the
    others as bytes); foxglove-sdk encodes but does not decode."""
    out, i = {}, 0

    def varint():
        nonlocal i
        v = shift = 0
        while True:
            b = buf[i]
            i += 1
            v |= (b & 0x7F) << shift
            shift += 7
            if b < 0x80:
                return v

    while i < len(buf):
        key = varint()
        if key & 7 == 0:
            val = varint()
        else:
            n = {1: 8, 5: 4}.get(key & 7) or varint()
            val, i = buf[i : i + n], i + n
        out.setdefault(key >> 3, []).append(val)
    return out


def _check_ground_points(out, clouds, schemas, rows):
    """``/ground/points``: one cloud per keyframe, stamped when the ground received its
    frame, its points (``keyframe_points.npy``) finite and round the keyframe's ground
    pose (within the map's range of the camera), one per ``cloud_voxel_m`` voxel."""
    from lunar_drake.mission_control.recording import ns_since_epoch
    from lunar_drake.outputs import write_keyframe_points
    from lunar_drake.perception.ground_pipeline import KeyframeCloud
    from lunar_drake.scenario_files import load_scenario

    per = load_scenario(filename=out / "scenario.yaml").ground.perception
    kf = rows("keyframes.csv")
    received = {}
    for r in rows("images.csv"):
        received.setdefault(int(r["frame_index"]), float(r["t_received_s"]))
    assert schemas["/ground/points"] == "foxglove.PointCloud"
    assert len(clouds) == len(kf) > 0
    file = np.load(out / "keyframe_points.npy", allow_pickle=False)
    assert file.dtype.names == ("frame_index", "x", "y", "z")
    assert sorted(set(file["frame_index"].tolist())) == sorted(int(r["frame_index"]) for r in kf)
    by_time = sorted(kf, key=lambda r: received[int(r["frame_index"])])
    again = []
    for (t, data), r in zip(clouds, by_time, strict=True):
        assert t == ns_since_epoch("2027-11-15T00:00:00", received[int(r["frame_index"])])
        msg = _protobuf_fields(data)  # foxglove.PointCloud: 2 frame_id, 4 stride, 6 data
        assert msg[2] == [b"site"] and msg[4] == [(12).to_bytes(4, "little")]
        pts = np.frombuffer(msg[6][0], np.float32).reshape(-1, 3)
        mine = file[file["frame_index"] == int(r["frame_index"])]
        np.testing.assert_array_equal(pts, np.stack([mine["x"], mine["y"], mine["z"]], 1))
        assert len(pts) > 100 and np.isfinite(pts).all()
        # around the ground's pose of the chassis (the camera is on its mast, < 1 m off)
        d = np.hypot(pts[:, 0] - float(r["x_m"]), pts[:, 1] - float(r["y_m"]))
        assert d.max() <= per.map.max_range_m + 1.0
        assert len(np.unique(np.floor(pts / per.cloud_voxel_m), axis=0)) >= 0.99 * len(pts)
        again.append(KeyframeCloud(t_capture_s=float(r["t_capture_s"]),
                                   frame_index=int(r["frame_index"]), points_W=pts))  # fmt: skip
    # written again from the same clouds: the same bytes (no timestamps inside)
    again.sort(key=lambda c: [int(r["frame_index"]) for r in kf].index(c.frame_index))
    copy = write_keyframe_points(out.parent / "again.npy", clouds=again)
    assert copy.read_bytes() == (out / "keyframe_points.npy").read_bytes()


def test_the_foxglove_live_server_advertises_the_live_topics():
    from aiohttp import ClientSession

    from lunar_drake.mission_control.foxglove_live import FoxgloveLive

    live = FoxgloveLive(host="127.0.0.1", port=0, epoch_utc="2027-11-15T00:00:00")
    port = live.server.port
    fields = dict.fromkeys(TELEMETRY_FIELDS, 0.0)

    async def main():
        async with ClientSession() as s, s.ws_connect(
            f"ws://127.0.0.1:{port}", protocols=("foxglove.sdk.v1", "foxglove.websocket.v1")
        ) as ws:
            topics = set()
            for _ in range(6):
                msg = json.loads((await ws.receive(timeout=10)).data)
                if msg.get("op") == "advertise":
                    topics |= {c["topic"] for c in msg["channels"]}
                if {"/rover/pose_estimate", "/ground/events"} <= topics:
                    break
            live.batch({"packets": [{"seq": 0, "t_sent_s": 1.0, "t_received_s": 2.3,
                                     "fields": fields}],
                        "events": [(2.3, "safed", "tilt")],
                        "ground_pose": (2.3, [0, 0, 0, 0, 0, 0.5])})  # fmt: skip
            return topics

    topics = asyncio.run(main())
    live.close()
    assert {"/rover/pose_estimate", "/ground/pose", "/tf", "/telemetry", "/ground/events",
            "/camera/left/compressed"} <= topics


def test_bad_command_lines_get_one_line_and_exit_2(tmp_path, capsys):
    from lunar_drake.cli import main

    for argv, msg in [
        (["run", "--scenario", "small", "--rate", "-1", "--out", str(tmp_path / "a")], "--rate"),
        (["run", "--scenario", "small", "--serve", "--port", "70000", "--no-meshcat",
          "--out", str(tmp_path / "b")], "--port 70000"),
        (["run", "--scenario", "small", "--serve", "--foxglove-port", "-5", "--no-meshcat",
          "--out", str(tmp_path / "c")], "--foxglove-port -5"),
        (["serve", str(tmp_path)], "not a run directory"),
        (["export-mcap", str(tmp_path / "nope")], "not a run directory"),
    ]:  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_costmap_classes_tell_prior_unconfirmed_and_stereo_found_hazards():
    from types import SimpleNamespace as NS

    from lunar_drake.mission_control.live import COSTMAP_CLASSES, costmap_classes

    inf = np.inf
    prior = NS(cost=np.array([[1.0, inf], [1.0, 1.0]]), unconfirmed=None)
    now = NS(cost=np.array([[inf, inf], [1.0, inf]]),
             unconfirmed=np.array([[False, False], [False, True]]))  # fmt: skip
    got = costmap_classes(now, prior)
    names = [[COSTMAP_CLASSES[v] for v in row] for row in got]
    assert names == [["lethal_stereo", "lethal_prior"], ["free", "unconfirmed"]]
