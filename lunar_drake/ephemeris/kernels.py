"""SPICE kernels built offline from the ``de421`` package, cached, verified and furnished.

DESIGN.md decision 4: no network. On first use the project writes four kernels from the
DE421 Chebyshev records that the ``de421`` PyPI package ships (the legacy jplephem
``.npy`` format: ``jpl-<name>.npy`` arrays of shape (records, components, coefficients),
times in TDB Julian days, positions in km, librations in rad; constants in
``constants.npy``):

``de421_lunar.bsp`` (SPK, type 2 Chebyshev, frame J2000 = ICRF as NAIF labels DE4xx)
    10 Sun rel. 0 SSB, 3 Earth-Moon barycentre rel. 0, and 399 Earth / 301 Moon rel. 3,
    the last two split from DE421's geocentric Moon records with EMRAT:
    ``r_E = -r_M/(1 + EMRAT)``, ``r_M' = r_M EMRAT/(1 + EMRAT)``. The split is applied to
    the coefficients record by record, which is exact because a Chebyshev series is linear
    in its coefficients. Chebyshev coefficients are in km against normalised time, so
    they are copied unscaled; SPICE derives velocities from ``intlen`` (s).
``moon_pa_de421.bpc`` (binary PCK, type 2, class ID 31006, relative to J2000)
    DE421's lunar libration angles (phi, theta, psi) in rad, stored in that order.
    SPICE's PCKMAT reverses them and calls ``EUL2XF(.., 3, 1, 3)``, so the J2000 -> PA
    rotation is ``[psi]_3 [theta]_1 [phi]_3``: the DE convention (Folkner et al. 2008,
    "The Planetary and Lunar Ephemeris DE 421", JPL IOM 343R-08-003 (from memory)).
``moon_de421.tf`` (frames kernel, text)
    MOON_PA_DE421 (class 2, ID 31006) and MOON_ME_DE421 (TK frame 31007 relative to
    MOON_PA_DE421: angles (67.92, 78.56, 0.30) arcsec about axes (3, 2, 1)), the values of
    NAIF's ``moon_080317.tf`` (Bachman, NAIF/JPL 2008), from Williams et al. 2008, "DE421
    Lunar Orbit, Physical Librations, and Surface Coordinates", JPL IOM
    335-JW,DB,WF-20080314-001 (IOM number from memory). Per NAIF frames.req, TK
    ``ANGLES`` give the ME -> PA matrix ``[a1]_3 [a2]_2 [a3]_1``; PA -> ME is its transpose.
``lunar_drake.tls`` (leap seconds, text)
    All leap seconds through 2017-01-01 (TAI - UTC = 37 s) and the DELTET constants of
    NAIF's ``naif0012.tls``.

Time arguments (``first``, ``last``, ``btime``) are TDB seconds past J2000:
``(JD_TDB - 2451545.0) * 86400``. Checks (tests/test_ephemeris.py): the SPK reproduces
the records (positions < 1e-6 km, rates < 1e-9 km/s), and MOON_ME_DE421 agrees with the
IAU 2015 lunar rotation model (Archinal et al. 2018) to < 0.004 deg over 1950-2050, where
MOON_PA_DE421 is ~0.03 deg off and a flipped PA -> ME offset ~0.06 deg.
Coverage is the package's full span, JD 2414992.5 to
2524624.5 (1899-12-04 to 2200-02-01 TDB; the package advertises 1900-2050).

The kernels live in ``$LUNAR_DRAKE_CACHE/spice`` if that variable is set, else in
``platformdirs.user_cache_dir("lunar_drake")/spice``, with ``manifest.json`` holding each
file's SHA-256. They are written under temporary names and renamed into place (the
manifest last), verified before they are furnished, and rebuilt when missing, corrupt or
built by another version of this module.

CSPICE keeps one global kernel pool per process and is not thread-safe. Every SPICE call
the project makes holds :data:`SPICE_LOCK`; :func:`ensure_kernels` is idempotent, notices a
``spiceypy.kclear()`` (or an unload) and furnishes again.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import json
import os
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lunar_drake.errors import LunarDrakeError, OutputError
from lunar_drake.files import ensure_output_dir, temp_sibling

__all__ = [
    "BUILD_VERSION",
    "KERNEL_FILES",
    "MOON_ME_FRAME",
    "MOON_PA_CLASS_ID",
    "MOON_PA_FRAME",
    "SPICE_LOCK",
    "KernelError",
    "KernelNotFoundError",
    "build_kernels",
    "coverage_tdb_s",
    "ensure_kernels",
    "load_de421",
    "spice_cache_dir",
    "unload_kernels",
    "verify_kernels",
]

BUILD_VERSION = 1
"""Bumped whenever the bytes this module writes change; a manifest of another version is
rebuilt."""

SPK_FILE = "de421_lunar.bsp"
PCK_FILE = "moon_pa_de421.bpc"
FK_FILE = "moon_de421.tf"
LSK_FILE = "lunar_drake.tls"
KERNEL_FILES = (LSK_FILE, FK_FILE, PCK_FILE, SPK_FILE)
"""Kernel file names, in furnishing order."""
MANIFEST_FILE = "manifest.json"

MOON_PA_FRAME = "MOON_PA_DE421"
MOON_ME_FRAME = "MOON_ME_DE421"
MOON_PA_CLASS_ID = 31006
"""NAIF frame/class ID of MOON_PA_DE421 (``moon_080317.tf``); MOON_ME_DE421 is 31007."""

J2000_JD = 2451545.0
SECONDS_PER_DAY = 86400.0

SPICE_LOCK = threading.RLock()
"""Held around every CSPICE call made by lunar_drake (CSPICE is not thread-safe)."""


class KernelError(LunarDrakeError, OSError):
    """A SPICE kernel could not be built, verified or furnished."""


class KernelNotFoundError(KernelError, FileNotFoundError):
    """An extra kernel path given by the user does not exist."""


# ------------------------------------------------------------------------------------------
# DE421 records


@dataclass(frozen=True)
class De421Records:
    """The DE421 arrays used here, as shipped by the ``de421`` package.

    Attributes:
        jalpha, jomega: first and last covered epoch (TDB Julian days).
        emrat: Earth/Moon mass ratio.
        sun, earthmoon: (n, 3, k) km, Sun and EMB relative to the SSB, J2000/ICRF.
        moon: (n, 3, k) km, geocentric Moon, J2000/ICRF.
        librations: (n, 3, k) rad, Euler angles phi, theta, psi (J2000 -> PA, 3-1-3).
        version: the ``de421`` package version.
    """

    jalpha: float
    jomega: float
    emrat: float
    sun: np.ndarray
    earthmoon: np.ndarray
    moon: np.ndarray
    librations: np.ndarray
    version: str

    def days_per_record(self, name: str) -> float:
        """Interval (TDB days) covered by one record of ``name``."""
        return (self.jomega - self.jalpha) / getattr(self, name).shape[0]


_RECORDS: De421Records | None = None


def load_de421() -> De421Records:
    """The DE421 records of the installed ``de421`` package (loaded once per process)."""
    global _RECORDS
    if _RECORDS is None:
        try:
            import de421
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise KernelError(
                "the 'de421' package is required to build the SPICE kernels (pip install de421)"
            ) from exc
        base = Path(de421.__file__).parent
        consts = {k.decode("ascii"): float(v) for k, v in np.load(base / "constants.npy")}
        arrays = {
            n: np.load(base / f"jpl-{n}.npy") for n in ("sun", "earthmoon", "moon", "librations")
        }
        _RECORDS = De421Records(
            jalpha=consts["jalpha"],
            jomega=consts["jomega"],
            emrat=consts["EMRAT"],
            version=importlib.metadata.version("de421"),
            **arrays,
        )
    return _RECORDS


def coverage_tdb_s() -> tuple[float, float]:
    """(first, last) epoch covered by the kernels, TDB seconds past J2000."""
    r = load_de421()
    return (r.jalpha - J2000_JD) * SECONDS_PER_DAY, (r.jomega - J2000_JD) * SECONDS_PER_DAY


# ------------------------------------------------------------------------------------------
# Writers

_LSK_TEXT = """KPL/LSK

