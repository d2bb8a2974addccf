"""Writing outputs so that nothing is half-written and nothing is lost.

Every file lunar_drake writes goes to a temporary sibling first and is renamed into
place only when complete (``os.replace`` is atomic on POSIX). Whole output directories
(a run, a site) are built in a temporary sibling directory and swapped in at the end,
so a failed or interrupted command leaves an existing directory untouched and removes
its own partial files.

A path that cannot be written raises :class:`~lunar_drake.errors.OutputError` naming the
path and the reason (one line, no traceback at the command line).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

from lunar_drake.errors import OutputError

__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_file",
    "check_replaceable",
    "ensure_output_dir",
    "remove_stale_siblings",
    "staged_directory",
    "temp_sibling",
]


def temp_sibling(path: str | os.PathLike, *, tag: str = "tmp") -> Path:
    """A unique hidden name next to ``path`` (same directory, so a rename is atomic).

    The suffix of ``path`` is kept (``.png``, ``.tif``) so writers that pick a format
    from the extension still work.
    """
    p = Path(path)
    return p.with_name(f".{p.stem}.{tag}-{os.getpid()}-{_HOST}{uuid.uuid4().hex[:8]}{p.suffix}")


#: This machine in :func:`temp_sibling` names (8 hex digits of its host name's hash), so
#: that a directory shared between machines is cleaned only of this machine's leftovers.
_HOST = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (in doubt: yes)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError, ValueError):  # not ours, or not a PID at all
        return True
    return True


def remove_stale_siblings(path: str | os.PathLike, *, keep_old: bool = False) -> list[Path]:
    """Removes the :func:`temp_sibling` directories of ``path`` that this machine's
    processes left and that no longer run (a build killed outright: SIGKILL, a power
    cut); returns them. Directories of running processes (this one's included), of other
    machines (a shared disk) or of other names are left alone, and so are the previous
    outputs set aside during a swap (``.old-``) while ``path`` itself is missing or
    ``keep_old``: one of them may be its only copy."""
    p = Path(path)
    removed = []
    if not p.parent.is_dir():
        return removed
    tags = "tmp" if keep_old or not p.is_dir() else "tmp|old"
    name = re.compile(rf"\.{re.escape(p.stem)}\.(?:{tags})-([0-9]{{1,9}})-{_HOST}[0-9a-f]{{8}}"
                      rf"{re.escape(p.suffix)}")  # fmt: skip
    for q in p.parent.iterdir():
        m = name.fullmatch(q.name)
        if m and q.is_dir() and not q.is_symlink() and not _alive(int(m.group(1))):
            shutil.rmtree(q, ignore_errors=True)
            removed.append(q)
    return removed


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def ensure_output_dir(path: str | os.PathLike, *, what: str = "output directory") -> Path:
    """Creates directory ``path`` (and parents) if needed and checks it is writable.

    Raises:
        OutputError: it cannot be created, is a file, or is not writable; the message
            names ``what``, the path and the reason.
    """
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(
            f"cannot write {what} {str(p)!r}: it exists and is not a directory"
        ) from None
    except OSError as exc:
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    if not p.is_dir():
        raise OutputError(f"cannot write {what} {str(p)!r}: it is not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write {what} {str(p)!r}: permission denied")
    return p


def check_output_file(path: str | os.PathLike, *, what: str = "file") -> Path:
    """Checks, before any work, that file ``path`` can be written; returns ``path``.

    Its directory must exist, ``path`` must not be a directory, and a probe file must be
    creatable (and is removed again) next to it, so the check also holds for root and
    for special file systems such as ``/proc``. Creates nothing that stays.

    Raises:
        OutputError: naming ``what``, the path and the reason.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise OutputError(f"cannot write {what} {str(p)!r}: it is a directory")
    if not parent.is_dir():
        why = "is not a directory" if parent.exists() else "does not exist"
        raise OutputError(f"cannot write {what} {str(p)!r}: {str(parent)!r} {why}")
    probe = temp_sibling(p, tag="probe")
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    os.close(fd)
    _unlink_quietly(probe)
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, what: str = "file") -> Iterator[Path]:
    """Yields a temporary sibling of ``path`` to write; renames it to ``path`` on success
    and removes it on any exception (``KeyboardInterrupt`` included).

    Raises:
        OutputError: the directory of ``path`` does not exist or is not writable.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(
            f"cannot write {what} {str(p)!r}: directory {str(parent)!r} does not exist"
        )
    tmp = temp_sibling(p)
    try:
        yield tmp
        os.replace(tmp, p)
    except OSError as exc:
        _unlink_quietly(tmp)
        if isinstance(exc, OutputError):
            raise
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    except BaseException:
        _unlink_quietly(tmp)
        raise


def atomic_write_text(path: str | os.PathLike, text: str, *, what: str = "file") -> Path:
    """Writes ``text`` to ``path`` atomically (UTF-8); returns ``path``."""
    with atomic_path(path, what=what) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, what: str = "file") -> Path:
    """Writes ``data`` to ``path`` atomically; returns ``path``."""
    with atomic_path(path, what=what) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _unlink_quietly(path: Path) -> None:
    for p in (path, path.with_name(path.name + ".aux.xml")):
        with contextlib.suppress(OSError):
            p.unlink()


def _created_parents(path: Path) -> list[Path]:
    """The missing ancestors of ``path`` (outermost first), created here. If one cannot
    be created, those created before it are removed again and the error is raised."""
    missing = []
    for parent in reversed(path.parents):
        if not parent.exists():
            missing.append(parent)
    done: list[Path] = []
    try:
        for parent in missing:
            parent.mkdir()
            done.append(parent)
    except BaseException:
        _remove_empty(done)
        raise
    return missing


def _remove_empty(created: list[Path]) -> None:
    """Removes directories created here (innermost first) if they are still empty."""
    for parent in reversed(created):
        with contextlib.suppress(OSError):
            parent.rmdir()


def check_replaceable(path: str | os.PathLike, *, allowed, what: str) -> None:
    """Refuses, before any work, to replace an existing directory ``path`` that holds
    anything but ``allowed`` names (a previous output of the same kind) and leftovers of
    interrupted writes (hidden ``.*.tmp-*`` / ``.*.old-*`` siblings). ``--out .`` or a
    data folder is never deleted wholesale.

    Raises:
        OutputError: naming the path and a few of the foreign entries.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputError(f"cannot write {what} {str(p)!r}: it is a file, not a directory")
    if not p.is_dir():
        return
    try:
        names = os.listdir(p)
    except OSError as exc:
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    allowed = set(allowed)
    foreign = sorted(
        n
        for n in names
        if n not in allowed and not (n.startswith(".") and (".tmp-" in n or ".old-" in n))
    )
    if foreign:
        shown = ", ".join(repr(n) for n in foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise OutputError(
            f"cannot write {what} {str(p)!r}: it exists and holds {len(foreign)} "
            f"{'entry that is' if len(foreign) == 1 else 'entries that are'} not {what} "
            f"outputs ({shown}); it would be replaced as a "
            "whole, so give a new or empty directory"
        )


@contextlib.contextmanager
def staged_directory(path: str | os.PathLike, *, what: str = "output directory") -> Iterator[Path]:
    """Builds a whole directory under a temporary sibling name and swaps it in at the end.

    Yields the temporary directory. On success the previous ``path`` (if any) is moved
    aside, the new one renamed into place and the old one deleted. On an exception
    (``KeyboardInterrupt`` included) the temporary directory is removed, the previous
    ``path`` is untouched, and parent directories created for it are removed again if
    they are still empty. Ctrl-C and SIGTERM wait while the two renames run (the main
    thread's signals are blocked), so an interrupt never leaves ``path`` missing.
    Before it starts, what killed processes left beside ``path`` goes
    (:func:`remove_stale_siblings`).

    Raises:
        OutputError: ``path`` is a file, or its parent cannot be created or written.
    """
    p = Path(os.path.abspath(path))  # "--out ." stages beside the real name
    if p.exists() and not p.is_dir():
        raise OutputError(f"cannot write {what} {str(p)!r}: it exists and is not a directory")
    try:
        created = _created_parents(p)
    except FileExistsError:
        raise OutputError(
            f"cannot write {what} {str(p)!r}: a parent exists and is not a directory"
        ) from None
    except OSError as exc:
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    remove_stale_siblings(p)
    tmp = temp_sibling(p)
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
        yield tmp
        old = None
        with _signals_held():
            if p.exists():
                old = temp_sibling(p, tag="old")
                os.rename(p, old)
            try:
                os.rename(tmp, p)
            except BaseException:
                if old is not None and not p.exists():
                    with contextlib.suppress(OSError):
                        os.rename(old, p)  # put the previous directory back
                raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(created)
        raise
    if old is not None:
        if old.is_symlink():  # ``path`` was a link: drop the link, not what it points to
            _unlink_quietly(old)
        else:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def _signals_held():
    """Blocks SIGINT and SIGTERM in the main thread while the block runs (delivered
    when it ends); elsewhere, or where the platform has no signal masks, a no-op."""
    import signal
    import threading

    held = {signal.SIGINT, signal.SIGTERM}
    if threading.current_thread() is not threading.main_thread() or not hasattr(
        signal, "pthread_sigmask"
    ):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
