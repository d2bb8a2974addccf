"""A one-way link (uplink or downlink): delay, jitter, bandwidth-limited channels with
queues, and losses. Pure functions on an immutable :class:`LinkState`; no Drake.

Model (per direction; :class:`LinkConfig`)
------------------------------------------
* **Channels.** Each topic travels on one logical channel (:class:`ChannelConfig`;
  a topic no channel lists goes on the first). A channel sends its messages in order
  (FIFO) through a token bucket: tokens (bytes) accrue at ``bandwidth_bps / 8`` up to
  ``bucket_bytes``; a message of ``S`` bytes departs once the bucket holds ``S`` and
  takes them. So over any window of ``W`` seconds a channel sends at most
  ``bucket_bytes + W bandwidth_bps / 8`` bytes. The departure time of a message is
  fixed when the link takes it (nothing taken later can delay it), so it is computed
  in closed form: ``t_ready = max(t_sent, previous departure)``, tokens then
  ``min(B, tokens + r (t_ready - t_prev))``, departure ``t_ready`` or
  ``t_ready + (S - tokens) / r``. A **bandwidth schedule** (``schedule``: rate steps
  from set times, e.g. a ground station handover or a lower-rate antenna) makes ``r``
  piecewise constant in time: the tokens accrue by the rate's integral and the
  departure is where that integral reaches the shortfall (still closed form, per
  segment).
* **Queue limit.** A message is refused (dropped, ``queue_full``) if the bytes waiting
  to depart when it arrives, plus its own, exceed ``queue_limit_bytes``; one larger
  than ``bucket_bytes`` can never depart and is dropped (``oversize``).
* **Payload size**: the message's own bytes (``Message.size_bytes``), or the
  scenario's table ``payload_bytes[topic]`` when the flight counterpart differs.
* **Delay**: ``delay_s`` (or ``topic_delay_s[topic]``; by default the light time from
  the ephemeris plus ``ground_processing_s``) after departure, plus jitter
  uniform in ``[0, jitter_s]`` drawn per message from a counter-based generator keyed
  by (seed, direction, topic, seq). Delivery keeps the channel's order: a message never
  arrives before the one sent ahead of it on its channel (``t_received = max(t_depart +
  delay + jitter, previous t_received)``).
* **Losses**: a message is lost (``dropped``; it still used its bandwidth) when
  the rover's end of the link is down (an :class:`OutageWindow`: scheduled windows;
  for the downlink the rover transmits at departure, for the uplink it receives at
  arrival), when the Earth is below the terrain horizon at the rover
  (``earth_visible`` False: loss of signal), or by the two-state burst model
  (:class:`BurstLossConfig`, Gilbert-Elliott: per message on a channel, the state
  moves good -> bad with ``p_enter_bad`` and bad -> good with ``p_leave_bad``; then
  the message is lost with ``loss_good`` or ``loss_bad``), drawn from the same keyed
  generator. Nothing else loses messages.

Every message gets a ledger row (:class:`LinkRecord`, the rows of ``link.csv``):
delivered ones with their reception time, dropped ones at once (``t_received`` NaN,
``dropped`` true, a ``reason``), and those still in flight at the end (NaN, false).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

from lunar_drake import rng
from lunar_drake.comms.messages import Delivery, Ledger, Message
from lunar_drake.errors import ConfigError, check_range

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

#: Why a message was dropped (``LinkRecord.reason``).
DROP_REASONS = ("queue_full", "oversize", "outage", "no_line_of_sight", "loss")


@dc.dataclass
class RateStep:
    """From ``start_s`` (s) on, a channel's bandwidth is ``bandwidth_bps`` (bit/s)."""

    start_s: float = 0.0
    bandwidth_bps: float = 1.0e6


