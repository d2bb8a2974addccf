"""The Earth-Moon link: exact delay, order, sequence numbers, records (core and system)."""

import dataclasses as dc
import math

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from lunar_drake.comms import link as core
from lunar_drake.comms.link import LinkConfig
from lunar_drake.comms.messages import Ledger, Message
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.systems.link import POLL_OFFSET_S, Link


def _msg(seq, t, topic="telemetry", value=None):
    payload = np.array([t if value is None else value])
    return Message(topic=topic, seq=seq, t_sent_s=t, payload=payload, size_bytes=8)


def _accept(s, msgs, now, cfg=None, **kw):
    return core.accept(s, msgs, config=cfg or LinkConfig(delay_s=1.3), now_s=now, **kw)


def test_core_delivers_each_message_exactly_delay_after_it_was_sent():
    s = core.LinkState()
    s = _accept(s, [_msg(0, 0.0), _msg(1, 0.25)], 0.3)
    s = _accept(s, [_msg(1, 0.25)], 0.35)  # seen already: ignored
    assert len(s.in_flight) == 2
    assert core.inbox(s, "telemetry", 1.3 - 1e-9, history=8) == ()
    (d0,) = core.inbox(s, "telemetry", 1.3, history=8)
    assert d0.message.seq == 0 and d0.t_received_s == 1.3
    s = core.deliver(s, 1.6, direction="downlink", history=8)
    assert [d.message.seq for d in s.delivered["telemetry"]] == [0, 1]
    assert s.in_flight == ()
    rows = core.records(s, 1.6, direction="downlink")
    assert [(r.seq, r.t_sent, r.t_received, r.dropped, r.channel) for r in rows] == [
        (0, 0.0, 1.3, False, "main"),
        (1, 0.25, 1.55, False, "main"),
    ]


def test_core_history_keeps_the_newest_and_records_in_flight_at_the_end():
    s = core.LinkState()
    s = _accept(s, [_msg(k, 0.1 * k) for k in range(5)], 0.5, LinkConfig(delay_s=0.0))
    s = core.deliver(s, 1.0, direction="uplink", history=2)
    assert [d.message.seq for d in s.delivered["telemetry"]] == [3, 4]
    s = _accept(s, [_msg(5, 2.0)], 2.0, LinkConfig(delay_s=10.0))
    rows = core.records(s, 3.0, direction="uplink")
    assert len(rows) == 6 and math.isnan(rows[-1].t_received) and not rows[-1].dropped
    assert core.statistics(s, 3.0) == (6, 5, 0, 1, 0)


# ------------------------------------------------------------------ link properties
def _traffic(n, *, seed, topics=("telemetry",), mean_gap=0.05, max_bytes=1500):
    """Seeded messages: exponential gaps, sizes uniform in [40, max_bytes] bytes."""
    g = np.random.default_rng(seed)
    t = np.cumsum(g.exponential(mean_gap, n))
    seqs = dict.fromkeys(topics, -1)
    out = []
    for k in range(n):
        topic = topics[k % len(topics)]
        seqs[topic] += 1
        size = int(g.integers(40, max_bytes + 1))
        out.append(Message(topic=topic, seq=seqs[topic], t_sent_s=float(t[k]),
                           payload=None, size_bytes=size))  # fmt: skip
    return out


def _run(cfg, msgs, *, direction="downlink", seed=0, poll=1e-6):
    """Feeds each message at its send time (+ poll) and returns every record at the end."""
    s = core.LinkState()
    for m in msgs:
        s = core.accept(s, [m], config=cfg, now_s=m.t_sent_s + poll, direction=direction,
                        seed=seed)  # fmt: skip
        s = core.deliver(s, m.t_sent_s + poll, direction=direction, history=4)
    return core.records(s, 1e9, direction=direction), s


def test_token_bucket_never_exceeds_the_bandwidth_over_any_window():
    # 1000 B/s, 3000 B bucket, offered ~15 kB/s: the channel is saturated and queues.
    ch = core.ChannelConfig(bandwidth_bps=8000.0, bucket_bytes=3000, queue_limit_bytes=10**9)
    cfg = LinkConfig(delay_s=1.0, channels=[ch])
    rows, _ = _run(cfg, _traffic(300, seed=1))
    assert not any(r.dropped for r in rows)
    t_dep = np.array([r.t_received - 1.0 for r in rows])  # no jitter: arrival = departure + D
    size = np.array([r.bytes for r in rows], dtype=float)
    assert np.all(np.diff(t_dep) >= -1e-12)  # FIFO
    c = np.concatenate(([0.0], np.cumsum(size)))
    for i in range(len(t_dep)):
        # bytes departing in [t_i, t_j] <= bucket + rate (t_j - t_i), for every j >= i
        sent = c[i + 1 :] - c[i]
        allowed = 3000 + 1000.0 * (t_dep[i:] - t_dep[i])
        assert np.all(sent <= allowed + 1e-6), i
    # Saturated: it really runs at the bandwidth (not just under it).
    span = t_dep[-1] - t_dep[0]
    assert (c[-1] - c[1]) / span == pytest.approx(1000.0, rel=0.05)