Leap-seconds kernel written by lunar_drake (lunar_drake.ephemeris.kernels).

The DELTET constants and the leap-second table are those of NAIF's naif0012.tls
(NAIF/JPL, 2016): every leap second through 2017-01-01, TAI - UTC = 37 s from then on.
DELTA_ET = ET - UTC = DELTA_T_A + DELTA_AT + K sin(E), E = M + EB sin(M), M = M0 + M1 t
(Moyer 1981, Celestial Mechanics 23, 33-68).

\\begindata

DELTET/DELTA_T_A       =   32.184
DELTET/K               =    1.657D-3
DELTET/EB              =    1.671D-2
DELTET/M               = (  6.239996D0   1.99096871D-7 )

DELTET/DELTA_AT        = ( 10,   @1972-JAN-1
                           11,   @1972-JUL-1
                           12,   @1973-JAN-1
                           13,   @1974-JAN-1
                           14,   @1975-JAN-1
                           15,   @1976-JAN-1
                           16,   @1977-JAN-1
                           17,   @1978-JAN-1
                           18,   @1979-JAN-1
                           19,   @1980-JAN-1
                           20,   @1981-JUL-1
                           21,   @1982-JUL-1
                           22,   @1983-JUL-1
                           23,   @1985-JUL-1
                           24,   @1988-JAN-1
                           25,   @1990-JAN-1
                           26,   @1991-JAN-1
                           27,   @1992-JUL-1
                           28,   @1993-JUL-1
                           29,   @1994-JUL-1
                           30,   @1996-JAN-1
                           31,   @1997-JUL-1
                           32,   @1999-JAN-1
                           33,   @2006-JAN-1
                           34,   @2009-JAN-1
                           35,   @2012-JUL-1
                           36,   @2015-JUL-1
                           37,   @2017-JAN-1 )