@dc.dataclass
class ChannelConfig:
    """A logical channel of one link direction.

    Attributes:
        name: label (``link.csv``'s ``channel``).
        bandwidth_bps: token rate, bits/s, in (0, 1e10].
        bucket_bytes: token-bucket depth (the largest burst and the largest message),
            bytes, >= 1.
        queue_limit_bytes: bytes that may wait to depart, >= 1.
        topics: the topics this channel carries.
        schedule: bandwidth steps (:class:`RateStep`, start times increasing); before
            the first, ``bandwidth_bps``.
    """

    name: str = "main"
    bandwidth_bps: float = 1.0e6
    bucket_bytes: int = 65536
    queue_limit_bytes: int = 1_000_000
    topics: list[str] = dc.field(default_factory=list)
    schedule: list[RateStep] = dc.field(default_factory=list)

    def validate(self) -> None:
        for k, step in enumerate(self.schedule):
            check_range(f"schedule[{k}].start_s", step.start_s, 0.0, 1.0e9, unit=" s")
            check_range(f"schedule[{k}].bandwidth_bps", step.bandwidth_bps, 0.0, 1.0e10,
                        lo_open=True, unit=" bit/s (use outages for no link)")  # fmt: skip
            if k and step.start_s <= self.schedule[k - 1].start_s:
                raise ConfigError(
                    f"schedule[{k}].start_s = {step.start_s:g} s must be after "
                    f"schedule[{k - 1}].start_s = {self.schedule[k - 1].start_s:g} s"
                )
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"name = {self.name!r} must be a non-empty string")
        check_range("bandwidth_bps", self.bandwidth_bps, 0.0, 1.0e10, lo_open=True,
                    unit=" bit/s")  # fmt: skip
        check_range("bucket_bytes", self.bucket_bytes, 1, 1.0e12, unit=" bytes")
        check_range("queue_limit_bytes", self.queue_limit_bytes, 1, 1.0e12, unit=" bytes")


@dc.dataclass
class OutageWindow:
    """The rover's end of the link is down for ``start_s <= t < end_s`` (s)."""

    start_s: float = 0.0
    end_s: float = 0.0

    def validate(self) -> None:
        check_range("start_s", self.start_s, 0.0, 1.0e9, unit=" s")
        check_range("end_s", self.end_s, self.start_s, 1.0e9, unit=" s (>= start_s)")


@dc.dataclass
class BurstLossConfig:
    """Two-state (Gilbert-Elliott) random loss, per message on a channel.

    Attributes:
        p_enter_bad: probability of moving good -> bad before a message, [0, 1].
        p_leave_bad: probability of moving bad -> good before a message, [0, 1].
        loss_good, loss_bad: loss probability of a message in each state, [0, 1].
    """

    p_enter_bad: float = 0.0
    p_leave_bad: float = 0.5
    loss_good: float = 0.0
    loss_bad: float = 1.0

    def validate(self) -> None:
        for name in ("p_enter_bad", "p_leave_bad", "loss_good", "loss_bad"):
            check_range(name, getattr(self, name), 0.0, 1.0)

    @property
    def lossless(self) -> bool:
        return self.loss_good == 0.0 and (self.p_enter_bad == 0.0 or self.loss_bad == 0.0)


@dc.dataclass
class LinkConfig:
    """One direction of the Earth-Moon link (module docstring).

    Attributes:
        delay_s: one-way delay after departure (s); ``None`` (the default): the
            Earth-rover light time at the scenario's epoch (from the ephemeris, about
            1.25-1.35 s over a month) plus ``ground_processing_s``.
        ground_processing_s: added to the light time when ``delay_s`` is None (s).
        topic_delay_s: per-topic delays that replace ``delay_s`` (s).
        jitter_s: extra delay uniform in [0, jitter_s] per message (s).
        channels: logical channels; the first carries every topic no channel lists.
        payload_bytes: per-topic payload size as flown (bytes), replacing the
            simulated message's size.
        outages: windows when the rover's end of the link is down.
        loss: random burst loss.
    """

    delay_s: float | None = None
    ground_processing_s: float = 0.05
    topic_delay_s: dict[str, float] = dc.field(default_factory=dict)
    jitter_s: float = 0.0
    channels: list[ChannelConfig] = dc.field(default_factory=lambda: [ChannelConfig()])
    payload_bytes: dict[str, int] = dc.field(default_factory=dict)
    outages: list[OutageWindow] = dc.field(default_factory=list)
    loss: BurstLossConfig = dc.field(default_factory=BurstLossConfig)

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        if self.delay_s is not None:
            check_range("delay_s", self.delay_s, 0.0, 3600.0, unit=" s")
        check_range("ground_processing_s", self.ground_processing_s, 0.0, 3600.0, unit=" s")
        for topic, d in self.topic_delay_s.items():
            check_range(f"topic_delay_s[{topic}]", d, 0.0, 3600.0, unit=" s")
        check_range("jitter_s", self.jitter_s, 0.0, 3600.0, unit=" s")
        if not self.channels:
            raise ConfigError("channels = [] must hold at least one channel")
        names = set()
        owner = {}
        for k, ch in enumerate(self.channels):
            _nested(f"channels[{k}]", ch.validate)
            if ch.name in names:
                raise ConfigError(f"channels[{k}].name = {ch.name!r} is used twice")
            names.add(ch.name)
            for t in ch.topics:
                if t in owner:
                    raise ConfigError(
                        f"topic {t!r} is on two channels ({owner[t]!r} and {ch.name!r})"
                    )
                owner[t] = ch.name
        for topic, n in self.payload_bytes.items():
            check_range(f"payload_bytes[{topic}]", n, 1, 1.0e12, unit=" bytes")
        for k, w in enumerate(self.outages):
            _nested(f"outages[{k}]", w.validate)
        _nested("loss", self.loss.validate)

    def one_way_delay_s(self, topic: str, *, light_time_s: float | None) -> float:
        """The delay (s) of ``topic`` after departure, before jitter: ``topic_delay_s``,
        else ``delay_s``, else ``light_time_s + ground_processing_s``."""
        if topic in self.topic_delay_s:
            return float(self.topic_delay_s[topic])
        if self.delay_s is not None:
            return float(self.delay_s)
        if light_time_s is None:
            raise ConfigError(
                "delay_s is not set (light time + ground processing) but no light time "
                "was given; pass light_time_s or set delay_s"
            )
        return float(light_time_s) + float(self.ground_processing_s)

    def channel_of(self, topic: str) -> ChannelConfig:
        """The channel that carries ``topic``."""
        for ch in self.channels:
            if topic in ch.topics:
                return ch
        return self.channels[0]


