"""Telemetry: the flight packetizer (rover -> downlink) and the ground receiver."""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy.telemetry import TELEMETRY_FIELDS, pack_telemetry
from lunar_drake.comms.messages import Ledger, Message, payload_size_bytes
from lunar_drake.systems.leaf import Leaf

TOPIC = "telemetry"


class TelemetryPacketizer(Leaf):
    """Flight: packs the rover's housekeeping into a telemetry message at ``rate_hz``.

    .. pydrake_system::

        name: TelemetryPacketizer
        input_ports:
        - pose_estimate
        - twist_command
        - brake_command
        - status
        output_ports:
        - telemetry

    ``telemetry`` is an outbox (a tuple holding the message made at the latest update;
    topic ``telemetry``, seq = update count, payload a float64 vector of
    :data:`~lunar_drake.autonomy.telemetry.TELEMETRY_FIELDS`). Inputs are flight
    signals only (estimate, commands, executor status; with ``power``, the power
    sensor's state of charge and array power).
    """

    def __init__(self, *, rate_hz: float, power: bool = False):
        super().__init__()
        self._rate = float(rate_hz)
        self.pose_estimate_input = self.DeclareVectorInputPort("pose_estimate", 6)
        self.twist_input = self.DeclareVectorInputPort("twist_command", 3)
        self.brake_input = self.DeclareVectorInputPort("brake_command", 1)
        self.status_input = self.DeclareVectorInputPort("status", 5)
        self.power_input = self.DeclareVectorInputPort("power", 3) if power else None
        self._outbox = self.DeclareAbstractState(AbstractValue.Make(()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / self._rate, 0.0, self._update)
        self.telemetry_output = self.DeclareStateOutputPort("telemetry", self._outbox)

    def _update(self, context, state):
        t = context.get_time()
        payload = pack_telemetry(
            pose_estimate=self.pose_estimate_input.Eval(context),
            twist_command=self.twist_input.Eval(context),
            brake=self.brake_input.Eval(context)[0],
            status=self.status_input.Eval(context),
            power=self.power_input.Eval(context) if self.power_input else None,
        )
        payload.setflags(write=False)
        msg = Message(
            topic=TOPIC,
            seq=round(t * self._rate),
            t_sent_s=t,
            payload=payload,
            size_bytes=payload_size_bytes(payload),
        )
        state.get_mutable_abstract_state(self._outbox).set_value((msg,))


class TelemetryReceiver(Leaf):
    """Ground: takes in the telemetry the downlink delivered, in order, once each.

    .. pydrake_system::

        name: TelemetryReceiver
        input_ports:
        - telemetry
        output_ports:
        - telemetry
        - t_received

    ``telemetry`` (input) is the downlink inbox. Every 1 / ``rate_hz`` s deliveries newer
    than the last handled are appended to the received ledger (abstract state; read it
    with :meth:`received`). Outputs: the newest received packet (``TELEMETRY_FIELDS``,
    zeros before the first) and its reception time (s; -1 before the first).
    """

    def __init__(self, *, rate_hz: float):
        super().__init__()
        n = len(TELEMETRY_FIELDS)
        self.telemetry_input = self.DeclareAbstractInputPort(TOPIC, AbstractValue.Make(()))
        self._ledger = self.DeclareAbstractState(AbstractValue.Make(Ledger()))
        # [newest seq, t_received, packet (n)]
        self._latest = self.DeclareDiscreteState(BasicVector(np.r_[-1.0, -1.0, np.zeros(n)]))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        xd = {self.xd_ticket()}
        self.telemetry_output = self.DeclareVectorOutputPort(
            TOPIC,
            BasicVector(n),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._latest).get_value()[2:]),
            prerequisites_of_calc=xd,
        )
        self.t_received_output = self.DeclareVectorOutputPort(
            "t_received",
            BasicVector(1),
            lambda c, o: o.SetFromVector(c.get_discrete_state(self._latest).get_value()[1:2]),
            prerequisites_of_calc=xd,
        )

    def received(self, context) -> list:
        """Every delivery handled so far (oldest first), in this system's context."""
        return context.get_abstract_state(self._ledger).get_value().items()

    def received_since(self, context, n: int) -> list:
        """The deliveries after the first ``n`` (oldest first; a live display's news)."""
        return context.get_abstract_state(self._ledger).get_value().since(n)

    def _update(self, context, state):
        latest = context.get_discrete_state(self._latest).get_value()
        last = latest[0]
        ledger = context.get_abstract_state(self._ledger).get_value()
        new = [d for d in self.telemetry_input.Eval(context) if d.message.seq > last]
        if not new:
            return
        for d in new:
            ledger = ledger.append(d)
        d = new[-1]
        state.get_mutable_abstract_state(self._ledger).set_value(ledger)
        state.get_mutable_discrete_state().get_mutable_vector(self._latest).SetFromVector(
            np.r_[float(d.message.seq), d.t_received_s, d.message.payload]
        )
