"""Link: one direction of the Earth-Moon link (uplink or downlink) as a Drake system."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lunar_drake.comms import link as core
from lunar_drake.comms.link import LinkConfig

#: Offset (s) of the link's polls after its producers' updates, so a message created at
#: t is taken at t + POLL_OFFSET_S (and delivered, from its own creation time, at
#: t + delay_s exactly whenever delay_s >= POLL_OFFSET_S).
POLL_OFFSET_S = 1.0e-6


class Link(LeafSystem):
    """Carries messages of named topics from producers to consumers.

    .. pydrake_system::

        name: Link
        input_ports:
        - <topic> (one per topic)
        output_ports:
        - <topic> (one per topic)

    Each input is a producer's *outbox* (a tuple of
    :class:`~lunar_drake.comms.messages.Message`, the messages it created at its latest
    update). The link polls each topic ``POLL_OFFSET_S`` after every update of its
    producer (``topics`` gives the producer's period) and schedules every new message
    for delivery at its creation time plus ``config.delay_s`` -- exact for any delay of
    at least ``POLL_OFFSET_S`` (1 us); a shorter delay delivers at the poll. Each output is the
    topic's *inbox*: a tuple of the last ``history`` deliveries
    (:class:`~lunar_drake.comms.messages.Delivery`), oldest first, exact at any
    evaluation time. State (abstract): the :class:`~lunar_drake.comms.link.LinkState`.

    Args:
        direction: ``uplink`` or ``downlink`` (a label in the records).
        topics: topic name -> period (s) of its producer's updates.
        config: :class:`~lunar_drake.comms.link.LinkConfig`.
        history: deliveries kept per topic in the inbox.
    """

    def __init__(self, *, direction: str, topics: dict, config: LinkConfig, history: int = 64):
        super().__init__()
        config.validate()
        self._direction = direction
        self._config = config
        self._history = int(history)
        self._topics = dict(topics)
        self._state = self.DeclareAbstractState(AbstractValue.Make(core.LinkState()))
        self.inputs = {}
        self.outputs = {}
        for topic in self._topics:
            self.inputs[topic] = self.DeclareAbstractInputPort(topic, AbstractValue.Make(()))
        for period in sorted(set(self._topics.values())):
            self.DeclarePeriodicUnrestrictedUpdateEvent(
                period, POLL_OFFSET_S, lambda c, s, p=period: self._poll(c, s, p)
            )
        for topic in self._topics:
            self.outputs[topic] = self.DeclareAbstractOutputPort(
                topic,
                lambda: AbstractValue.Make(()),
                lambda c, o, t=topic: o.set_value(self.inbox(c, t)),
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
        return core.records(
            self.link_state(context),
            context.get_time(),
            direction=self._direction,
            channel="main",
        )

    def _poll(self, context, state, period):
        s = self.link_state(context)
        for topic, p in self._topics.items():
            if p == period:
                s = core.accept(
                    s,
                    self.inputs[topic].Eval(context),
                    delay_s=self._config.delay_s,
                    now_s=context.get_time(),
                )
        s = core.deliver(
            s,
            context.get_time(),
            direction=self._direction,
            channel="main",
            history=self._history,
        )
        state.get_mutable_abstract_state(self._state).set_value(s)
