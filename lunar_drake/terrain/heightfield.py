"""Heightfield: a georeferenced elevation grid answering height/gradient/normal/slope queries.

A :class:`Heightfield` is an elevation grid ``z[row, col]`` (m) with a north-up
pixel-is-area affine transform, a projected CRS in metres and a site origin at the
raster centre (see :mod:`lunar_drake.terrain` for the conventions). It is either held
in memory (:meth:`Heightfield.from_array`) or backed lazily by a GeoTIFF
(:meth:`Heightfield.open`): then only the blocks a query touches are read, through a
bounded LRU block cache, so a 30720 x 30720 DEM is never loaded whole.

Interpolation:

* ``height`` is bilinear between pixel centres; in the half-pixel band between the
  outermost pixel centres and the raster edge the edge values are clamped (constant).
* ``gradient`` is the bilinear interpolation of the central-difference gradient at the
  pixel centres (one-sided on the outermost rows/columns). It is continuous (good for
  compliant contact, where a jumping normal makes forces chatter), equals the central
  difference at each pixel centre (the "normal at each DEM posting" of the paper's
  normal map), and is exact for a plane; it is not the piecewise derivative of the
  bilinear ``height`` surface. In the clamped edge band it keeps the edge value.
* A query "touches" the 2 x 2 pixels around it (``height``) or those pixels and their
  four-neighbours (``gradient``, ``normal``, ``slope``); touching a NaN (nodata) pixel
  raises :class:`~lunar_drake.errors.NoDataError`.
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numba
import numpy as np
from rasterio.coords import BoundingBox
from rasterio.errors import RasterioError
from rasterio.transform import Affine
from rasterio.windows import Window

from lunar_drake.errors import (
    ConfigError,
    NoDataError,
    OutOfBoundsError,
    OutOfRangeError,
    RasterError,
)
from lunar_drake.terrain.crs import moon_south_polar_stereographic, require_projected_metres
from lunar_drake.terrain.geotiff import GeoTiffWriter, check_window, open_raster, write_geotiff
from lunar_drake.terrain.grid import GridSpec

__all__ = ["BlockCacheInfo", "Heightfield", "MinMaxPyramid"]

_IO_TILE = 2048  # side (px) of the windows used for whole-raster passes (bounded memory)


# ----------------------------------------------------------------------------------------
# Min/max pyramid
# ----------------------------------------------------------------------------------------
@dataclass
class MinMaxPyramid:
    """NaN-aware min/max pyramid of a grid.

    ``levels[k]`` is ``(zmin, zmax)``, float32 arrays of shape
    ``(ceil(nrows / 2**k), ceil(ncols / 2**k))``: cell ``(i, j)`` bounds the level-0
    pixels ``[i*2**k, (i+1)*2**k) x [j*2**k, (j+1)*2**k)``, ignoring NaN (NaN only when
    all of them are NaN). Level 0 is the grid itself (its min and max are the same
    array); the last level is 1 x 1. Levels below ``start_level`` (see
    :meth:`Heightfield.pyramid`) are None.

    Attributes:
        levels: per-level ``(zmin, zmax)`` (m) or None.
        shape: ``(nrows, ncols)`` of level 0.
    """

    levels: list[tuple[np.ndarray, np.ndarray] | None]
    shape: tuple[int, int]

    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def level_shape(self, level: int) -> tuple[int, int]:
        """``(rows, cols)`` of ``level``."""
        s = 1 << int(level)
        return (-(-self.shape[0] // s), -(-self.shape[1] // s))

    def range_in_window(
        self, level: int, row0: int, col0: int, nrows: int, ncols: int
    ) -> tuple[float, float]:
        """``(zmin, zmax)`` (m) bounding the level-0 pixel window using ``level``'s cells.

        The window is in level-0 (full-resolution) pixel indices; the cells of ``level``
        that intersect it are reduced, so the result is exact at level 0 or when the
        window is aligned to ``2**level`` and conservative (``zmin`` <= true min,
        ``zmax`` >= true max) otherwise. ``(nan, nan)`` if every pixel is NaN.

        Raises:
            OutOfRangeError: no such level, or it was not built.
            OutOfBoundsError: the window is empty or not inside the level-0 grid.
        """
        if not 0 <= int(level) < self.num_levels or self.levels[int(level)] is None:
            built = [k for k, lv in enumerate(self.levels) if lv is not None]
            raise OutOfRangeError(
                f"level = {level!r} is not available; built levels: {built[0]}..{built[-1]}"
            )
        check_window(row0, col0, nrows, ncols, *self.shape, source="min/max pyramid")
        lvl = int(level)
        zmin, zmax = self.levels[lvl]  # type: ignore[misc]
        r0, c0 = int(row0) >> lvl, int(col0) >> lvl
        r1, c1 = (
            ((int(row0) + int(nrows) - 1) >> lvl) + 1,
            ((int(col0) + int(ncols) - 1) >> lvl) + 1,
        )
        lo = np.fmin.reduce(zmin[r0:r1, c0:c1], axis=None)
        hi = np.fmax.reduce(zmax[r0:r1, c0:c1], axis=None)
        return float(lo), float(hi)


def _reduce2(zmin: np.ndarray, zmax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 2 x 2 NaN-aware min/max reduction (odd sizes padded with NaN)."""
    h, w = zmin.shape
    ph, pw = h % 2, w % 2
    if ph or pw:
        zmin = np.pad(zmin, ((0, ph), (0, pw)), constant_values=np.nan)
        zmax = np.pad(zmax, ((0, ph), (0, pw)), constant_values=np.nan)
    t = np.fmin(zmin[0::2], zmin[1::2])  # pairs of rows first: contiguous, one temporary
    mn = np.fmin(t[:, 0::2], t[:, 1::2])
    t = np.fmax(zmax[0::2], zmax[1::2])
    mx = np.fmax(t[:, 0::2], t[:, 1::2])
    return mn, mx


