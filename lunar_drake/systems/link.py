"""Link: one direction of the Earth-Moon link (uplink or downlink) as a Drake system."""

from __future__ import annotations

from pydrake.common.value import AbstractValue

from lunar_drake.comms import link as core
from lunar_drake.comms.link import LinkConfig
from lunar_drake.systems.leaf import Leaf

#: Offset (s) of the link's polls after its producers' updates, so a message created at
#: t is taken at t + POLL_OFFSET_S (and delivered, from its own creation time, at
#: t + delay_s exactly whenever delay_s >= POLL_OFFSET_S).
POLL_OFFSET_S = 1.0e-6


class Link(Leaf):
    """Carries messages of named topics from producers to consumers.

    .. pydrake_system::

        name: Link
        input_ports:
        - <topic> (one per topic)
        - earth_visible (optional)
        output_ports:
        - <topic> (one per topic)
        - statistics

    Each input is a producer's *outbox* (a tuple of
    :class:`~lunar_drake.comms.messages.Message`, the messages it created at its latest
    update). The link polls each topic ``POLL_OFFSET_S`` after every update of its
    producer (``topics`` gives the producer's period) and queues, drops or schedules
    every new message (:mod:`lunar_drake.comms.link`: channels, token buckets, delay,
    jitter, losses); on an idle channel a message is delivered at its creation time
    plus its delay -- exact for any delay of at least ``POLL_OFFSET_S`` (1 us); a
    shorter delay delivers at the poll. ``earth_visible`` (1/0; unconnected: always
    in view) is the plant's line of sight to Earth: messages taken while it is 0 are
    lost. ``statistics`` outputs
    :data:`~lunar_drake.comms.link.LINK_STAT_FIELDS` at the context's time. Each output is the
    topic's *inbox*: a tuple of the last ``history`` deliveries
    (:class:`~lunar_drake.comms.messages.Delivery`), oldest first, exact at any
    evaluation time. State (abstract): the :class:`~lunar_drake.comms.link.LinkState`.

    Args:
        direction: ``uplink`` or ``downlink`` (a label in the records).
        topics: topic name -> period (s) of its producer's updates, or (period, offset)
            for a producer whose updates start at ``offset`` (s).
        config: :class:`~lunar_drake.comms.link.LinkConfig`.
        history: deliveries kept per topic in the inbox.
        seed: the scenario's random seed (jitter and loss draws).
        light_time_s: the one-way light time (s) used when ``config.delay_s`` is None
            (:func:`~lunar_drake.comms.light_time.light_time_s`).
    """

    def __init__(
        self,
        *,
        direction: str,
        topics: dict,
        config: LinkConfig,
        history: int = 64,
        seed: int = 0,
        light_time_s: float | None = None,
    ):
        super().__init__()
        config.validate()
        self._seed = int(seed)
        self._light_time_s = light_time_s
        self._direction = direction
        self._config = config
        self._history = int(history)
        self._topics = {
            t: (float(v[0]), float(v[1])) if isinstance(v, tuple) else (float(v), 0.0)
            for t, v in topics.items()
        }
        self._state = self.DeclareAbstractState(AbstractValue.Make(core.LinkState()))
        self.inputs = {}
        self.outputs = {}
        for topic in self._topics:
            self.inputs[topic] = self.DeclareAbstractInputPort(topic, AbstractValue.Make(()))
        self.earth_visible_input = self.DeclareVectorInputPort("earth_visible", 1)
        for period, offset in sorted(set(self._topics.values())):
            self.DeclarePeriodicUnrestrictedUpdateEvent(
                period,
                offset + POLL_OFFSET_S,
                lambda c, s, p=(period, offset): self._poll(c, s, p),
            )
        for topic in self._topics:
            self.outputs[topic] = self.DeclareAbstractOutputPort(
                topic,
                lambda: AbstractValue.Make(()),
                lambda c, o, t=topic: o.set_value(self.inbox(c, t)),
                prerequisites_of_calc={self.time_ticket(), self.all_state_ticket()},
            )
        self.statistics_output = self.DeclareVectorOutputPort(
            "statistics",
            len(core.LINK_STAT_FIELDS),
            lambda c, o: o.SetFromVector(core.statistics(self.link_state(c), c.get_time())),
            prerequisites_of_calc={self.time_ticket(), self.all_state_ticket()},
        )

    @property
    def config(self) -> LinkConfig:
        """The link's configuration."""
        return self._config

    @property
    def direction(self) -> str:
        """``uplink`` or ``downlink``."""
        return self._direction

    def link_state(self, context) -> core.LinkState:
        """The LinkState in ``context`` (this system's context)."""
        return context.get_abstract_state(self._state).get_value()

    def inbox(self, context, topic: str) -> tuple:
        """The deliveries of ``topic`` available at the context's time."""
        return core.inbox(
            self.link_state(context), topic, context.get_time(), history=self._history
        )

    def records(self, context) -> list:
        """Every message carried so far (:class:`~lunar_drake.comms.link.LinkRecord`)."""
        return core.records(self.link_state(context), context.get_time(), direction=self._direction)

    def _poll(self, context, state, period):
        # From `state`, not the context: polls of other topics due at the same instant
        # have already written theirs there.
        s = state.get_abstract_state(self._state).get_value()
        port = self.earth_visible_input
        visible = not port.HasValue(context) or port.Eval(context)[0] > 0.5
        for topic, p in self._topics.items():
            if p == period:
                s = core.accept(
                    s,
                    self.inputs[topic].Eval(context),
                    config=self._config,
                    now_s=context.get_time(),
                    direction=self._direction,
                    seed=self._seed,
                    earth_visible=visible,
                    light_time_s=self._light_time_s,
                )
        s = core.deliver(s, context.get_time(), direction=self._direction, history=self._history)
        state.get_mutable_abstract_state(self._state).set_value(s)
