"""GeoTIFF I/O: atomic whole-array and windowed (tiled, dask-compatible) writes, checked reads.

Every writer produces a tiled GeoTIFF under a temporary name in the destination's
directory and renames it over the destination only once it is complete
(``os.replace``, atomic on POSIX), so a reader never sees a half-written raster and a
failed write leaves neither the destination nor the temporary file behind. Rasters are
pixel-is-area with a north-up affine transform (see :mod:`lunar_drake.terrain`).

Readers validate what they open: a missing path raises
:class:`~lunar_drake.errors.RasterNotFoundError`; an unreadable or corrupt file, or one
without a geotransform, :class:`~lunar_drake.errors.RasterError`; a missing, geographic
(degree) or non-metre CRS, :class:`~lunar_drake.errors.CRSError`.
"""

from __future__ import annotations

import contextlib
import os
import threading
import warnings
from dataclasses import dataclass

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.crs import CRS
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.transform import Affine
from rasterio.windows import Window

from lunar_drake.errors import (
    ConfigError,
    OutOfBoundsError,
    OutOfRangeError,
    OutputError,
    RasterError,
    RasterNotFoundError,
)
from lunar_drake.files import temp_sibling
from lunar_drake.terrain.crs import require_projected_metres

__all__ = [
    "COMPRESSIONS",
    "GeoTiffWriter",
    "RasterInfo",
    "open_raster",
    "raster_info",
    "read_window",
    "write_geotiff",
]

COMPRESSIONS = ("deflate", "lzw", "zstd", "packbits")
"""Allowed ``compress`` values (None for uncompressed)."""


@dataclass(frozen=True)
class RasterInfo:
    """Header of a validated raster file.

    Attributes:
        path: file path. height, width, count: rows, columns, bands.
        dtype: numpy dtype name of the bands. transform: pixel -> map affine (m).
        crs: projected CRS in metres. nodata: nodata value or None.
        block_shape: (rows, cols) of the file's internal blocks (band 1).
    """

    path: str
    height: int
    width: int
    count: int
    dtype: str
    transform: Affine
    crs: CRS
    nodata: float | None
    block_shape: tuple[int, int]


# Writers below keep their own commit (not lunar_drake.files.atomic_path) because GDAL
# may write a PAM sidecar (.aux.xml) beside the temporary file, which moves with it.


def _temp_name(path: str) -> str:
    return os.fspath(temp_sibling(os.path.abspath(path)))


def _check_parent(path: str) -> None:
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        why = f"'{parent}' is not a directory"
        if not os.path.exists(parent):
            why = f"directory '{parent}' does not exist"
        raise RasterNotFoundError(f"cannot write raster '{path}': {why}")


def _remove_quietly(path: str) -> None:
    """Removes a temporary file and its sidecar; never raises, so that cleaning up after
    an error cannot hide that error."""
    for p in (path, path + ".aux.xml"):
        with contextlib.suppress(OSError):
            os.remove(p)


def _create(tmp: str, path: str, profile: dict):
    """Opens temporary file ``tmp`` for writing; a file GDAL cannot create (no permission,
    a special file system) raises OutputError naming ``path`` and GDAL's reason."""
    try:
        return rasterio.open(tmp, "w", **profile)
    except RasterioError as exc:
        _remove_quietly(tmp)
        reason = str(exc).replace(tmp, os.path.basename(path))
        raise OutputError(f"cannot write raster '{path}': {reason}") from None


def _commit(tmp: str, path: str) -> None:
    os.replace(tmp, path)
    # GDAL writes a PAM sidecar only for metadata a TIFF cannot hold; keep it with the file.
    if os.path.exists(tmp + ".aux.xml"):
        os.replace(tmp + ".aux.xml", path + ".aux.xml")


# GeoTIFF creation options carried over when a file is rewritten in canonical order.
_CREATION_KEYS = ("tiled", "blockxsize", "blockysize", "interleave", "BIGTIFF", "compress")


