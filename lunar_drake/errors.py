"""Errors raised by lunar_drake.

Every error derives from :class:`LunarDrakeError`; each subclass also derives from the
built-in exception a caller would naturally catch (``ValueError`` for bad values,
``OSError``/``FileNotFoundError`` for files), so ``except ValueError`` keeps working.
Messages quote the offending value and say what is allowed.
"""

from __future__ import annotations

import numbers


class LunarDrakeError(Exception):
    """Root of every error raised on purpose by lunar_drake."""


class ConfigError(LunarDrakeError, ValueError):
    """A scenario or command-line value is unknown, malformed or out of range."""


class OutOfRangeError(ConfigError):
    """A numeric value lies outside its allowed interval."""


class RasterError(LunarDrakeError, OSError):
    """A raster file is missing, unreadable, corrupt or not georeferenced."""


class RasterNotFoundError(RasterError, FileNotFoundError):
    """The raster path does not exist."""


class CRSError(RasterError):
    """A raster's coordinate reference system is missing or not in metres."""


class NoDataError(LunarDrakeError, ValueError):
    """A query hit NaN (nodata) cells, or a raster holds no valid data at all."""


class OutOfBoundsError(LunarDrakeError, ValueError):
    """A query point lies outside the raster's extent."""


class SimulationError(LunarDrakeError, RuntimeError):
    """A simulation could not be built or ran into an unrecoverable state."""


class OutputError(LunarDrakeError, OSError):
    """An output file or directory cannot be written (the message names the path)."""


def format_value(value) -> str:
    """A value for a message: floats to 6 significant digits (13.3, not 13.299999999999999),
    everything else as ``repr``."""
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value)


def check_range(name: str, value, lo, hi, *, lo_open=False, hi_open=False, unit="") -> None:
    """Raises OutOfRangeError naming ``name`` and ``value`` unless lo <= value <= hi
    (strict at an ``_open`` end); NaN is always out of range."""
    bad = (
        value != value
        or (value <= lo if lo_open else value < lo)
        or (value >= hi if hi_open else value > hi)
    )
    if bad:
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise OutOfRangeError(
            f"{name} = {format_value(value)} is out of range; allowed "
            f"{lb}{_bound(lo)}, {_bound(hi)}{rb}{unit}"
        )


def _bound(v) -> str:
    """A range end as written: ``%g`` for floats; an integer exactly (``2**63 - 1``
    rather than 9.22337e+18)."""
    if isinstance(v, numbers.Integral) and not isinstance(v, bool):
        v = int(v)
        if v > 2**20 and (v + 1) & v == 0:
            return f"2**{(v + 1).bit_length() - 1} - 1"
        return str(v)
    return f"{v:g}"
