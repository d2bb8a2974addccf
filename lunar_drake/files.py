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
import glob
import os
import shutil
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
    return p.with_name(f".{p.stem}.{tag}-{os.getpid()}-{uuid.uuid4().hex[:8]}{p.suffix}")


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists (on this machine)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # it exists but is not ours
        return True
    return True


def remove_stale_siblings(path: str | os.PathLike) -> list[Path]:
    """Removes the :func:`temp_sibling` directories of directory ``path`` left by
    processes that no longer run (a build killed outright: SIGKILL, a power cut);
    returns them. Only while ``path`` itself exists (else one of them may be the only
    copy); those of a running process, this one's included, are left alone."""
    p = Path(path)
    removed = []
    if not p.is_dir():
        return removed
    for tag in ("tmp", "old"):
        pattern = f".{glob.escape(p.stem)}.{tag}-*-*{glob.escape(p.suffix)}"
        for q in p.parent.glob(pattern):
            pid = q.name[len(f".{p.stem}.{tag}-") :].split("-", 1)[0]
            if pid.isdigit() and q.is_dir() and not q.is_symlink() and not _alive(int(pid)):
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
    they are still empty. After a success, what killed processes left beside ``path``
    goes (:func:`remove_stale_siblings`).

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
    tmp = temp_sibling(p)
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
        yield tmp
        old = None
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
    remove_stale_siblings(p)