def _block_mean(w: np.ndarray, f: int) -> np.ndarray:
    """NaN-aware mean over ``f x f`` blocks (partial blocks at the far edges), float32."""
    h, wd = w.shape
    ph, pw = (-h) % f, (-wd) % f
    if ph or pw:
        w = np.pad(w, ((0, ph), (0, pw)), constant_values=np.nan)
    r = w.reshape(w.shape[0] // f, f, w.shape[1] // f, f)
    valid = ~np.isnan(r)
    s = np.where(valid, r, 0.0).sum(axis=(1, 3), dtype=np.float64)
    n = valid.sum(axis=(1, 3))
    out = np.full(s.shape, np.nan)
    np.divide(s, n, out=out, where=n > 0)
    return out.astype(np.float32)


# ----------------------------------------------------------------------------------------
# Elevation sources
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BlockCacheInfo:
    """State of a file-backed Heightfield's block cache.

    Attributes:
        blocks: blocks held now. max_blocks: capacity. block_size: block side (px).
        hits, misses: cache lookups served / read from the file.
        pixels_read: pixels read from the file so far (cache fills and window reads).
    """

    blocks: int
    max_blocks: int
    block_size: int
    hits: int
    misses: int
    pixels_read: int


@numba.njit(cache=True)
def heights_in_box(z, xs, ys, res, left, right, bottom, top):  # pragma: no cover - numba
    """Bilinear heights (float64) at points inside ``[left, right] x [bottom, top]`` (m)
    of the in-memory raster ``z``; -inf and ok False outside it or on nodata. The same
    operations, in the same order, as :meth:`Heightfield.height` (same bits)."""
    nrows, ncols = z.shape
    n = xs.size
    out = np.full(n, -np.inf)
    ok = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        x = xs[i]
        y = ys[i]
        if not (x >= left and x <= right and y >= bottom and y <= top):  # NaN fails too
            continue
        col = x / res + 0.5 * ncols - 0.5
        row = 0.5 * nrows - 0.5 - y / res
        row = min(max(row, 0.0), nrows - 1.0)
        col = min(max(col, 0.0), ncols - 1.0)
        r0 = min(int(np.floor(row)), max(nrows - 2, 0))
        c0 = min(int(np.floor(col)), max(ncols - 2, 0))
        fr = row - r0
        fc = col - c0
        r1 = min(r0 + 1, nrows - 1)
        c1 = min(c0 + 1, ncols - 1)
        v0 = np.float64(z[r0, c0])
        v1 = np.float64(z[r0, c1])
        v2 = np.float64(z[r1, c0])
        v3 = np.float64(z[r1, c1])
        t = v0 + fc * (v1 - v0)
        b = v2 + fc * (v3 - v2)
        h = t + fr * (b - t)
        if h == h:
            out[i] = h
            ok[i] = True
    return out, ok


class _ArraySource:
    def __init__(self, z: np.ndarray) -> None:
        self.z = z
        self.shape = z.shape
        self.dtype = z.dtype
        self.name = "<in-memory array>"

    def gather(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.z[rows, cols].astype(np.float64, copy=False)

    def read(self, row0: int, col0: int, nrows: int, ncols: int) -> np.ndarray:
        return self.z[row0 : row0 + nrows, col0 : col0 + ncols]


class _FileSource:
    """Band 1 of a raster file, read lazily through an LRU cache of square blocks."""

    def __init__(self, path: str, ds, *, block_size: int, cache_blocks: int) -> None:
        self.path = path
        self.name = path
        self.shape = (ds.height, ds.width)
        self.dtype = np.dtype(np.float64 if ds.dtypes[0] == "float64" else np.float32)
        self.block_size = block_size
        self.cache_blocks = cache_blocks
        self._nbc = -(-ds.width // block_size)
        self._ds = ds
        self._init_runtime()

    def _init_runtime(self) -> None:
        self._lock = threading.RLock()
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self.hits = self.misses = self.pixels_read = 0

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for k in ("_ds", "_lock", "_cache"):
            state.pop(k, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._ds = None
        self._init_runtime()

    def close(self) -> None:
        with self._lock:
            if self._ds is not None:
                self._ds.close()
                self._ds = None
            self._cache.clear()

    def read(self, row0: int, col0: int, nrows: int, ncols: int) -> np.ndarray:
        with self._lock:
            if self._ds is None:
                self._ds = open_raster(self.path)
            try:
                m = self._ds.read(1, window=Window(col0, row0, ncols, nrows), masked=True)
            except RasterioError as exc:
                raise RasterError(
                    f"cannot read window (row0={row0}, col0={col0}, nrows={nrows}, "
                    f"ncols={ncols}) of raster '{self.path}': {exc}"
                ) from exc
            self.pixels_read += nrows * ncols
        return np.ma.filled(m.astype(self.dtype), np.nan)

    def _block(self, key: int) -> np.ndarray:
        with self._lock:
            blk = self._cache.get(key)
            if blk is not None:
                self._cache.move_to_end(key)
                self.hits += 1
                return blk
            self.misses += 1
            br, bc = divmod(key, self._nbc)
            b = self.block_size
            r0, c0 = br * b, bc * b
            blk = self.read(r0, c0, min(b, self.shape[0] - r0), min(b, self.shape[1] - c0))
            blk.flags.writeable = False
            self._cache[key] = blk
            while len(self._cache) > self.cache_blocks:
                self._cache.popitem(last=False)
            return blk

    def gather(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        b = self.block_size
        key = (rows // b) * self._nbc + cols // b
        order = np.argsort(key, kind="stable")
        ks = key[order]
        starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
        ends = np.r_[starts[1:], ks.size]
        out = np.empty(rows.shape, dtype=np.float64)
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            k = int(ks[s])
            blk = self._block(k)
            br, bc = divmod(k, self._nbc)
            idx = order[s:e]
            out[idx] = blk[rows[idx] - br * b, cols[idx] - bc * b]
        return out

    def info(self) -> BlockCacheInfo:
        with self._lock:
            return BlockCacheInfo(
                blocks=len(self._cache),
                max_blocks=self.cache_blocks,
                block_size=self.block_size,
                hits=self.hits,
                misses=self.misses,
                pixels_read=self.pixels_read,
            )


def _windows(nrows: int, ncols: int, step_r: int, step_c: int):
    for r0 in range(0, nrows, step_r):
        for c0 in range(0, ncols, step_c):
            yield r0, c0, min(step_r, nrows - r0), min(step_c, ncols - c0)


# ----------------------------------------------------------------------------------------
# Heightfield
# ----------------------------------------------------------------------------------------
class Heightfield:
    """Elevation grid (m) + north-up affine transform + projected CRS (m) + site origin.

    Site coordinates: metres, x east, y north, origin at the raster centre
    (``x = X_crs - origin_x``, ``y = Y_crs - origin_y``). Build with
    :meth:`from_array` or :meth:`open`; do not call the constructor directly.
    """

    def __init__(self, source, *, transform: Affine, crs) -> None:
        self._src = source
        self._transform = transform
        self._crs = crs
        nrows, ncols = source.shape
        res = float(transform.a)
        self._grid = GridSpec(int(nrows), int(ncols), res)
        self._origin = (
            float(transform.c + 0.5 * ncols * res),
            float(transform.f - 0.5 * nrows * res),
        )

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def from_array(
        cls,
        z,
        *,
        resolution_m: float,
        crs=None,
        origin_xy: tuple[float, float] = (0.0, 0.0),
    ) -> Heightfield:
        """In-memory heightfield of ``z[row, col]`` (m; NaN = nodata).

        Args:
            z: 2-D elevations; float32/float64 are kept without copying (do not modify
                the array afterwards), other dtypes are converted to float.
            resolution_m: pixel size (m), > 0.
            crs: projected CRS in metres; default lunar south polar stereographic.
            origin_xy: CRS coordinates (m) of the raster centre (the site origin).

        Raises:
            ConfigError / OutOfRangeError: bad shape, resolution or origin.
            CRSError: ``crs`` is geographic or not in metres.
            NoDataError: ``z`` is all NaN.
        """
        arr = np.asarray(z)
        if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
            raise ConfigError(
                f"z has shape {arr.shape}; a non-empty 2-D (rows, cols) grid is required"
            )
        if arr.dtype.kind not in "fiub":
            raise ConfigError(f"z has dtype {arr.dtype}; a numeric dtype is required")
        if arr.dtype not in (np.float32, np.float64):
            big_int = arr.dtype.kind in "iu" and arr.dtype.itemsize > 2
            arr = arr.astype(np.float64 if big_int else np.float32)
        arr = arr.view()
        arr.flags.writeable = False
        res = float(resolution_m)
        if not (math.isfinite(res) and res > 0.0):
            raise OutOfRangeError(f"resolution_m = {resolution_m!r} is invalid; must be > 0 (m)")
        try:
            ox, oy = (float(v) for v in origin_xy)
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"origin_xy = {origin_xy!r} is invalid; expected (x, y) in m"
            ) from exc
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise OutOfRangeError(f"origin_xy = {origin_xy!r} is invalid; must be finite (m)")
        rcrs = require_projected_metres(
            moon_south_polar_stereographic() if crs is None else crs,
            source="Heightfield.from_array",
        )
        if np.isnan(arr).all():
            raise NoDataError(f"z ({arr.shape[0]} x {arr.shape[1]}) is all NaN (nodata)")
        nrows, ncols = arr.shape
        transform = Affine(res, 0.0, ox - 0.5 * ncols * res, 0.0, -res, oy + 0.5 * nrows * res)
        return cls(_ArraySource(arr), transform=transform, crs=rcrs)

    @classmethod
    def open(cls, path, *, block_size: int = 512, cache_blocks: int = 64) -> Heightfield:
        """Lazily open band 1 of a GeoTIFF DEM (m); nodata reads as NaN.

        Only blocks of ``block_size`` x ``block_size`` pixels that queries touch are read,
        kept in an LRU cache of at most ``cache_blocks`` blocks (default 64 x 512**2 x 4 B
        = 64 MiB for float32). Non-float64 files are read as float32.

        Raises:
            RasterNotFoundError: no such file.
            RasterError: unreadable/corrupt, no geotransform, or not north-up with square
                pixels.
            CRSError: no CRS, geographic (degrees) or not in metres.
            NoDataError: every pixel is nodata.
            OutOfRangeError: bad ``block_size`` (8..65536) or ``cache_blocks`` (>= 1).
        """
        path = os.fspath(path)
        if not 8 <= int(block_size) <= 65536:
            raise OutOfRangeError(f"block_size = {block_size!r} is invalid; allowed 8..65536 px")
        if int(cache_blocks) < 1:
            raise OutOfRangeError(f"cache_blocks = {cache_blocks!r} is invalid; must be >= 1")
        ds = open_raster(path)
        try:
            t = ds.transform
            a, e = float(t.a), float(t.e)
            if t.b != 0 or t.d != 0 or a <= 0 or not math.isclose(-e, a, rel_tol=1e-9):
                raise RasterError(
                    f"raster '{path}' has transform {tuple(t)[:6]}; a north-up transform "
                    "with square pixels (a = -e > 0, b = d = 0) is required"
                )
            crs = ds.crs
            src = _FileSource(path, ds, block_size=int(block_size), cache_blocks=int(cache_blocks))
        except BaseException:
            ds.close()
            raise
        hf = cls(src, transform=Affine(a, 0.0, t.c, 0.0, -a, t.f), crs=crs)
        if not hf._has_valid_data():
            src.close()
            raise NoDataError(f"raster '{path}' holds no valid data: every pixel is nodata")
        return hf

    def _has_valid_data(self) -> bool:
        """True if any pixel is valid: the centre block first, then a bounded-memory scan."""
        nrows, ncols = self.shape
        b = getattr(self._src, "block_size", _IO_TILE)
        r0, c0 = max(0, nrows // 2 - b // 2), max(0, ncols // 2 - b // 2)
        if not np.isnan(self._src.read(r0, c0, min(b, nrows - r0), min(b, ncols - c0))).all():
            return True
        for w in _windows(nrows, ncols, _IO_TILE, _IO_TILE):
            if not np.isnan(self._src.read(*w)).all():
                return True
        return False

    # -- properties -------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """``(nrows, ncols)``."""
        return (self._grid.nrows, self._grid.ncols)

    @property
    def resolution_m(self) -> float:
        """Pixel size (m)."""
        return self._grid.resolution_m

    @property
    def transform(self) -> Affine:
        """Pixel -> CRS affine (m), north-up, pixel-is-area."""
        return self._transform

    @property
    def crs(self):
        """Projected CRS (rasterio ``CRS``), metres."""
        return self._crs

    @property
    def origin_xy(self) -> tuple[float, float]:
        """CRS coordinates (m) of the raster centre = the site origin."""
        return self._origin

    @property
    def grid(self) -> GridSpec:
        return self._grid

    @property
    def bounds(self) -> BoundingBox:
        """Raster extent in site coordinates (m): ``(left, bottom, right, top)``."""
        g = self._grid
        return BoundingBox(g.x_min, -g.y_max, -g.x_min, g.y_max)

    @property
    def dtype(self) -> np.dtype:
        """Storage dtype of elevations (float32 or float64)."""
        return self._src.dtype

    @property
    def path(self) -> str | None:
        """Backing file, or None when in memory."""
        return getattr(self._src, "path", None)

    def cache_info(self) -> BlockCacheInfo | None:
        """Block-cache statistics of a file-backed heightfield (None when in memory)."""
        return self._src.info() if isinstance(self._src, _FileSource) else None

    def close(self) -> None:
        """Release the file handle and block cache (a later query reopens the file)."""
        if isinstance(self._src, _FileSource):
            self._src.close()

    def __enter__(self) -> Heightfield:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __copy__(self) -> Heightfield:
        # Immutable: Drake's AbstractValue copies values; share instead of copying rasters.
        return self

    def __deepcopy__(self, memo) -> Heightfield:
        return self

    def __repr__(self) -> str:
        where = self.path or "in memory"
        return (
            f"Heightfield({self.shape[0]} x {self.shape[1]} px at {self.resolution_m:g} m, "
            f"{where}, origin_xy={self._origin})"
        )

    # -- coordinates ------------------------------------------------------------------------
    def site_to_crs(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """CRS coordinates (m) of site points (m)."""
        return np.asarray(x, float) + self._origin[0], np.asarray(y, float) + self._origin[1]

    def crs_to_site(self, x_crs, y_crs) -> tuple[np.ndarray, np.ndarray]:
        """Site coordinates (m) of CRS points (m)."""
        return (
            np.asarray(x_crs, float) - self._origin[0],
            np.asarray(y_crs, float) - self._origin[1],
        )

    # -- point queries ----------------------------------------------------------------------
    def _locate(self, x, y):
        """Flattened points, their shape, base indices and bilinear fractions."""
        xx, yy = np.broadcast_arrays(
            np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        )
        shape = xx.shape
        xf, yf = xx.ravel(), yy.ravel()
        b = self.bounds
        inside = (xf >= b.left) & (xf <= b.right) & (yf >= b.bottom) & (yf <= b.top)
        if not inside.all():
            bad = np.flatnonzero(~inside)
            i = int(bad[0])
            raise OutOfBoundsError(
                f"site point (x={float(xf[i]):.6g}, y={float(yf[i]):.6g}) m is outside the raster "
                "extent "
                f"x in [{b.left:g}, {b.right:g}] m, y in [{b.bottom:g}, {b.top:g}] m "
                f"({bad.size} of {xf.size} points outside)"
            )
        nrows, ncols = self.shape
        row, col = self._grid.to_pixel(xf, yf)
        row = np.clip(row, 0.0, nrows - 1.0)
        col = np.clip(col, 0.0, ncols - 1.0)
        r0 = np.minimum(np.floor(row).astype(np.int64), max(nrows - 2, 0))
        c0 = np.minimum(np.floor(col).astype(np.int64), max(ncols - 2, 0))
        return xf, yf, shape, r0, c0, row - r0, col - c0

    def _nodata_error(self, what: str, xf, yf, result: np.ndarray) -> NoDataError:
        bad = np.flatnonzero(np.isnan(result))
        i = int(bad[0])
        return NoDataError(
            f"{what} query at site point (x={float(xf[i]):.6g}, y={float(yf[i]):.6g}) m touches "
            "nodata (NaN) "
            f"pixels of '{self._src.name}' ({bad.size} of {xf.size} points affected)"
        )

    def height(self, x, y) -> np.ndarray:
        """Elevation z (m) at site points (m), bilinear between pixel centres.

        ``x`` and ``y`` broadcast; returns float64 of their broadcast shape.

        Raises:
            OutOfBoundsError: a point lies outside the raster extent.
            NoDataError: a point's 2 x 2 interpolation pixels include NaN.
        """
        xf, yf, shape, r0, c0, fr, fc = self._locate(x, y)
        nrows, ncols = self.shape
        r1 = np.minimum(r0 + 1, nrows - 1)
        c1 = np.minimum(c0 + 1, ncols - 1)
        rows = np.stack([r0, r0, r1, r1])
        cols = np.stack([c0, c1, c0, c1])
        v = self._src.gather(rows.ravel(), cols.ravel()).reshape(4, -1)
        top = v[0] + fc * (v[1] - v[0])
        bot = v[2] + fc * (v[3] - v[2])
        z = top + fr * (bot - top)
        if np.isnan(z).any():
            raise self._nodata_error("height", xf, yf, z)
        return z.reshape(shape)[()]

    def within_kernel_args(self, *, margin_m: float = 0.0):
        """``(z, resolution_m, left, right, bottom, top)`` for compiled callers of
        :func:`heights_in_box` (the box shrunk by ``margin_m``, m), or None for a
        file-backed raster. The same lookups as :meth:`heights_within`.

        Raises:
            OutOfRangeError: ``margin_m`` is negative or not a finite number.
        """
        memo = self.__dict__.setdefault("_kernel_args", {})  # per margin: the contact's
        args = memo.get(margin_m)  # hot loop asks every step
        if args is not None:
            return args
        try:
            ok = math.isfinite(float(margin_m)) and float(margin_m) >= 0.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise OutOfRangeError(f"margin_m = {margin_m!r}; a finite distance >= 0 m is required")
        if not isinstance(self._src, _ArraySource):
            return None
        b = self.bounds
        args = memo[margin_m] = (self._src.z, self.resolution_m, b.left + margin_m,
                                 b.right - margin_m, b.bottom + margin_m,
                                 b.top - margin_m)  # fmt: skip
        return args

    def heights_within(self, x, y, *, margin_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Heights (m) and an ``ok`` mask at site points (m) for the contact's hot loop:
        like :meth:`height` (same values), but points off the raster by less than
        ``margin_m`` inside its edge, non-finite points and points touching nodata get
        ``ok`` False and height -inf instead of an error. Compiled for in-memory rasters."""
        xx, yy = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        kernel = self.within_kernel_args(margin_m=margin_m)
        if kernel is not None:
            z, ok = heights_in_box(kernel[0], xx.ravel(), yy.ravel(), *kernel[1:])
            return z.reshape(xx.shape), ok.reshape(xx.shape)
        b = self.bounds
        lo_x, hi_x = b.left + margin_m, b.right - margin_m
        lo_y, hi_y = b.bottom + margin_m, b.top - margin_m
        ok = (xx >= lo_x) & (xx <= hi_x) & (yy >= lo_y) & (yy <= hi_y)
        z = np.full(xx.shape, -np.inf)
        if ok.all():
            try:
                return self.height(xx, yy), ok
            except NoDataError:
                pass
        for k in np.flatnonzero(ok.ravel()):
            try:
                z.ravel()[k] = self.height(xx.ravel()[k : k + 1], yy.ravel()[k : k + 1])[0]
            except (NoDataError, OutOfBoundsError):
                ok.ravel()[k] = False
        return z, ok

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """``(dz/dx, dz/dy)`` (m/m, x east, y north) at site points (m).

        Bilinear interpolation of the central-difference gradients at the four
        surrounding pixel centres (one-sided on the outer rows/columns).

        Raises:
            OutOfBoundsError: a point lies outside the raster extent.
            NoDataError: a NaN pixel is among those the point's gradient uses.
        """
        xf, yf, shape, r0, c0, fr, fc = self._locate(x, y)
        nrows, ncols = self.shape
        k = np.arange(-1, 3)
        ri = np.clip(r0[:, None] + k, 0, nrows - 1)  # (N, 4)
        ci = np.clip(c0[:, None] + k, 0, ncols - 1)
        # 4 x 4 stencil; the four corner pixels are gathered but never used.
        v = self._src.gather(
            np.broadcast_to(ri[:, :, None], (ri.shape[0], 4, 4)).ravel(),
            np.broadcast_to(ci[:, None, :], (ci.shape[0], 4, 4)).ravel(),
        ).reshape(-1, 4, 4)
        res = self.resolution_m
        gx = np.empty((xf.size, 2, 2))
        gy = np.empty((xf.size, 2, 2))
        for a in (1, 2):
            for b in (1, 2):
                dc = (ci[:, b + 1] - ci[:, b - 1]).astype(np.float64)
                dr = (ri[:, a + 1] - ri[:, a - 1]).astype(np.float64)
                nx = v[:, a, b + 1] - v[:, a, b - 1]
                ny = v[:, a - 1, b] - v[:, a + 1, b]  # row index grows southwards
                # dc == 0 only on a 1-pixel-wide axis, where nx is 0 (or NaN): slope 0.
                gx[:, a - 1, b - 1] = nx / (np.maximum(dc, 1.0) * res)
                gy[:, a - 1, b - 1] = ny / (np.maximum(dr, 1.0) * res)

        def blend(g: np.ndarray) -> np.ndarray:
            top = g[:, 0, 0] + fc * (g[:, 0, 1] - g[:, 0, 0])
            bot = g[:, 1, 0] + fc * (g[:, 1, 1] - g[:, 1, 0])
            return top + fr * (bot - top)

        dzdx, dzdy = blend(gx), blend(gy)
        bad = np.isnan(dzdx) | np.isnan(dzdy) | np.isnan(v[:, 1:3, 1:3]).any(axis=(1, 2))
        if bad.any():
            raise self._nodata_error("gradient", xf, yf, np.where(bad, np.nan, 0.0))
        return dzdx.reshape(shape)[()], dzdy.reshape(shape)[()]

    def normal(self, x, y) -> np.ndarray:
        """Unit upward surface normals ``(..., 3)`` (x east, y north, z up) at site points."""
        gx, gy = self.gradient(x, y)
        gx, gy = np.asarray(gx), np.asarray(gy)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.sqrt(1.0 + gx * gx + gy * gy)[..., None]

    def slope(self, x, y) -> np.ndarray:
        """Surface slope (rad, 0 = level) at site points: ``arctan(|grad z|)``."""
        gx, gy = self.gradient(x, y)
        return np.arctan(np.hypot(gx, gy))

    # -- rasters ----------------------------------------------------------------------------
    def read_window(self, row0: int, col0: int, nrows: int, ncols: int) -> np.ndarray:
        """Elevations (m) of a pixel window as a new float32 array (NaN = nodata).

        Raises:
            OutOfBoundsError: the window is empty or not inside the grid.
        """
        check_window(row0, col0, nrows, ncols, *self.shape, source=self._src.name)
        w = self._src.read(int(row0), int(col0), int(nrows), int(ncols))
        return np.array(w, dtype=np.float32, copy=True)

    def decimated(self, *, max_size: int) -> tuple[np.ndarray, float]:
        """Reduced-resolution copy ``(z, resolution_m)`` with ``max(z.shape) <= max_size``.

        Integer factor ``f = ceil(max(nrows, ncols) / max_size)``; output pixel ``(i, j)``
        is the NaN-aware mean of the ``f x f`` input pixels ``[i*f:(i+1)*f, j*f:(j+1)*f]``
        (fewer on the last row/column when ``f`` does not divide the size; NaN if all are
        NaN); ``resolution_m = f * self.resolution_m``. Float32. Files are reduced window
        by window (bounded memory).
        """
        if int(max_size) < 1:
            raise OutOfRangeError(f"max_size = {max_size!r} is invalid; must be >= 1 (px)")
        nrows, ncols = self.shape
        f = max(1, -(-max(nrows, ncols) // int(max_size)))
        out = np.empty((-(-nrows // f), -(-ncols // f)), dtype=np.float32)
        step = f * max(1, -(-_IO_TILE // f))
        for r0, c0, nr, nc in _windows(nrows, ncols, step, step):
            w = self._src.read(r0, c0, nr, nc)
            out[r0 // f : r0 // f + -(-nr // f), c0 // f : c0 // f + -(-nc // f)] = _block_mean(
                w, f
            )
        return out, f * self.resolution_m

    def pyramid(self, *, start_level: int = 0) -> MinMaxPyramid:
        """NaN-aware min/max pyramid (see :class:`MinMaxPyramid`).

        Built window by window, so a file-backed heightfield needs memory only for the
        output levels. ``start_level`` > 0 skips storing the finest levels (each level
        ``k`` costs ``8 / 4**k`` bytes per pixel; level 0, 4 B/px, shares one array).
        """
        nrows, ncols = self.shape
        n_levels, m = 1, max(nrows, ncols)
        while m > 1:
            m, n_levels = -(-m // 2), n_levels + 1
        s = int(start_level)
        if not 0 <= s < n_levels:
            raise OutOfRangeError(
                f"start_level = {start_level!r} is invalid; allowed 0..{n_levels - 1}"
            )
        pyr = MinMaxPyramid(levels=[None] * n_levels, shape=(nrows, ncols))
        hs, ws = pyr.level_shape(s)
        zmin = np.empty((hs, ws), dtype=np.float32)
        zmax = zmin if s == 0 else np.empty((hs, ws), dtype=np.float32)
        p = 1 << s
        step = p * max(1, -(-_IO_TILE // p))
        for r0, c0, nr, nc in _windows(nrows, ncols, step, step):
            w = np.asarray(self._src.read(r0, c0, nr, nc), dtype=np.float32)
            mn = mx = w
            for _ in range(s):
                mn, mx = _reduce2(mn, mx)
            rs, cs = r0 >> s, c0 >> s
            zmin[rs : rs + mn.shape[0], cs : cs + mn.shape[1]] = mn
            if s > 0:
                zmax[rs : rs + mx.shape[0], cs : cs + mx.shape[1]] = mx
        pyr.levels[s] = (zmin, zmax)
        for k in range(s + 1, n_levels):
            pyr.levels[k] = _reduce2(*pyr.levels[k - 1])  # type: ignore[misc]
        return pyr

    def to_geotiff(self, path, *, compress: str | None = None) -> None:
        """Write the elevations as a tiled GeoTIFF (atomic; nodata = NaN)."""
        path = os.fspath(path)
        if isinstance(self._src, _ArraySource):
            write_geotiff(
                path,
                self._src.z,
                transform=self._transform,
                crs=self._crs,
                nodata=float("nan"),
                compress=compress,
            )
            return
        nrows, ncols = self.shape
        with GeoTiffWriter(
            path,
            height=nrows,
            width=ncols,
            count=1,
            dtype=self.dtype,
            transform=self._transform,
            crs=self._crs,
            nodata=float("nan"),
            compress=compress,
        ) as w:
            for r0, c0, nr, nc in _windows(nrows, ncols, _IO_TILE, _IO_TILE):
                w.write(self._src.read(r0, c0, nr, nc), row0=r0, col0=c0)