def test_a_bandwidth_schedule_is_never_exceeded_over_any_window():
    """Rate steps 1000 -> 250 -> 2000 B/s under saturating traffic: over every window the
    bytes sent stay within bucket + the rate's integral, computed here by fine quadrature
    of the step function (not the link's own integral), and each segment runs at its
    rate."""
    steps = [core.RateStep(start_s=20.0, bandwidth_bps=2000.0),
             core.RateStep(start_s=45.0, bandwidth_bps=16000.0)]  # fmt: skip
    ch = core.ChannelConfig(bandwidth_bps=8000.0, bucket_bytes=3000, queue_limit_bytes=10**9,
                            schedule=steps)  # fmt: skip
    cfg = LinkConfig(delay_s=1.0, channels=[ch])
    rows, _ = _run(cfg, _traffic(300, seed=4))
    t_dep = np.array([r.t_received - 1.0 for r in rows])
    size = np.array([r.bytes for r in rows], dtype=float)
    assert np.all(np.diff(t_dep) >= -1e-12)
    grid = np.linspace(0.0, t_dep[-1] + 1.0, 400001)
    rate = np.where(grid < 20.0, 1000.0, np.where(grid < 45.0, 250.0, 2000.0))
    cum_rate = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(grid))))
    R = np.interp(t_dep, grid, cum_rate)
    c = np.concatenate(([0.0], np.cumsum(size)))
    for i in range(len(t_dep)):
        sent = c[i + 1 :] - c[i]
        assert np.all(sent <= 3000 + (R[i:] - R[i]) + 0.5), i  # 0.5 B: the quadrature
    for lo, hi, r in ((25.0, 44.0, 250.0), (50.0, t_dep[-1], 2000.0)):
        k = (t_dep >= lo) & (t_dep <= hi)
        assert size[k][1:].sum() / (t_dep[k][-1] - t_dep[k][0]) == pytest.approx(r, rel=0.08)


def test_a_bad_schedule_is_a_one_line_error():
    from lunar_drake.errors import ConfigError, OutOfRangeError

    with pytest.raises(ConfigError, match=r"schedule\[1\].start_s = 5 s must be after"):
        core.ChannelConfig(schedule=[core.RateStep(10.0, 1e3), core.RateStep(5.0, 1e3)]).validate()
    with pytest.raises(OutOfRangeError, match=r"schedule\[0\].bandwidth_bps"):
        core.ChannelConfig(schedule=[core.RateStep(10.0, 0.0)]).validate()


def test_fifo_per_channel_with_jitter_and_per_topic_delays_and_jitter_bounds():
    msgs = _traffic(400, seed=2, topics=("telemetry", "images"), max_bytes=200)
    cfg = LinkConfig(
        delay_s=1.3, topic_delay_s={"images": 1.5}, jitter_s=0.2,
        channels=[core.ChannelConfig(name="ops", bandwidth_bps=1e9)],
    )  # fmt: skip
    rows, _ = _run(cfg, msgs)
    assert [r.t_sent for r in rows] == sorted(r.t_sent for r in rows)  # delivered in order
    sent = {(m.topic, m.seq): m.t_sent_s for m in msgs}
    extra = []
    prev = -math.inf
    for r in rows:
        d = {"images": 1.5}.get(r.topic, 1.3)
        lo = sent[(r.topic, r.seq)] + d
        assert r.t_received >= lo - 1e-12 and r.t_received >= prev
        if r.t_received > prev + 1e-9:  # not held back behind an earlier message
            assert r.t_received <= lo + 0.2 + 1e-6 + 1e-12  # + the poll offset
            extra.append(r.t_received - lo)
        prev = r.t_received
    # Jitter is uniform on [0, 0.2]: its mean over the free arrivals is near 0.1
    # (biased low a little by the FIFO hold-backs removed above).
    assert 0.07 < float(np.mean(extra)) < 0.12