def _creation_profile(
    *,
    height,
    width,
    count,
    dtype,
    transform,
    crs,
    nodata,
    blocksize,
    compress,
    path,
    interleave: str = "band",
) -> dict:
    if int(height) < 1 or int(width) < 1 or int(count) < 1:
        raise OutOfRangeError(
            f"raster size (count, height, width) = ({count}, {height}, {width}) for '{path}' "
            "is invalid; each must be >= 1"
        )
    if int(blocksize) < 16 or int(blocksize) % 16:
        raise OutOfRangeError(
            f"blocksize = {blocksize!r} is invalid; GeoTIFF tiles must be a positive multiple of 16"
        )
    if compress is not None and str(compress).lower() not in COMPRESSIONS:
        raise ConfigError(f"compress = {compress!r} is unknown; allowed: None, {COMPRESSIONS}")
    if not isinstance(transform, Affine):
        raise ConfigError(f"transform for '{path}' must be an affine.Affine, got {transform!r}")
    if transform.is_identity:
        raise RasterError(f"transform for '{path}' is the identity; a geotransform is required")
    rcrs = require_projected_metres(crs, source=path)
    dt = np.dtype(dtype)
    # A tile larger than a small raster only wastes space: shrink it to the raster.
    bs = min(int(blocksize), 16 * -(-max(int(height), int(width)) // 16))
    profile = dict(
        driver="GTiff",
        height=int(height),
        width=int(width),
        count=int(count),
        dtype=dt.name,
        transform=transform,
        crs=rcrs,
        tiled=True,
        blockxsize=bs,
        blockysize=bs,
        interleave=interleave,
        BIGTIFF="IF_SAFER",
    )
    if nodata is not None:
        profile["nodata"] = nodata
    if compress is not None:
        profile["compress"] = str(compress).lower()
        if compress.lower() != "packbits":
            profile["predictor"] = 3 if dt.kind == "f" else 2
        # Tiles compressed by two threads (the same bytes as by one); the fastest levels.
        profile["num_threads"] = "2"
        if compress.lower() == "zstd":
            profile["zstd_level"] = 1
        elif compress.lower() == "deflate":
            profile["zlevel"] = 1
    return profile


def write_geotiff(path, array, *, transform, crs, nodata=None, compress=None) -> None:
    """Write a 2-D ``(rows, cols)`` or 3-D ``(bands, rows, cols)`` array as a tiled GeoTIFF.

    Atomic: written to a temporary file in the same directory and renamed over ``path``
    when complete; the temporary file is removed if anything fails.

    Args:
        path: destination file.
        array: raster values; dtype is kept.
        transform: pixel -> map affine (m), north-up pixel-is-area.
        crs: projected CRS in metres (rasterio/pyproj CRS, WKT, ...).
        nodata: nodata value written to the header (NaN allowed for floats).
        compress: None or one of :data:`COMPRESSIONS`.
    """
    path = os.fspath(path)
    arr = np.asarray(array)
    if arr.ndim == 2:
        arr = arr[np.newaxis]
    if arr.ndim != 3:
        raise ConfigError(
            f"array for '{path}' has shape {np.shape(array)}; expected (rows, cols) or "
            "(bands, rows, cols)"
        )
    profile = _creation_profile(
        height=arr.shape[1],
        width=arr.shape[2],
        count=arr.shape[0],
        dtype=arr.dtype,
        transform=transform,
        crs=crs,
        nodata=nodata,
        blocksize=256,
        compress=compress,
        path=path,
    )
    _check_parent(path)
    tmp = _temp_name(path)
    try:
        with _create(tmp, path, profile) as ds:
            ds.write(arr)
        _commit(tmp, path)
    except BaseException:
        _remove_quietly(tmp)
        raise


class GeoTiffWriter:
    """Windowed writer for a large tiled GeoTIFF (context manager; thread-safe).

    Use as ``with GeoTiffWriter(path, height=..., ...) as w: w.write(tile, row0=r, col0=c)``.
    The file is created under a temporary name on ``__enter__`` and renamed to ``path``
    on a clean ``__exit__``; on an exception it is deleted and ``path`` is untouched.
    Blocks never written read back as ``nodata`` (or 0 when ``nodata`` is None).

    It is also a ``dask.array.store`` target: ``da.store(arr, writer, lock=False)``
    (threaded scheduler; the writer serialises GDAL calls with its own lock). Keys are
    tuples of unit-step slices, ``(rows, cols)`` or ``(bands, rows, cols)``.

    Args:
        path: destination file.
        height, width, count: raster rows, columns, bands.
        dtype: numpy dtype of the bands.
        transform: pixel -> map affine (m). crs: projected CRS in metres.
        nodata: nodata value for the header. blocksize: tile size (px, multiple of 16).
        compress: None or one of :data:`COMPRESSIONS`.
        descriptions: one name per band (GDAL band descriptions), or None.
        canonical: rewrite the file in canonical block order on close (needed when
            windows come from several threads); a single writer of rows in order, to a
            one-band or pixel-interleaved file, may skip it (``False``).
        interleave: ``"band"`` (default) or ``"pixel"`` (every tile holds all bands).
    """

    def __init__(
        self,
        path,
        *,
        height: int,
        width: int,
        count: int = 1,
        dtype="float32",
        transform: Affine,
        crs,
        nodata=None,
        blocksize: int = 256,
        compress: str | None = None,
        descriptions: tuple[str, ...] | None = None,
        canonical: bool = True,
        interleave: str = "band",
    ) -> None:
        self.path = os.fspath(path)
        self._canonical = bool(canonical)
        if descriptions is not None and len(descriptions) != int(count):
            raise ConfigError(
                f"descriptions {descriptions!r} for '{self.path}' must name each of its "
                f"{count} bands"
            )
        self._descriptions = tuple(descriptions) if descriptions is not None else None
        self._profile = _creation_profile(
            height=height,
            width=width,
            count=count,
            dtype=dtype,
            transform=transform,
            crs=crs,
            nodata=nodata,
            blocksize=blocksize,
            compress=compress,
            path=self.path,
            interleave=interleave,
        )
        self.height = int(height)
        self.width = int(width)
        self.count = int(count)
        self.dtype = np.dtype(dtype)
        self._lock = threading.Lock()
        self._ds = None
        self._tmp: str | None = None

    # -- array-like surface used by dask.array.store ------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        """``(rows, cols)`` for one band, else ``(bands, rows, cols)``."""
        if self.count == 1:
            return (self.height, self.width)
        return (self.count, self.height, self.width)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __enter__(self) -> GeoTiffWriter:
        if self._ds is not None:
            raise RasterError(f"GeoTiffWriter for '{self.path}' is already open")
        _check_parent(self.path)
        self._tmp = _temp_name(self.path)
        try:
            self._ds = _create(self._tmp, self.path, self._profile)
            for k, name in enumerate(self._descriptions or (), start=1):
                self._ds.set_band_description(k, name)
        except BaseException:
            _remove_quietly(self._tmp)
            self._tmp = None
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # Detach under the lock: a write still running in a worker thread (e.g. after a
        # Ctrl-C in the main thread) finishes first, later ones see a closed writer.
        with self._lock:
            ds, tmp = self._ds, self._tmp
            self._ds, self._tmp = None, None
        if ds is None or tmp is None:
            return
        if exc_type is not None:
            # Leaving on an error: discard the file; nothing here may replace that error.
            with contextlib.suppress(Exception):
                ds.close()
            _remove_quietly(tmp)
            return
        canon = None
        try:
            ds.close()
            if not self._canonical:
                _commit(tmp, self.path)
                return
            # Windows written from several threads land in the file in completion order;
            # a sequential GDAL copy puts the blocks in canonical order, so the file's
            # bytes depend only on its pixels (not on tiling or workers).
            canon = _temp_name(self.path)
            opts = {k: v for k, v in self._profile.items() if k in _CREATION_KEYS}
            rasterio.shutil.copy(tmp, canon, driver="GTiff", **opts)
            _remove_quietly(tmp)
            _commit(canon, self.path)
        except BaseException:
            _remove_quietly(tmp)
            if canon is not None:
                _remove_quietly(canon)
            raise

    def write(self, array, *, row0: int, col0: int, band: int | None = None) -> None:
        """Write ``array`` with its top-left pixel at global ``(row0, col0)``.

        ``array`` is 2-D (into ``band``, default 1, which must be given when the raster
        has several bands) or 3-D ``(count, rows, cols)`` covering every band.
        """
        arr = np.asarray(array)
        if arr.ndim == 2:
            if band is None:
                if self.count != 1:
                    raise ConfigError(
                        f"a 2-D array needs band= for the {self.count}-band '{self.path}'"
                    )
                band = 1
            if not 1 <= int(band) <= self.count:
                raise OutOfRangeError(
                    f"band = {band!r} is invalid for '{self.path}'; allowed 1..{self.count}"
                )
            bands = [int(band)]
            arr = arr[np.newaxis]
        elif arr.ndim == 3:
            if band is not None:
                raise ConfigError("band= is only for 2-D arrays; a 3-D array covers all bands")
            if arr.shape[0] != self.count:
                raise ConfigError(f"array has {arr.shape[0]} bands; '{self.path}' has {self.count}")
            bands = list(range(1, self.count + 1))
        else:
            raise ConfigError(
                f"array shape {arr.shape} is invalid; expected (rows, cols) or (bands, rows, cols)"
            )
        self._write(arr, bands, int(row0), int(col0))

    def __setitem__(self, key, value) -> None:
        if not isinstance(key, tuple):
            key = (key,)
        if len(key) == 2:
            b0, b1 = 0, 1
            if self.count != 1:
                raise ConfigError(
                    f"2-D key {key!r} needs a leading band slice for {self.count}-band "
                    f"'{self.path}'"
                )
            rs, cs = key
        elif len(key) == 3:
            b0, b1 = self._slice(key[0], self.count, "band")
            rs, cs = key[1], key[2]
        else:
            raise ConfigError(f"key {key!r} is invalid; expected 2 or 3 slices")
        r0, r1 = self._slice(rs, self.height, "row")
        c0, c1 = self._slice(cs, self.width, "column")
        arr = np.asarray(value)
        if arr.ndim == 2:
            arr = arr[np.newaxis]
        if arr.shape != (b1 - b0, r1 - r0, c1 - c0):
            raise ConfigError(
                f"value of shape {np.shape(value)} does not fit the key {key!r} for '{self.path}'"
            )
        self._write(arr, list(range(b0 + 1, b1 + 1)), r0, c0)

    def _slice(self, s, n: int, what: str) -> tuple[int, int]:
        if not isinstance(s, slice) or s.step not in (None, 1):
            raise ConfigError(f"{what} key {s!r} is invalid; only unit-step slices are allowed")
        start, stop, _ = s.indices(n)
        if stop <= start:
            raise ConfigError(f"{what} slice {s!r} is empty for size {n}")
        return start, stop

    def _write(self, arr: np.ndarray, bands: list[int], row0: int, col0: int) -> None:
        nrows, ncols = arr.shape[1], arr.shape[2]
        if row0 < 0 or col0 < 0 or row0 + nrows > self.height or col0 + ncols > self.width:
            raise OutOfBoundsError(
                f"window (row0={row0}, col0={col0}, nrows={nrows}, ncols={ncols}) is outside "
                f"'{self.path}' of {self.height} x {self.width} pixels"
            )
        data = np.ascontiguousarray(arr, dtype=self.dtype)
        window = Window(col0, row0, ncols, nrows)
        with self._lock:
            if self._ds is None:
                raise RasterError(
                    f"GeoTiffWriter for '{self.path}' is not open; use it in a with-block"
                )
            self._ds.write(data, indexes=bands, window=window)


def raster_info(path) -> RasterInfo:
    """Validated header of a raster file (see :func:`open_raster` for the errors)."""
    with open_raster(path) as ds:
        return _info(ds, os.fspath(path))


def _info(ds, path: str) -> RasterInfo:
    nodata = ds.nodata
    return RasterInfo(
        path=path,
        height=ds.height,
        width=ds.width,
        count=ds.count,
        dtype=ds.dtypes[0],
        transform=ds.transform,
        crs=ds.crs,
        nodata=None if nodata is None else float(nodata),
        block_shape=tuple(ds.block_shapes[0]),
    )


def open_raster(path):
    """Open a raster for reading after checking it is georeferenced in metres.

    Returns an open rasterio dataset (a context manager; the caller closes it).

    Raises:
        RasterNotFoundError: ``path`` does not exist.
        RasterError: not a readable raster, or it has no geotransform.
        CRSError: no CRS, a geographic (degree) CRS, or units other than metres.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise RasterNotFoundError(f"raster file '{path}' does not exist")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(path)
    except RasterioError as exc:
        raise RasterError(f"cannot read raster '{path}': {exc}") from exc
    try:
        if ds.transform.is_identity and not ds.gcps[0] and not ds.rpcs:
            raise RasterError(
                f"raster '{path}' has no geotransform (identity pixel-to-map transform); "
                "a north-up affine transform in metres is required"
            )
        require_projected_metres(ds.crs, source=path)
    except BaseException:
        ds.close()
        raise
    return ds


def read_window(path, *, row0: int, col0: int, nrows: int, ncols: int, band: int = 1):
    """Values of window ``(row0, col0, nrows, ncols)`` of ``band`` in the file's dtype.

    Nodata pixels keep their stored value (see ``raster_info(path).nodata``).

    Raises:
        OutOfBoundsError: the window is empty or not inside the raster.
        OutOfRangeError: ``band`` is not in 1..count.
        RasterNotFoundError, RasterError, CRSError: see :func:`open_raster`.
    """
    path = os.fspath(path)
    with open_raster(path) as ds:
        if not 1 <= int(band) <= ds.count:
            raise OutOfRangeError(f"band = {band!r} is invalid for '{path}'; allowed 1..{ds.count}")
        check_window(row0, col0, nrows, ncols, ds.height, ds.width, source=path)
        try:
            return ds.read(int(band), window=Window(int(col0), int(row0), int(ncols), int(nrows)))
        except RasterioError as exc:
            raise RasterError(f"cannot read window from raster '{path}': {exc}") from exc


def check_window(row0, col0, nrows, ncols, height: int, width: int, *, source: str) -> None:
    """Raise OutOfBoundsError unless the window is non-empty and inside ``height x width``."""
    r0, c0, nr, nc = (int(v) for v in (row0, col0, nrows, ncols))
    if nr < 1 or nc < 1 or r0 < 0 or c0 < 0 or r0 + nr > height or c0 + nc > width:
        raise OutOfBoundsError(
            f"window (row0={r0}, col0={c0}, nrows={nr}, ncols={nc}) is not inside '{source}' "
            f"of {height} x {width} pixels (rows 0..{height - 1}, cols 0..{width - 1})"
        )
