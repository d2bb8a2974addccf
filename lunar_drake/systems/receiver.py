"""TopicReceiver: the ground's intake of one downlink topic (received once each)."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.comms.messages import Ledger
from lunar_drake.systems.leaf import Leaf


class TopicReceiver(Leaf):
    """Ground: takes in the messages of one topic the downlink delivered, once each.

    .. pydrake_system::

        name: TopicReceiver
        input_ports:
        - <topic>
        output_ports:
        - <count_name>

    Every 1 / ``rate_hz`` s deliveries newer (by seq) than the last handled are appended
    to the received ledger (abstract state; :meth:`received`), in delivery order or,
    with ``by_seq``, in seq order; ``<count_name>`` (1,) counts them.
    """

    def __init__(self, *, topic: str, count_name: str, rate_hz: float, by_seq: bool = False):
        super().__init__()
        self._by_seq = by_seq
        self.inbox_input = self.DeclareAbstractInputPort(topic, AbstractValue.Make(()))
        self._ledger = self.DeclareAbstractState(AbstractValue.Make((-1, Ledger())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.count_output = self.DeclareVectorOutputPort(
            count_name,
            BasicVector(1),
            lambda c, o: o.SetFromVector([len(c.get_abstract_state(self._ledger).get_value()[1])]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def received(self, context) -> list:
        """Every delivery handled so far (oldest first), in this system's context."""
        return context.get_abstract_state(self._ledger).get_value()[1].items()

    def received_since(self, context, n: int) -> list:
        """The deliveries after the first ``n`` (oldest first; a live display's news)."""
        return context.get_abstract_state(self._ledger).get_value()[1].since(n)

    def received_count(self, context) -> int:
        """How many deliveries were handled so far."""
        return len(context.get_abstract_state(self._ledger).get_value()[1])

    def _update(self, context, state):
        last, ledger = context.get_abstract_state(self._ledger).get_value()
        new = [d for d in self.inbox_input.Eval(context) if d.message.seq > last]
        if not new:
            return
        if self._by_seq:
            new.sort(key=lambda d: d.message.seq)
        for d in new:
            ledger = ledger.append(d)
        state.get_mutable_abstract_state(self._ledger).set_value((new[-1].message.seq, ledger))
