"""Messages that cross the link, and the append-only ledger that logs them.

A producer (flight telemetry, ground commands) publishes an *outbox*: the tuple of
messages it created at its latest update. A link carries them and publishes an *inbox*
per topic: the most recent deliveries, oldest first. Consumers act on deliveries whose
``seq`` is newer than the last they handled. Messages, deliveries and ledgers are
immutable; ``copy.deepcopy`` returns them as they are, so keeping them in Drake abstract
state costs nothing per update.
"""

from __future__ import annotations

import dataclasses as dc

import numpy as np


@dc.dataclass(frozen=True, eq=False)
class Message:
    """One message.

    Attributes:
        topic: what it carries (``telemetry``, ``commands``).
        seq: per-topic sequence number, 0, 1, 2, ... in order of creation.
        t_sent_s: simulation time the producer created it (s).
        payload: a numpy vector or a command (treated as immutable).
        size_bytes: payload size as sent (bytes).
    """

    topic: str
    seq: int
    t_sent_s: float
    payload: object
    size_bytes: int

    def __deepcopy__(self, memo):
        return self


@dc.dataclass(frozen=True, eq=False)
class Delivery:
    """A message as received: ``t_received_s`` is the simulation time of delivery (s)."""

    message: Message
    t_received_s: float

    def __deepcopy__(self, memo):
        return self


def payload_size_bytes(payload) -> int:
    """Size of a payload as sent: a numpy array's bytes, or the payload's own
    ``size_bytes()`` (commands)."""
    if isinstance(payload, np.ndarray):
        return int(payload.nbytes)
    return int(payload.size_bytes())


class Ledger:
    """An immutable append-only log: ``append`` returns a new ledger in O(1), sharing
    the old one; ``copy.deepcopy`` returns the ledger itself."""

    __slots__ = ("_item", "_len", "_prev")

    def __init__(self, _prev: Ledger | None = None, _item=None, _len: int = 0):
        self._prev = _prev
        self._item = _item
        self._len = _len

    def append(self, item) -> Ledger:
        """A ledger with ``item`` added at the end."""
        return Ledger(self, item, self._len + 1)

    def __len__(self) -> int:
        return self._len

    def items(self) -> list:
        """Every item, oldest first."""
        out = []
        node = self
        while node._len:
            out.append(node._item)
            node = node._prev
        out.reverse()
        return out

    def since(self, n: int) -> list:
        """The items after the first ``n`` (oldest first), in O(len - n)."""
        out = []
        node = self
        while node._len > max(int(n), 0):
            out.append(node._item)
            node = node._prev
        out.reverse()
        return out

    def __copy__(self):
        return self

    def __deepcopy__(self, memo):
        return self
