"""SciencePacketizer (flight) and ScienceReceiver (ground): instrument records over the
downlink (:mod:`lunar_drake.comms.science`)."""

from __future__ import annotations

import dataclasses as dc
import math

from pydrake.common.value import AbstractValue

from lunar_drake.comms.messages import Message
from lunar_drake.comms.science import TOPIC, ScienceRecord
from lunar_drake.sensors.sampling import delivered_index
from lunar_drake.systems.leaf import Leaf
from lunar_drake.systems.receiver import TopicReceiver

#: How often the packetizer looks for new instrument samples (s).
TICK_S = 0.1


@dc.dataclass(frozen=True)
class Instrument:
    """An instrument the packetizer serves: its ``name`` (the record's ``instrument``
    and the input port ``rover.<name>``), ``n_values``, and its sampling (Hz, s);
    ``rate_hz`` 0: an event instrument whose values start with its sample count and end
    with the sample's time (the drill)."""

    name: str
    n_values: int
    rate_hz: float
    delay_s: float


class SciencePacketizer(Leaf):
    """Flight: one ``science`` message per new instrument sample.

    .. pydrake_system::

        name: SciencePacketizer
        input_ports:
        - rover.<instrument> (one per instrument)
        - pose_estimate
        output_ports:
        - science

    Every :data:`TICK_S` s (from 1 us) each instrument's newest delivered sample (index
    from its ``rate_hz`` and ``delay_s``), if not sent yet, goes into the outbox
    ``science`` (a tuple of the messages of this tick; seq counts every record sent) as a
    :class:`~lunar_drake.comms.science.ScienceRecord` with the on-board
    ``pose_estimate`` (6,). State (abstract): (last index sent per instrument, records
    sent, outbox).
    """

    def __init__(self, *, instruments):
        super().__init__()
        self._instruments = tuple(instruments)
        self.values_inputs = {
            i.name: self.DeclareVectorInputPort(f"rover.{i.name}", i.n_values)
            for i in self._instruments
        }
        self.pose_input = self.DeclareVectorInputPort("pose_estimate", 6)
        start = ((-1,) * len(self._instruments), 0, ())
        self._state = self.DeclareAbstractState(AbstractValue.Make(start))
        self.DeclarePeriodicUnrestrictedUpdateEvent(TICK_S, 1e-6, self._update)
        self.science_output = self.DeclareAbstractOutputPort(
            TOPIC,
            lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(c.get_abstract_state(self._state).get_value()[2]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def _update(self, context, state):
        last, sent, previous = context.get_abstract_state(self._state).get_value()
        t = context.get_time()
        new_last, out = list(last), []
        for n, inst in enumerate(self._instruments):
            values = None
            if inst.rate_hz > 0:
                k = delivered_index(t, rate_hz=inst.rate_hz, delay_s=inst.delay_s)
                t_sample, dt = k / inst.rate_hz, 1.0 / inst.rate_hz
            else:  # event instrument: values = (count, ..., time of the sample)
                values = tuple(float(v) for v in self.values_inputs[inst.name].Eval(context))
                k, t_sample, dt = int(values[0]) - 1, values[-1], 0.0
            if k < 0 or k == last[n]:
                continue
            if values is None:
                values = tuple(float(v) for v in self.values_inputs[inst.name].Eval(context))
            pose = tuple(float(v) for v in self.pose_input.Eval(context))
            record = ScienceRecord(
                instrument=inst.name,
                index=k,
                t_sample_s=t_sample,
                values=values,
                integration_s=dt,
                pose_estimate=pose if all(math.isfinite(v) for v in pose) else (math.nan,) * 6,
            )
            out.append(Message(topic=TOPIC, seq=sent, t_sent_s=t, payload=record,
                               size_bytes=record.size_bytes()))  # fmt: skip
            new_last[n], sent = k, sent + 1
        if out or previous:
            state.get_mutable_abstract_state(self._state).set_value(
                (tuple(new_last), sent, tuple(out))
            )


class ScienceReceiver(TopicReceiver):
    """Ground: takes in the science records the downlink delivered, once each, in seq
    order (:class:`~lunar_drake.systems.receiver.TopicReceiver` of ``science``;
    ``records_received`` (1,) counts them)."""

    def __init__(self, *, rate_hz: float):
        super().__init__(topic=TOPIC, count_name="records_received", rate_hz=rate_hz,
                         by_seq=True)  # fmt: skip
        self.science_input = self.inbox_input
        self.records_received_output = self.count_output
