"""Ctrl-C (SIGINT) bookkeeping shared by the CLI and :func:`lunar_drake.simulation.simulate`.

Python raises KeyboardInterrupt at whatever bytecode runs when SIGINT arrives. Inside an
import callback or a C++ callback that exception can be swallowed ("Exception ignored")
or turned into another error, and a half-imported extension can fail at interpreter exit.
So a SIGINT is also *latched* here: whoever installs :func:`raise_and_latch` as the
handler can later ask :func:`requested` whether Ctrl-C was pressed, whatever became of
the exception. Main thread only (Python delivers signals there).
"""

from __future__ import annotations

import os
import signal
import threading

_requested = False


def requested() -> bool:
    """True once a SIGINT reached :func:`raise_and_latch` since the last :func:`clear`."""
    return _requested


def clear() -> None:
    """Forgets a latched SIGINT."""
    global _requested
    _requested = False


def raise_and_latch(signum, frame):
    """SIGINT handler: latches the interrupt, then raises KeyboardInterrupt as Python's
    default handler does."""
    global _requested
    _requested = True
    raise KeyboardInterrupt


class LatchedSigint:
    """Installs :func:`raise_and_latch` for SIGINT (main thread only; elsewhere a no-op);
    ``restore()`` puts the previous handler back. The outermost installer owns the latch:
    its ``restore()`` also clears it (so a notebook's next run starts clean), while a
    nested one (``simulate()`` under the CLI) leaves it for the owner to see."""

    def __init__(self) -> None:
        self._installed = threading.current_thread() is threading.main_thread()
        self._owner = False
        if self._installed:
            self._previous = signal.signal(signal.SIGINT, raise_and_latch)
            self._owner = self._previous is not raise_and_latch
            if self._owner:
                clear()

    def restore(self) -> None:
        if self._installed:
            previous = self._previous
            signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)
            self._installed = False
            if self._owner:
                clear()


_terminated = False


def terminated() -> bool:
    """True once a SIGTERM reached a :class:`TermAsInterrupt` handler (until it is
    restored)."""
    return _terminated


class TermAsInterrupt:
    """Takes SIGTERM as Ctrl-C (:func:`raise_and_latch`) for the ``lunar-drake`` program,
    so that staged outputs are removed as after Ctrl-C; :func:`terminated` tells which it
    was. Main thread of this process only, and not where SIGTERM was ignored; a forked
    child (a drawing worker) gets the default handler back and dies as it would have.
    ``restore()`` puts the previous handler back."""

    def __init__(self) -> None:
        global _terminated
        _terminated = False
        self._pid = os.getpid()
        self._installed = False
        if threading.current_thread() is threading.main_thread():
            previous = signal.getsignal(signal.SIGTERM)
            if previous is not signal.SIG_IGN:
                self._previous = signal.signal(signal.SIGTERM, self._handle)
                self._installed = True

    def _handle(self, signum, frame):
        global _terminated
        if os.getpid() != self._pid:  # a forked child: die as by default
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        _terminated = True
        raise_and_latch(signum, frame)

    def restore(self) -> None:
        global _terminated
        if self._installed:
            previous = self._previous
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
            self._installed = False
        _terminated = False
