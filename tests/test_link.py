"""The Earth-Moon link: exact delay, order, sequence numbers, records (core and system)."""

import math

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from lunar_drake.comms import link as core
from lunar_drake.comms.link import LinkConfig
from lunar_drake.comms.messages import Ledger, Message
from lunar_drake.errors import OutOfRangeError
from lunar_drake.systems.link import POLL_OFFSET_S, Link


def _msg(seq, t, topic="telemetry", value=None):
    payload = np.array([t if value is None else value])
    return Message(topic=topic, seq=seq, t_sent_s=t, payload=payload, size_bytes=8)


def test_core_delivers_each_message_exactly_delay_after_it_was_sent():
    s = core.LinkState()
    s = core.accept(s, [_msg(0, 0.0), _msg(1, 0.25)], delay_s=1.3, now_s=0.3)
    s = core.accept(s, [_msg(1, 0.25)], delay_s=1.3, now_s=0.35)  # seen already: ignored
    assert len(s.in_flight) == 2
    assert core.inbox(s, "telemetry", 1.3 - 1e-9, history=8) == ()
    (d0,) = core.inbox(s, "telemetry", 1.3, history=8)
    assert d0.message.seq == 0 and d0.t_received_s == 1.3
    s = core.deliver(s, 1.6, direction="downlink", channel="main", history=8)
    assert [d.message.seq for d in s.delivered["telemetry"]] == [0, 1]
    assert s.in_flight == ()
    rows = core.records(s, 1.6, direction="downlink", channel="main")
    assert [(r.seq, r.t_sent, r.t_received, r.dropped) for r in rows] == [
        (0, 0.0, 1.3, False),
        (1, 0.25, 1.55, False),
    ]


def test_core_history_keeps_the_newest_and_records_in_flight_at_the_end():
    s = core.LinkState()
    s = core.accept(s, [_msg(k, 0.1 * k) for k in range(5)], delay_s=0.0, now_s=0.5)
    s = core.deliver(s, 1.0, direction="uplink", channel="main", history=2)
    assert [d.message.seq for d in s.delivered["telemetry"]] == [3, 4]
    s = core.accept(s, [_msg(5, 2.0)], delay_s=10.0, now_s=2.0)
    rows = core.records(s, 3.0, direction="uplink", channel="main")
    assert len(rows) == 6 and math.isnan(rows[-1].t_received)


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