\\begintext
"""

_FK_TEXT = """KPL/FK

Lunar frames kernel written by lunar_drake (lunar_drake.ephemeris.kernels).

MOON_PA_DE421: principal-axes frame of DE421, a PCK frame whose orientation comes from
the binary PCK moon_pa_de421.bpc (class ID 31006) that lunar_drake writes from the DE421
libration angles.

MOON_ME_DE421: mean-Earth/polar-axis frame of DE421 (the frame of LOLA maps and of
lunar_drake's sites), a fixed offset from MOON_PA_DE421. The definitions below are those
of NAIF's moon_080317.tf (N. Bachman, NAIF/JPL, 2008); the rotation angles are from
J. G. Williams, D. H. Boggs, W. M. Folkner (2008), "DE421 Lunar Orbit, Physical
Librations, and Surface Coordinates", JPL IOM 335-JW,DB,WF-20080314-001.

\\begindata

   FRAME_MOON_PA_DE421           = 31006
   FRAME_31006_NAME              = 'MOON_PA_DE421'
   FRAME_31006_CLASS             = 2
   FRAME_31006_CLASS_ID          = 31006
   FRAME_31006_CENTER            = 301

   FRAME_MOON_ME_DE421           = 31007
   FRAME_31007_NAME              = 'MOON_ME_DE421'
   FRAME_31007_CLASS             = 4
   FRAME_31007_CLASS_ID          = 31007
   FRAME_31007_CENTER            = 301

   TKFRAME_31007_SPEC            = 'ANGLES'
   TKFRAME_31007_RELATIVE        = 'MOON_PA_DE421'
   TKFRAME_31007_ANGLES          = (   67.92     78.56     0.30    )
   TKFRAME_31007_AXES            = (   3,        2,        1       )
   TKFRAME_31007_UNITS           = 'ARCSECONDS'

\\begintext
"""

_COMMENT = (
    "Written by lunar_drake.ephemeris.kernels (build version {build}) from the DE421",
    "Chebyshev records of the 'de421' Python package {version} (JPL DE421, Folkner,",
    "Williams & Boggs 2009, IPN Progress Report 42-178). Times: TDB s past J2000.",
)


def _type2_cdata(records: np.ndarray) -> np.ndarray:
    """(n, 3, k) Chebyshev records -> the flat layout of SPK/PCK type 2.

    Record after record, each holding the X (or first angle) coefficients, then Y, then Z.
    """
    ncomp = records.shape[1]
    if ncomp != 3:  # pragma: no cover - DE421 layout
        raise KernelError(f"expected 3 components per record, got {ncomp}")
    return np.ascontiguousarray(records, dtype=np.float64).ravel()


def _write_type2(writer, handle: int, ident: int, center: int | None, records, r, segid):
    n, _, k = records.shape
    days = (r.jomega - r.jalpha) / n
    intlen = days * SECONDS_PER_DAY
    btime = (r.jalpha - J2000_JD) * SECONDS_PER_DAY
    last = (r.jomega - J2000_JD) * SECONDS_PER_DAY
    cdata = _type2_cdata(records)
    if center is None:
        writer(handle, ident, "J2000", btime, last, segid, intlen, n, k - 1, cdata, btime)
    else:
        writer(handle, ident, center, "J2000", btime, last, segid, intlen, n, k - 1, cdata, btime)


def _write_spk(path: Path, r: De421Records) -> None:
    import spiceypy

    share_e = 1.0 / (1.0 + r.emrat)
    share_m = r.emrat / (1.0 + r.emrat)
    handle = spiceypy.spkopn(str(path), "DE421 lunar_drake", 4096)
    with _closing_on_error(handle):
        spiceypy.dafac(handle, [c.format(build=BUILD_VERSION, version=r.version) for c in _COMMENT])
        w = spiceypy.spkw02
        _write_type2(w, handle, 10, 0, r.sun, r, "DE421 SUN")
        _write_type2(w, handle, 3, 0, r.earthmoon, r, "DE421 EARTH-MOON BARYCENTER")
        _write_type2(w, handle, 301, 3, r.moon * share_m, r, "DE421 MOON")
        _write_type2(w, handle, 399, 3, r.moon * -share_e, r, "DE421 EARTH")
    spiceypy.spkcls(handle)


@contextlib.contextmanager
def _closing_on_error(handle: int) -> Iterator[None]:
    """Closes a DAF being written if writing fails (SPKCLS/PCKCLS refuse empty files)."""
    import spiceypy

    try:
        yield
    except BaseException:
        with contextlib.suppress(Exception):
            spiceypy.dafcls(handle)
        raise


def _write_pck(path: Path, r: De421Records) -> None:
    import spiceypy

    handle = spiceypy.pckopn(str(path), "DE421 lunar_drake", 4096)
    with _closing_on_error(handle):
        spiceypy.dafac(handle, [c.format(build=BUILD_VERSION, version=r.version) for c in _COMMENT])
        _write_type2(
            spiceypy.pckw02,
            handle,
            MOON_PA_CLASS_ID,
            None,
            r.librations,
            r,
            "DE421 MOON_PA LIBRATIONS",
        )
    spiceypy.pckcls(handle)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def build_kernels(directory: str | Path) -> dict[str, Path]:
    """Writes the four kernels and the manifest into ``directory``; returns name -> path.

    Each file is written under a unique temporary name and renamed into place; the
    manifest is renamed last, so a crash never leaves a directory that verifies. On any
    failure (Ctrl-C included) the temporary files are removed.

    Raises:
        OutputError: ``directory`` cannot be created or written.
        KernelError: the kernels could not be written.
    """
    import spiceypy

    out = _ensure_cache_dir(directory)
    r = load_de421()
    tmp = {name: temp_sibling(out / name) for name in KERNEL_FILES}
    mtmp = temp_sibling(out / MANIFEST_FILE)
    try:
        tmp[LSK_FILE].write_text(_LSK_TEXT, encoding="ascii")
        tmp[FK_FILE].write_text(_FK_TEXT, encoding="ascii")
        with SPICE_LOCK:
            _write_pck(tmp[PCK_FILE], r)
            _write_spk(tmp[SPK_FILE], r)
            if spiceypy.failed():  # pragma: no cover - spiceypy raises instead
                spiceypy.reset()
                raise KernelError(f"CSPICE failed while writing kernels in {out}")
        manifest = {
            "build_version": BUILD_VERSION,
            "de421_version": r.version,
            "files": {name: _sha256(p) for name, p in tmp.items()},
            "sizes": {name: p.stat().st_size for name, p in tmp.items()},
        }
        for name, p in tmp.items():
            os.replace(p, out / name)
        mtmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n", encoding="ascii")
        os.replace(mtmp, out / MANIFEST_FILE)
    except BaseException as exc:
        for p in (*tmp.values(), mtmp):
            with contextlib.suppress(OSError):
                p.unlink()
        if isinstance(exc, LunarDrakeError) or not isinstance(exc, Exception):
            raise
        raise KernelError(f"could not build the SPICE kernels in {out}: {exc}") from exc
    return {name: out / name for name in KERNEL_FILES}


def verify_kernels(directory: str | Path) -> bool:
    """True if ``directory`` holds a complete build of this version whose checksums match."""
    d = Path(directory)
    try:
        manifest = json.loads((d / MANIFEST_FILE).read_text(encoding="ascii"))
        if manifest.get("build_version") != BUILD_VERSION:
            return False
        if manifest.get("de421_version") != load_de421().version:
            return False
        files, sizes = manifest["files"], manifest["sizes"]
        for name in KERNEL_FILES:
            p = d / name
            if p.stat().st_size != sizes[name] or _sha256(p) != files[name]:
                return False
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return True


def spice_cache_dir() -> Path:
    """``$LUNAR_DRAKE_CACHE/spice`` if set, else ``user_cache_dir("lunar_drake")/spice``."""
    env = os.environ.get("LUNAR_DRAKE_CACHE")
    if env:
        return Path(env) / "spice"
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("lunar_drake")) / "spice"


def _ensure_cache_dir(directory: str | Path) -> Path:
    """Creates the kernel cache ``directory`` if needed and checks it is writable.

    Raises:
        OutputError: it cannot be; the message names it, the reason and the way out.
    """
    try:
        return ensure_output_dir(directory, what="SPICE kernel cache directory")
    except OutputError as exc:
        raise OutputError(
            f"{exc} (set LUNAR_DRAKE_CACHE to a writable directory; the kernels go in its "
            "'spice' subdirectory)"
        ) from None


@contextlib.contextmanager
def _dir_lock(directory: Path) -> Iterator[None]:
    """An inter-process lock on ``directory`` (POSIX flock; a no-op elsewhere).

    Raises:
        OutputError: ``directory`` (or its lock file) cannot be created or written.
    """
    _ensure_cache_dir(directory)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    try:
        f = open(directory / ".lock", "a+b")  # closed by the with-block below
    except OSError as exc:
        raise OutputError(
            f"cannot write SPICE kernel cache directory '{directory}': "
            f"{exc.strerror or exc} (set LUNAR_DRAKE_CACHE to a writable directory)"
        ) from None
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


# ------------------------------------------------------------------------------------------
# Furnishing


@dataclass
class _PoolState:
    directory: Path | None = None
    env: str | None = None
    ours: tuple[Path, ...] = ()
    extras: tuple[Path, ...] = ()
    builds: int = 0
    """How many times this process built the kernels (for tests and diagnostics)."""


_STATE = _PoolState()


def _is_loaded(path: Path) -> bool:
    import spiceypy
    from spiceypy.utils.exceptions import SpiceyError

    try:
        spiceypy.kinfo(str(path))
    except SpiceyError:
        return False
    return True


def _unload(paths: Iterable[Path]) -> None:
    import spiceypy

    for p in paths:
        if _is_loaded(p):
            spiceypy.unload(str(p))


def _furnsh(path: Path) -> None:
    import spiceypy
    from spiceypy.utils.exceptions import SpiceyError

    try:
        spiceypy.furnsh(str(path))
    except SpiceyError as exc:
        raise KernelError(f"CSPICE could not load kernel '{path}': {exc}") from exc


def ensure_kernels(extra: Iterable[str | os.PathLike] = ()) -> list[Path]:
    """Makes sure the project's kernels, then ``extra`` kernels, are furnished.

    Idempotent and thread-safe: the first call in a process (or the first after the cache
    directory changed, after ``spiceypy.kclear()`` or after one of our kernels was
    unloaded) verifies the cached kernels against their manifest, rebuilds them when
    missing or corrupt, and furnishes them; later calls only check that they are still
    loaded. Extra kernels (any SPICE kernel: SPK, PCK, FK, meta-kernel, ...) are furnished
    after ours, so their data take precedence; each is furnished once and re-furnished
    with ours after a ``kclear``.

    Args:
        extra: paths of additional kernels, in the order to furnish them.

    Returns:
        Every kernel furnished through this function, in furnishing (priority) order.

    Raises:
        KernelNotFoundError: an extra path does not exist.
        KernelError: the kernels could not be built or loaded.
    """
    extras = []
    for e in extra:
        p = Path(e).expanduser().resolve()
        if not p.is_file():
            raise KernelNotFoundError(f"extra SPICE kernel '{e}' does not exist (or is not a file)")
        extras.append(p)
    with SPICE_LOCK:
        env = os.environ.get("LUNAR_DRAKE_CACHE")
        stale = not _STATE.ours or env != _STATE.env or not all(_is_loaded(p) for p in _STATE.ours)
        if stale:
            directory = spice_cache_dir().resolve()
            _unload((*_STATE.ours, *_STATE.extras))
            with _dir_lock(directory):
                if not verify_kernels(directory):
                    build_kernels(directory)
                    _STATE.builds += 1
            ours = tuple(directory / name for name in KERNEL_FILES)
            for p in ours:
                _furnsh(p)
            _STATE.directory, _STATE.ours, _STATE.env = directory, ours, env
            for p in _STATE.extras:
                if p.is_file():
                    _furnsh(p)
            _STATE.extras = tuple(p for p in _STATE.extras if p.is_file())
        for p in extras:
            if p not in _STATE.extras or not _is_loaded(p):
                _furnsh(p)
                if p not in _STATE.extras:
                    _STATE.extras = (*_STATE.extras, p)
        return [*_STATE.ours, *_STATE.extras]


def unload_kernels(*, extras_only: bool = False) -> None:
    """Unloads the kernels furnished by :func:`ensure_kernels` and forgets them.

    With ``extras_only`` only the user's extra kernels go; otherwise the next
    :func:`ensure_kernels` re-verifies (and if needed rebuilds) the project's kernels.
    """
    with SPICE_LOCK:
        _unload(_STATE.extras)
        _STATE.extras = ()
        if not extras_only:
            _unload(_STATE.ours)
            _STATE.directory, _STATE.env, _STATE.ours = None, None, ()
