"""SciencePacketizer (flight) and ScienceReceiver (ground): instrument records over the
downlink (:mod:`lunar_drake.comms.science`)."""

from __future__ import annotations

import math

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem

from lunar_drake.comms.messages import Ledger, Message
from lunar_drake.comms.science import TOPIC, ScienceRecord
from lunar_drake.sensors.sampling import delivered_index


class SciencePacketizer(LeafSystem):
    """Flight: one ``science`` message per new instrument sample.

    .. pydrake_system::

        name: SciencePacketizer
        input_ports:
        - counts
        - pose_estimate
        output_ports:
        - science

    Every sample period, just after a sample is delivered (``offset_s``), the newest
    delivered sample (index from the instrument's ``rate_hz`` and ``delay_s``) goes into
    the outbox ``science`` (a tuple with the newest message; seq = the sample index) as
    a :class:`~lunar_drake.comms.science.ScienceRecord` with the on-board
    ``pose_estimate`` (6,). State (abstract): (last index sent, outbox).
    """

    def __init__(self, *, instrument: str, n_values: int, rate_hz: float, delay_s: float):
        super().__init__()
        self._instrument = instrument
        self._rate, self._delay = float(rate_hz), float(delay_s)
        period = 1.0 / self._rate
        self.values_input = self.DeclareVectorInputPort("counts", n_values)
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self._state = self.DeclareAbstractState(AbstractValue.Make((-1, ())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, (self._delay % period) + 1e-6,
                                                    self._update)  # fmt: skip
        self.science_output = self.DeclareAbstractOutputPort(
            TOPIC,
            lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(c.get_abstract_state(self._state).get_value()[1]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def _update(self, context, state):
        last, previous = context.get_abstract_state(self._state).get_value()
        k = delivered_index(context.get_time(), rate_hz=self._rate, delay_s=self._delay)
        if k < 0 or k == last:
            if previous:
                state.get_mutable_abstract_state(self._state).set_value((last, ()))
            return
        pose = tuple(float(v) for v in self.pose_input.Eval(context))
        record = ScienceRecord(
            instrument=self._instrument,
            index=k,
            t_sample_s=k / self._rate,
            values=tuple(float(v) for v in self.values_input.Eval(context)),
            integration_s=1.0 / self._rate,
            pose_estimate=pose if all(math.isfinite(v) for v in pose) else (math.nan,) * 6,
        )
        msg = Message(topic=TOPIC, seq=k, t_sent_s=context.get_time(), payload=record,
                      size_bytes=record.size_bytes())  # fmt: skip
        state.get_mutable_abstract_state(self._state).set_value((k, (msg,)))


class ScienceReceiver(LeafSystem):
    """Ground: takes in the science records the downlink delivered, once each.

    .. pydrake_system::

        name: ScienceReceiver
        input_ports:
        - science
        output_ports:
        - records_received

    Every 1 / ``rate_hz`` s deliveries newer than the last handled are appended to the
    received ledger (abstract state; :meth:`received`).
    """

    def __init__(self, *, rate_hz: float):
        super().__init__()
        self.science_input = self.DeclareAbstractInputPort(TOPIC, AbstractValue.Make(()))
        self._ledger = self.DeclareAbstractState(AbstractValue.Make((-1, Ledger())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.records_received_output = self.DeclareVectorOutputPort(
            "records_received",
            BasicVector(1),
            lambda c, o: o.SetFromVector([len(c.get_abstract_state(self._ledger).get_value()[1])]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def received(self, context) -> list:
        """Every delivery handled so far (oldest first), in this system's context."""
        return context.get_abstract_state(self._ledger).get_value()[1].items()

    def _update(self, context, state):
        last, ledger = context.get_abstract_state(self._ledger).get_value()
        new = [d for d in self.science_input.Eval(context) if d.message.seq > last]
        if not new:
            return
        for d in sorted(new, key=lambda d: d.message.seq):
            ledger = ledger.append(d)
        state.get_mutable_abstract_state(self._ledger).set_value((ledger.items()[-1].message.seq,
                                                                   ledger))  # fmt: skip