def _nested(prefix: str, validate) -> None:
    try:
        validate()
    except ConfigError as exc:
        raise type(exc)(f"{prefix}.{exc}") from None


@dc.dataclass(frozen=True)
class LinkRecord:
    """One message's passage over the link (a row of ``link.csv``; ``reason`` is why
    it was dropped, '' otherwise; not a CSV column)."""

    direction: str
    channel: str
    topic: str
    seq: int
    bytes: int
    t_sent: float
    t_received: float
    dropped: bool
    reason: str = ""


@dc.dataclass(frozen=True)
class ChannelState:
    """A channel's token bucket after its latest departure, its queue and loss state.

    ``t_last``/``tokens``: time (s) of the latest departure and the bucket then (bytes);
    ``departures``: (departure time, bytes) of messages not yet departed at the latest
    acceptance; ``t_last_received``: the latest scheduled arrival (keeps FIFO);
    ``count``: messages offered so far (the loss model's counter); ``bad``: burst state.
    """

    t_last: float = -math.inf
    tokens: float = math.inf
    departures: tuple = ()
    t_last_received: float = -math.inf
    count: int = 0
    bad: bool = False


@dc.dataclass(frozen=True, eq=False)
class LinkState:
    """What a link holds: messages in flight (with their delivery times), the last
    ``history`` deliveries per topic, the newest accepted ``seq`` per topic, channel
    states, and the ledger of delivered and dropped messages."""

    in_flight: tuple = ()
    delivered: dict = dc.field(default_factory=dict)
    last_seq: dict = dc.field(default_factory=dict)
    channels: dict = dc.field(default_factory=dict)
    ledger: Ledger = dc.field(default_factory=Ledger)

    def __deepcopy__(self, memo):
        return self


def _in_outage(t: float, outages) -> bool:
    return any(w.start_s <= t < w.end_s for w in outages)


def _uniforms(seed: int, name: str, index: int, n: int):
    """``n`` uniforms in [0, 1) for draw ``index`` of the stream ``name`` under ``seed``."""
    u = rng.hash_uniform(rng.stream_key(seed, name), int(index) % (1 << 31), list(range(n)))
    return [float(x) for x in u]


