"""glibc's per-thread malloc cache, raised for simulation: the programs re-execute
themselves once with it.

A simulated step frees and allocates thousands of small blocks (Drake's contact solver,
caches and pybind11's conversions; ``callgrind``: 18 % of a no-camera mission's
instructions were in glibc's ``malloc`` and ``free``). glibc keeps at most 7 freed
blocks per size in each thread's cache (``tcache``); the rest go through its slower
bins, and ``malloc_consolidate``. With ``glibc.malloc.tcache_count`` at
:data:`TCACHE_COUNT` the same second of a no-camera mission runs 6.5 % fewer
instructions (221.0 M against 206.7 M, callgrind) and, measured alternately on this
machine, about 14 % less time. The results do not change: the allocator only decides
where blocks live.

glibc reads its tunables (``GLIBC_TUNABLES``) once, when a process starts, so
:func:`reexec_with_malloc_tunables` -- called first thing by the ``lunar-drake`` program
and the benchmarks -- starts the same command again with the tunable added, once. It
does nothing where the allocator is not glibc's, where ``GLIBC_TUNABLES`` already sets
``glibc.malloc.tcache_count`` (yours wins; ``./lunar.sh`` exports it, so everything it
runs starts with it), or with ``LUNAR_DRAKE_MALLOC=default``. A notebook or script that
wants the same starts Python with ``GLIBC_TUNABLES=glibc.malloc.tcache_count=1000``.
"""

from __future__ import annotations

import os
import platform
import sys

from lunar_drake.errors import ConfigError

__all__ = [
    "TCACHE_COUNT",
    "TCACHE_TUNABLE",
    "reexec_or_exit",
    "reexec_with_malloc_tunables",
    "tunables_to_set",
    "with_tcache",
]

#: Freed blocks glibc keeps per size class and thread (its default is 7).
TCACHE_COUNT = 1000
TCACHE_TUNABLE = "glibc.malloc.tcache_count"
#: ``LUNAR_DRAKE_MALLOC``: ``tuned`` (or unset) raises the cache, ``default`` keeps glibc's.
OPT_OUT_ENV = "LUNAR_DRAKE_MALLOC"
MALLOC_CHOICES = ("tuned", "default")


def with_tcache(tunables: str | None, *, count: int = TCACHE_COUNT) -> str | None:
    """``tunables`` (a ``GLIBC_TUNABLES`` value, ``name=value`` pairs joined by ``:``)
    with ``glibc.malloc.tcache_count=count`` added; None when it already sets that
    tunable (left as it is)."""
    pairs = [p for p in (tunables or "").split(":") if p]
    if any(p.split("=", 1)[0] == TCACHE_TUNABLE for p in pairs):
        return None
    return ":".join([*pairs, f"{TCACHE_TUNABLE}={int(count)}"])


def tunables_to_set(environ) -> str | None:
    """The ``GLIBC_TUNABLES`` value a process with environment ``environ`` should start
    with, or None to leave it as it is (not glibc, already set, opted out). Raises
    ConfigError for a ``LUNAR_DRAKE_MALLOC`` other than ``tuned`` or ``default``."""
    choice = environ.get(OPT_OUT_ENV, "").strip().lower() or "tuned"
    if choice not in MALLOC_CHOICES:
        raise ConfigError(
            f"{OPT_OUT_ENV} = {environ[OPT_OUT_ENV]!r}; choose one of {list(MALLOC_CHOICES)}"
        )
    if choice == "default":
        return None
    if sys.platform != "linux" or platform.libc_ver()[0] != "glibc":
        return None
    return with_tcache(environ.get("GLIBC_TUNABLES"))


def reexec_with_malloc_tunables(*, environ=None, execv=None) -> bool:
    """Starts this process's command again (``sys.orig_argv``) with glibc's tcache
    raised (module docstring); returns False where it does not (not glibc, already
    set, opted out, or the exec failed), and never returns where it does.
    ``environ``/``execv``: for tests (default ``os.environ``, ``os.execve``)."""
    env = os.environ if environ is None else environ
    value = tunables_to_set(env)
    argv = list(getattr(sys, "orig_argv", ()) or ())
    if value is None or not argv:
        return False
    new_env = {**env, "GLIBC_TUNABLES": value}
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        (execv or os.execve)(sys.executable, [sys.executable, *argv[1:]], new_env)
    except OSError:
        return False
    return True  # only with a test's execv


def reexec_or_exit(prog: str) -> None:
    """:func:`reexec_with_malloc_tunables` for a program's first line: a bad
    ``LUNAR_DRAKE_MALLOC`` is one line on stderr and exit status 2."""
    try:
        reexec_with_malloc_tunables()
    except ConfigError as exc:
        print(f"{prog}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(2)
