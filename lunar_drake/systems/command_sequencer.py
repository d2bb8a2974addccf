"""CommandSequencer (ground "operator command source"): the route as uplink commands."""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lunar_drake.comms.messages import Message, payload_size_bytes

TOPIC = "commands"


class CommandSequencer(LeafSystem):
    """Sends a fixed command sequence, one command per ground tick from t = 0.

    .. pydrake_system::

        name: CommandSequencer
        output_ports:
        - commands

    ``commands`` is an outbox (a tuple holding the message made at the latest tick,
    empty when nothing was sent); topic ``commands``, seq 0, 1, ... in order. State
    (abstract): (index of the next command, outbox).

    Args:
        commands: the commands (e.g. :class:`~lunar_drake.autonomy.commands.DriveCommand`)
            in the order to send. rate_hz: ground software tick (Hz).
    """

    def __init__(self, *, commands, rate_hz: float):
        super().__init__()
        self._commands = tuple(commands)
        self._state = self.DeclareAbstractState(AbstractValue.Make((0, ())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.commands_output = self.DeclareAbstractOutputPort(
            TOPIC,
            lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(c.get_abstract_state(self._state).get_value()[1]),
            prerequisites_of_calc={self.all_state_ticket()},
        )

    def _update(self, context, state):
        k, _ = context.get_abstract_state(self._state).get_value()
        outbox = ()
        if k < len(self._commands):
            cmd = self._commands[k]
            outbox = (
                Message(
                    topic=TOPIC,
                    seq=k,
                    t_sent_s=context.get_time(),
                    payload=cmd,
                    size_bytes=payload_size_bytes(cmd),
                ),
            )
            k += 1
        state.get_mutable_abstract_state(self._state).set_value((k, outbox))
