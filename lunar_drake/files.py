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
    "ensure_output_dir",
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
        raise OutputError(f"cannot write {what} {str(p)!r}: it exists and is not a directory")
    except OSError as exc:
        raise OutputError(f"cannot write {what} {str(p)!r}: {_reason(exc)}") from None
    if not p.is_dir():
        raise OutputError(f"cannot write {what} {str(p)!r}: it is not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise OutputError(f"cannot write {what} {str(p)!r}: permission denied")
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
    """The missing ancestors of ``path`` (outermost first), created here."""
    missing = []
    for parent in reversed(path.parents):
        if not parent.exists():
            missing.append(parent)
    for parent in missing:
        parent.mkdir()
    return missing


@contextlib.contextmanager
def staged_directory(
    path: str | os.PathLike, *, what: str = "output directory"
) -> Iterator[Path]:
    """Builds a whole directory under a temporary sibling name and swaps it in at the end.

    Yields the temporary directory. On success the previous ``path`` (if any) is moved
    aside, the new one renamed into place and the old one deleted. On an exception
    (``KeyboardInterrupt`` included) the temporary directory is removed, the previous
    ``path`` is untouched, and parent directories created for it are removed again if
    they are still empty.

    Raises:
        OutputError: ``path`` is a file, or its parent cannot be created or written.
    """
    p = Path(path)
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
        os.rename(tmp, p)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for parent in reversed(created):
            with contextlib.suppress(OSError):
                parent.rmdir()  # only if still empty
        raise