def test_losses_only_where_configured_and_burst_statistics():
    msgs = _traffic(4000, seed=3, max_bytes=100)
    free = LinkConfig(delay_s=1.3, channels=[core.ChannelConfig(bandwidth_bps=1e9)])
    rows, _ = _run(free, msgs)
    assert not any(r.dropped for r in rows) and all(math.isfinite(r.t_received) for r in rows)
    # Scheduled outage on the downlink: exactly the messages sent inside it are lost.
    out = dc.replace(free, outages=[core.OutageWindow(start_s=50.0, end_s=80.0)])
    rows, _ = _run(out, msgs)
    for r in rows:
        inside = 50.0 <= r.t_sent + 1e-6 < 80.0
        assert r.dropped == inside and (r.reason == "outage") == inside
    # Uplink: lost when the rover would receive it inside the window.
    rows, _ = _run(out, msgs, direction="uplink")
    for r in rows:
        assert r.dropped == (50.0 <= r.t_sent + 1e-6 + 1.3 < 80.0)
    # Gilbert-Elliott: stationary loss p_enter / (p_enter + p_leave) * loss_bad, bursts
    # of mean length 1 / p_leave.
    ge = dc.replace(free, loss=core.BurstLossConfig(p_enter_bad=0.02, p_leave_bad=0.25))
    rows, _ = _run(ge, msgs, seed=5)
    lost = np.array([r.dropped for r in sorted(rows, key=lambda r: r.seq)])
    assert all(r.reason == "loss" for r in rows if r.dropped)
    assert lost.mean() == pytest.approx(0.02 / 0.27, abs=0.02)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2]
    assert runs.mean() == pytest.approx(4.0, rel=0.3)


def test_same_seed_same_bytes_other_seed_other_draws():
    msgs = _traffic(300, seed=4, max_bytes=300)
    cfg = LinkConfig(delay_s=1.3, jitter_s=0.1, loss=core.BurstLossConfig(p_enter_bad=0.1),
                     channels=[core.ChannelConfig(bandwidth_bps=20000.0)])  # fmt: skip
    a, _ = _run(cfg, msgs, seed=7)
    b, _ = _run(cfg, msgs, seed=7)
    c, _ = _run(cfg, msgs, seed=8)
    assert a == b
    assert a != c


def test_queue_limit_oversize_and_payload_table_drop_and_count_never_hang():
    # 100 B/s, queue 1000 B: offered 20 x 300 B at once -> a few queue, the rest refused.
    ch = core.ChannelConfig(bandwidth_bps=800.0, bucket_bytes=500, queue_limit_bytes=1000)
    cfg = LinkConfig(delay_s=0.5, channels=[ch], payload_bytes={"images": 900})
    burst = [Message(topic="telemetry", seq=k, t_sent_s=0.0, payload=None, size_bytes=300)
             for k in range(20)]  # fmt: skip
    s = core.accept(core.LinkState(), burst, config=cfg, now_s=0.0)
    big = Message(topic="images", seq=0, t_sent_s=0.0, payload=None, size_bytes=10)
    s = core.accept(s, [big], config=cfg, now_s=0.0)  # 900 B by the table: > bucket
    rows = core.records(s, 100.0, direction="downlink")
    reasons = [r.reason for r in rows if r.dropped]
    assert reasons.count("oversize") == 1
    assert reasons.count("queue_full") == 20 - 1 - 3  # 1 departs now, 3 (900 B) wait
    got = [r for r in rows if not r.dropped]
    assert [r.seq for r in got] == [0, 1, 2, 3]
    assert [r.t_received for r in got] == pytest.approx([0.5, 1.5, 4.5, 7.5])
    assert core.statistics(s, 0.0) == (21, 0, 17, 4, 900)
    assert core.statistics(s, 100.0)[:3] == (21, 4, 17)


def test_link_config_errors_name_the_field():
    with pytest.raises(OutOfRangeError, match="bandwidth_bps = 0"):
        LinkConfig(channels=[core.ChannelConfig(bandwidth_bps=0.0)])
    with pytest.raises(ConfigError, match="topic 'a' is on two channels"):
        LinkConfig(channels=[core.ChannelConfig(name="x", topics=["a"]),
                             core.ChannelConfig(name="y", topics=["a"])])  # fmt: skip
    with pytest.raises(OutOfRangeError, match=r"outages\[0\]\.end_s"):
        LinkConfig(outages=[core.OutageWindow(start_s=5.0, end_s=1.0)])
    with pytest.raises(OutOfRangeError, match=r"loss\.p_enter_bad"):
        LinkConfig(loss=core.BurstLossConfig(p_enter_bad=1.5))


