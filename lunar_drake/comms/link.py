"""A one-way link (uplink or downlink): today a pass-through with a fixed delay.

Pure functions on an immutable :class:`LinkState`. A message created at ``t_sent_s``
is delivered at exactly ``t_sent_s + delay_s``. The comms issue adds jitter, token-bucket
channels, queues and losses here; the state already keeps per-topic sequence numbers
and a ledger of every message (the rows of ``link.csv``).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

from lunar_drake.comms.messages import Delivery, Ledger, Message
from lunar_drake.errors import check_range

#: Columns of a link record (``link.csv``).
LINK_RECORD_FIELDS = (
    "direction",
    "channel",
    "topic",
    "seq",
    "bytes",
    "t_sent",
    "t_received",
    "dropped",
)


@dc.dataclass
class LinkConfig:
    """One direction of the Earth-Moon link.

    Attributes:
        delay_s: one-way delay from a message's creation to its delivery (s). The
            default, 1.3 s, is the mean Earth-Moon light time (384 400 km / c = 1.28 s)
            plus a little ground processing.
    """

    delay_s: float = 1.3

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("delay_s", self.delay_s, 0.0, 3600.0, unit=" s")


@dc.dataclass(frozen=True)
class LinkRecord:
    """One message's passage over the link (a row of ``link.csv``)."""

    direction: str
    channel: str
    topic: str
    seq: int
    bytes: int
    t_sent: float
    t_received: float
    dropped: bool


@dc.dataclass(frozen=True, eq=False)
class LinkState:
    """What a link holds: messages in flight (with their delivery times), the last
    ``history`` deliveries per topic, the newest accepted ``seq`` per topic, and the
    ledger of delivered messages."""

    in_flight: tuple = ()
    delivered: dict = dc.field(default_factory=dict)
    last_seq: dict = dc.field(default_factory=dict)
    ledger: Ledger = dc.field(default_factory=Ledger)

    def __deepcopy__(self, memo):
        return self


def accept(state: LinkState, messages, *, delay_s: float, now_s: float) -> LinkState:
    """The state after the link takes ``messages`` at ``now_s`` (those newer than the
    last accepted of their topic; older ones were already taken). Each is due at its
    creation time plus ``delay_s``, or at ``now_s`` if that is later (a link cannot
    deliver a message before it has it)."""
    last = dict(state.last_seq)
    new = []
    for m in messages:
        if m.seq > last.get(m.topic, -1):
            last[m.topic] = m.seq
            due = max(m.t_sent_s + delay_s, now_s)
            new.append(Delivery(message=m, t_received_s=due))
    if not new:
        return state
    return dc.replace(state, in_flight=state.in_flight + tuple(new), last_seq=last)


def _due(delivery: Delivery, now_s: float) -> bool:
    # The delivery time is computed as t_sent + delay; compare with a relative tolerance
    # so a delivery due exactly now is not missed by rounding.
    return delivery.t_received_s <= now_s + 1e-12 * max(1.0, abs(now_s))


def deliver(
    state: LinkState, now_s: float, *, direction: str, channel: str, history: int
) -> LinkState:
    """The state after every message due by ``now_s`` moved from in flight to delivered
    (keeping the last ``history`` per topic) and into the ledger."""
    due = [d for d in state.in_flight if _due(d, now_s)]
    if not due:
        return state
    delivered = dict(state.delivered)
    ledger = state.ledger
    for d in due:
        m = d.message
        delivered[m.topic] = (*delivered.get(m.topic, ()), d)[-history:]
        ledger = ledger.append(_record(m, d.t_received_s, direction, channel))
    rest = tuple(d for d in state.in_flight if not _due(d, now_s))
    return dc.replace(state, in_flight=rest, delivered=delivered, ledger=ledger)


def inbox(state: LinkState, topic: str, now_s: float, *, history: int) -> tuple:
    """The last ``history`` deliveries of ``topic`` by ``now_s`` (oldest first),
    including messages that came due since the state was last updated."""
    done = state.delivered.get(topic, ())
    due = tuple(d for d in state.in_flight if d.message.topic == topic and _due(d, now_s))
    return (done + due)[-history:]


def records(state: LinkState, now_s: float, *, direction: str, channel: str) -> list:
    """Every message the link has carried by ``now_s`` (in delivery order), then those
    still in flight (``t_received`` NaN)."""
    state = deliver(state, now_s, direction=direction, channel=channel, history=1)
    rows = state.ledger.items()
    rows.extend(_record(d.message, math.nan, direction, channel) for d in state.in_flight)
    return rows


def _record(m, t_received: float, direction: str, channel: str) -> LinkRecord:
    """The ledger row of message ``m`` received at ``t_received`` (s; NaN: in flight)."""
    return LinkRecord(
        direction=direction,
        channel=channel,
        topic=m.topic,
        seq=m.seq,
        bytes=m.size_bytes,
        t_sent=m.t_sent_s,
        t_received=t_received,
        dropped=False,
    )


__all__ = [
    "LINK_RECORD_FIELDS",
    "LinkConfig",
    "LinkRecord",
    "LinkState",
    "Message",
    "accept",
    "deliver",
    "inbox",
    "records",
]