def accept(
    state: LinkState,
    messages,
    *,
    config: LinkConfig,
    now_s: float,
    direction: str = "link",
    seed: int = 0,
    earth_visible: bool = True,
    light_time_s: float | None = None,
) -> LinkState:
    """The state after the link takes ``messages`` at ``now_s`` (those newer than the
    last accepted of their topic; older ones were already taken): each is queued on its
    channel, refused, lost, or scheduled for delivery (module docstring). A message is
    never delivered before ``now_s``. ``earth_visible`` False (the Earth below the
    terrain horizon at the rover, as of ``now_s``) loses every message taken now
    (``no_line_of_sight``; for the uplink the visibility at reception is approximated
    by the visibility now, 1-3 s earlier)."""
    last = dict(state.last_seq)
    chans = dict(state.channels)
    new = []
    ledger = state.ledger
    for m in messages:
        if m.seq <= last.get(m.topic, -1):
            continue
        last[m.topic] = m.seq
        ch = config.channel_of(m.topic)
        cs = chans.get(ch.name, ChannelState())
        size = int(config.payload_bytes.get(m.topic, m.size_bytes))
        t_arrive = float(m.t_sent_s)
        waiting = tuple(d for d in cs.departures if d[0] > now_s)
        queued = sum(b for _, b in waiting)
        reason = ""
        if size > ch.bucket_bytes:
            reason = "oversize"
        elif queued + size > ch.queue_limit_bytes:
            reason = "queue_full"
        if reason:
            chans[ch.name] = dc.replace(cs, departures=waiting)
            ledger = ledger.append(_record(m, size, math.nan, direction, ch.name, reason))
            continue
        # Token bucket, FIFO: the departure is fixed now.
        t_ready = max(t_arrive, cs.t_last)
        if cs.t_last == -math.inf:  # the bucket starts full
            tokens = float(ch.bucket_bytes)
        else:
            tokens = min(float(ch.bucket_bytes), cs.tokens + accrued_bytes(ch, cs.t_last, t_ready))
        if tokens >= size:
            t_dep, left = t_ready, tokens - size
        else:
            t_dep, left = time_to_accrue(ch, t_ready, size - tokens), 0.0
        # Random loss (burst model) and jitter: keyed per message, same seed same draws.
        u_state, u_loss = _uniforms(seed, f"link/{direction}/{ch.name}/loss", cs.count, 2)
        bad = cs.bad
        lost = False
        if not config.loss.lossless:
            bad = (
                (u_state >= config.loss.p_leave_bad) if bad else (u_state < config.loss.p_enter_bad)
            )
            lost = u_loss < (config.loss.loss_bad if bad else config.loss.loss_good)
        delay = config.one_way_delay_s(m.topic, light_time_s=light_time_s)
        if config.jitter_s > 0.0:
            (u_j,) = _uniforms(seed, f"link/{direction}/{m.topic}/jitter", m.seq, 1)
            delay += config.jitter_s * u_j
        due = max(t_dep + delay, cs.t_last_received, now_s)
        rover_time = t_dep if direction == "downlink" else due
        if _in_outage(rover_time, config.outages):
            reason = "outage"
        elif not earth_visible:
            reason = "no_line_of_sight"
        elif lost:
            reason = "loss"
        cs = ChannelState(
            t_last=t_dep,
            tokens=left,
            departures=(*waiting, (t_dep, size)),
            t_last_received=cs.t_last_received if reason else due,
            count=cs.count + 1,
            bad=bad,
        )
        chans[ch.name] = cs
        if reason:
            ledger = ledger.append(_record(m, size, math.nan, direction, ch.name, reason))
        else:
            new.append((Delivery(message=m, t_received_s=due), ch.name, size))
    if not new and ledger is state.ledger and last == state.last_seq:
        return state
    return dc.replace(
        state, in_flight=state.in_flight + tuple(new), last_seq=last, channels=chans,
        ledger=ledger,
    )  # fmt: skip


def _segments(ch: ChannelConfig) -> list:
    """[(start_s, bytes per second), ...] of a channel's rate, the first from -inf."""
    return [(-math.inf, ch.bandwidth_bps / 8.0)] + [
        (float(r.start_s), r.bandwidth_bps / 8.0) for r in ch.schedule
    ]


def accrued_bytes(ch: ChannelConfig, t0: float, t1: float) -> float:
    """Tokens (bytes) a channel's rate adds over ``[t0, t1]`` (its schedule's integral)."""
    if t1 <= t0:
        return 0.0
    seg = _segments(ch)
    total = 0.0
    for k, (start, rate) in enumerate(seg):
        end = seg[k + 1][0] if k + 1 < len(seg) else math.inf
        lo, hi = max(t0, start), min(t1, end)
        if hi > lo:
            total += rate * (hi - lo)
    return total