def test_ledger_is_persistent_and_never_copied():
    import copy

    a = Ledger().append(1).append(2)
    b = a.append(3)
    assert a.items() == [1, 2] and b.items() == [1, 2, 3] and len(b) == 3
    assert copy.deepcopy(b) is b


def test_link_config_is_validated():
    with pytest.raises(OutOfRangeError, match="delay_s = -1"):
        LinkConfig(delay_s=-1.0)


class _Producer(LeafSystem):
    """Sends a message every ``period`` s whose payload is a signal of its send time."""

    def __init__(self, period, topic="telemetry"):
        super().__init__()
        self._period = period
        self._topic = topic
        self._box = self.DeclareAbstractState(AbstractValue.Make(()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("outbox", self._box)

    @staticmethod
    def signal(t):
        return math.sin(0.7 * t) + 0.1 * t

    def _update(self, context, state):
        t = context.get_time()
        msg = _msg(round(t / self._period), t, self._topic, self.signal(t))
        state.get_mutable_abstract_state(self._box).set_value((msg,))


@pytest.mark.parametrize("delay", [0.0, 0.05, 1.3, 2.6])
def test_link_system_delays_every_signal_by_exactly_the_delay(delay):
    """out(t_sent + D) == in(t_sent) for every message, exact to 1e-12 s; a delay shorter
    than the poll offset (1 us) delivers at the poll."""
    period = 0.1
    builder = DiagramBuilder()
    prod = builder.AddSystem(_Producer(period))
    link = builder.AddSystem(
        Link(direction="downlink", topics={"telemetry": period}, config=LinkConfig(delay_s=delay))
    )
    builder.Connect(prod.get_output_port(), link.inputs["telemetry"])
    diagram = builder.Build()
    sim = Simulator(diagram)
    ctx = link.GetMyContextFromRoot(sim.get_mutable_context())
    seen = {}
    # Probe the inbox just before and exactly at each due time. (Simulator.AdvanceTo(t)
    # handles events at t on the next call, so a zero delay is probed just after the poll.)
    latency = max(delay, POLL_OFFSET_S)
    for k in range(40):
        t_due = k * period + latency
        sim.AdvanceTo(t_due - min(1e-7, latency / 2))
        before = {d.message.seq for d in link.inbox(ctx, "telemetry")}
        assert k not in before, (k, delay)
        sim.AdvanceTo(t_due if delay >= 1e-3 else t_due + latency / 2)
        for d in link.inbox(ctx, "telemetry"):
            seen[d.message.seq] = d
        assert k in seen, (k, delay)
    for k, d in seen.items():
        t_sent = k * period
        assert d.message.t_sent_s == pytest.approx(t_sent, abs=1e-12)
        # out(t_sent + D) == in(t_sent): the value that crossed is the signal at t_sent
        assert d.message.payload[0] == pytest.approx(_Producer.signal(t_sent), abs=1e-12)
        assert d.t_received_s - d.message.t_sent_s == pytest.approx(latency, abs=1e-12)
    rows = link.records(ctx)
    got = [r for r in rows if math.isfinite(r.t_received)]
    assert [r.seq for r in got] == sorted(r.seq for r in got)  # in order
    assert all(r.t_received - r.t_sent == pytest.approx(latency, abs=1e-12) for r in got)


def test_mission_link_from_the_scenario_drops_counts_and_round_trips(small_site):
    """The scenario's comms section drives the mission's links: a downlink outage and
    burst loss lose telemetry (counted by reason in the summary), the scenario YAML
    round-trips, and the same seed gives the same link records."""
    from lunar_drake import metrics
    from lunar_drake.scenario_files import apply_overrides, dump_scenario, scenario_from_text
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    scenario = apply_overrides(
        scenario,
        """{simulation_duration: 6.0, sensors: {camera: {enabled: false}},
            flight: {telemetry_rate_hz: 10.0},
            comms: {downlink: {delay_s: 0.5, jitter_s: 0.05,
                               outages: [{start_s: 2.0, end_s: 3.5}],
                               loss: {p_enter_bad: 0.2, p_leave_bad: 0.5},
                               channels: [{name: telemetry, bandwidth_bps: 64000.0,
                                           topics: [telemetry]}]}}}""",
    )
    assert scenario_from_text(dump_scenario(scenario)).comms == scenario.comms
    logs = simulate(scenario=scenario, site=site, progress=False)
    down = [r for r in logs.link if r.direction == "downlink"]
    assert {r.channel for r in down} == {"telemetry"}
    outage = [r for r in down if 2.0 <= r.t_sent + 1e-6 < 3.5]
    assert outage and all(r.dropped and r.reason == "outage" for r in outage)
    stats = metrics.link_stats(logs)["downlink"]
    assert stats["dropped"] == sum(r.dropped for r in down) > len(outage)
    assert stats["dropped_by_reason"]["outage"] == len(outage)
    # Telemetry the ground got is what the link delivered, in order (less any that
    # arrived after the ground's last poll).
    got = {r.seq: r.t_received for r in down if not r.dropped and math.isfinite(r.t_received)}
    assert stats["delivered"] == len(got) > 0
    ground = list(logs.telemetry.seq)
    assert ground == sorted(ground) and set(ground) <= set(got)
    assert all(got[k] > 5.0 for k in set(got) - set(ground))
    again = simulate(scenario=scenario, site=site, progress=False)
    assert again.link == logs.link


def test_camera_frames_go_down_compressed_and_pay_for_their_real_bytes(small_site):
    """PNG frames round-trip exactly; JPEG ones are smaller and lossy; in the mission each
    stereo frame is charged its encoded bytes, on the images channel, whose bucket and
    bandwidth hold over every window."""
    import cv2

    from lunar_drake.comms.images import (
        PNG_FILTERS,
        ImageDownlinkConfig,
        decode_frame,
        encode_frame,
    )
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    rng = np.random.default_rng(5)
    raw = (rng.normal(1500, 300, (96, 128)).clip(0, 4095)).astype(np.uint16)
    png = encode_frame(raw, config=ImageDownlinkConfig(codec="png"))
    assert np.array_equal(decode_frame(png, codec="png"), raw)
    assert len(png) == len(cv2.imencode(".png", raw, [cv2.IMWRITE_PNG_COMPRESSION, 3,
                                                      cv2.IMWRITE_PNG_STRATEGY,
                                                      cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
                                                      cv2.IMWRITE_PNG_FILTER,
                                                      cv2.IMWRITE_PNG_FILTER_SUB])[1])
    # every row filter round-trips; the filter changes the bytes, never the pixels
    by_filter = {f: encode_frame(raw, config=ImageDownlinkConfig(png_filter=f))
                 for f in PNG_FILTERS}  # fmt: skip
    for buf in by_filter.values():
        assert np.array_equal(decode_frame(buf, codec="png"), raw)
    assert len({bytes(b) for b in by_filter.values()}) == len(PNG_FILTERS)
    with pytest.raises(ConfigError, match="png_filter = 'lzw' is unknown"):
        ImageDownlinkConfig(png_filter="lzw").validate()
    jpg = encode_frame(raw, config=ImageDownlinkConfig(codec="jpeg", jpeg_quality=80))
    back = decode_frame(jpg, codec="jpeg")
    assert len(jpg) < len(png) and np.abs(back.astype(float) - raw).mean() < 200.0

    scenario, site = small_site
    scenario = apply_overrides(
        scenario,
        "{simulation_duration: 12.0, sensors: {camera: {rate_hz: 0.5, width: 160, height: 120}},"
        " comms: {downlink: {delay_s: 1.0, channels: [{name: main},"
        " {name: images, bandwidth_bps: 64000.0, bucket_bytes: 60000, topics: [images]}]}}}",
    )
    logs = simulate(scenario=scenario, site=site)
    rows = [r for r in logs.link if r.topic == "images"]
    got = [r for r in rows if not r.dropped and np.isfinite(r.t_received)]
    assert len(rows) == 6 and all(r.channel == "images" for r in rows)
    sizes = [r.bytes for r in rows]
    assert min(sizes) > 24 + 2 * 5000  # two 160 x 120 16-bit PNGs of a textured scene
    # Token bucket: bytes leaving in [t_i, t_j] <= bucket + rate (t_j - t_i).
    t_dep = np.array([r.t_received - 1.0 for r in got])
    c = np.concatenate(([0.0], np.cumsum([r.bytes for r in got])))
    for i in range(len(got)):
        assert np.all(c[i + 1 :] - c[i] <= 60000 + 8000.0 * (t_dep[i:] - t_dep[i]) + 1e-6)
    assert any(r.t_received - r.t_sent > 1.5 for r in got)  # queued behind the bandwidth
    assert [x[2] for x in logs.images_received] == [int(r.seq) for r in got]