def time_to_accrue(ch: ChannelConfig, t0: float, amount: float) -> float:
    """The first time ``t >= t0`` by which the channel's rate has added ``amount``
    bytes since ``t0``."""
    seg = _segments(ch)
    need = float(amount)
    for k, (start, rate) in enumerate(seg):
        end = seg[k + 1][0] if k + 1 < len(seg) else math.inf
        lo = max(t0, start)
        if end <= lo:
            continue
        if rate * (end - lo) >= need:
            return lo + need / rate
        need -= rate * (end - lo)
    return math.inf  # not reached: the last segment is open-ended with rate > 0


def _due(t_received_s: float, now_s: float) -> bool:
    # Delivery times are sums of floats; compare with a relative tolerance so a delivery
    # due exactly now is not missed by rounding.
    return t_received_s <= now_s + 1e-12 * max(1.0, abs(now_s))


def deliver(state: LinkState, now_s: float, *, direction: str, history: int) -> LinkState:
    """The state after every message due by ``now_s`` moved from in flight to delivered
    (keeping the last ``history`` per topic) and into the ledger."""
    due = [f for f in state.in_flight if _due(f[0].t_received_s, now_s)]
    if not due:
        return state
    due.sort(key=lambda f: f[0].t_received_s)
    delivered = dict(state.delivered)
    ledger = state.ledger
    for d, channel, size in due:
        m = d.message
        delivered[m.topic] = (*delivered.get(m.topic, ()), d)[-history:]
        ledger = ledger.append(_record(m, size, d.t_received_s, direction, channel, ""))
    rest = tuple(f for f in state.in_flight if not _due(f[0].t_received_s, now_s))
    return dc.replace(state, in_flight=rest, delivered=delivered, ledger=ledger)


def inbox(state: LinkState, topic: str, now_s: float, *, history: int) -> tuple:
    """The last ``history`` deliveries of ``topic`` by ``now_s`` (oldest first),
    including messages that came due since the state was last updated."""
    done = state.delivered.get(topic, ())
    due = sorted(
        (f[0] for f in state.in_flight
         if f[0].message.topic == topic and _due(f[0].t_received_s, now_s)),
        key=lambda d: d.t_received_s,
    )  # fmt: skip
    return (done + tuple(due))[-history:]


def records(state: LinkState, now_s: float, *, direction: str) -> list:
    """Every message the link has handled by ``now_s`` (delivered in delivery order,
    dropped when dropped), then those still in flight (``t_received`` NaN)."""
    state = deliver(state, now_s, direction=direction, history=1)
    rows = state.ledger.items()
    rows.extend(
        _record(d.message, size, math.nan, direction, channel, "")
        for d, channel, size in state.in_flight
    )
    return rows


#: Fields of :func:`statistics` (and the Link system's ``statistics`` output).
LINK_STAT_FIELDS = ("offered", "delivered", "dropped", "in_flight", "queued_bytes")


def statistics(state: LinkState, now_s: float) -> tuple:
    """(offered, delivered, dropped, in flight, bytes waiting to depart) at ``now_s``."""
    rows = state.ledger.items()
    dropped = sum(1 for r in rows if r.dropped)
    due = sum(1 for f in state.in_flight if _due(f[0].t_received_s, now_s))
    in_flight = len(state.in_flight) - due
    delivered = len(rows) - dropped + due
    queued = sum(b for cs in state.channels.values() for t, b in cs.departures if t > now_s)
    return (delivered + dropped + in_flight, delivered, dropped, in_flight, queued)


def _record(m: Message, size: int, t_received: float, direction, channel, reason) -> LinkRecord:
    """The ledger row of message ``m`` (``t_received`` NaN: dropped or in flight)."""
    return LinkRecord(
        direction=direction,
        channel=channel,
        topic=m.topic,
        seq=m.seq,
        bytes=int(size),
        t_sent=m.t_sent_s,
        t_received=t_received,
        dropped=bool(reason),
        reason=reason,
    )


__all__ = [
    "DROP_REASONS",
    "LINK_RECORD_FIELDS",
    "LINK_STAT_FIELDS",
    "BurstLossConfig",
    "ChannelConfig",
    "ChannelState",
    "LinkConfig",
    "LinkRecord",
    "LinkState",
    "Message",
    "OutageWindow",
    "RateStep",
    "accept",
    "accrued_bytes",
    "deliver",
    "inbox",
    "records",
    "statistics",
    "time_to_accrue",
]
