"""Wheel-track groove depth as a sparse tiled raster (paper section 5, "Wheel Tracks").

The paper draws tracks into a 1-channel texture over the drivable area ("wherever a rover
wheel travels we draw a groove in the texture ... an anti-aliased dot ... These dots
overlap to give the appearance of a continuous groove") and bump-maps the shader with
its slopes. :class:`TrackRaster` is that texture for a whole site, in metres:

* **Grid.** Global cells of ``cell_m`` (default 0.02 m) anchored at the site origin:
  cell ``(iy, ix)`` covers ``x in [ix c, (ix+1) c)``, ``y in [iy c, (iy+1) c)`` (site
  frame, x east, y north), its value sits at its centre. Cells are grouped in square
  tiles of ``tile_cells`` (256) cells; tile ``(tile_row, tile_col) = (iy // T, ix // T)``
  holds a float32 ``(T, T)`` array indexed ``[iy % T, ix % T]`` (row 0 = south edge:
  tile arrays are *south-up*; :meth:`TrackRaster.window` returns north-up arrays).
  Tiles are created lazily, only where a groove is stamped, and kept in a dict, so a
  200 m x 200 m site costs memory only along the rover's path (256 KiB per 5.12 m x
  5.12 m tile at the defaults).
* **Value.** Groove depth (m, positive down, >= 0); 0 where nothing was stamped or no
  tile exists. Stamps combine by ``max`` (a wheel re-driving a groove never makes it
  shallower).
* **Stamp.** :meth:`TrackRaster.stamp_segment` sweeps a disk of the tread width from p0
  to p1 (a capsule: a rectangle of the tread width with round ends -- the paper's
  overlapping dots made continuous, so joints of a curved polyline have no gaps). The
  cross profile is flat in the middle and rolls off with a half-cosine over the outer
  ``edge_fraction`` of the half-width on each side (never narrower than one cell, as
  anti-aliasing). An optional grouser pattern modulates the depth along the track (see
  :class:`TrackProfile`).
* **Lookup.** :meth:`TrackRaster.depth_at` (also ``__call__``): vectorized bilinear
  interpolation between cell centres (0 for cells without a tile), float32 -- the
  ``track_depth`` callable of :func:`lunar_drake.render.shading.shade`.
* **Copy-on-write.** :meth:`TrackRaster.copy` (also ``copy.copy``/``copy.deepcopy``,
  which Drake's abstract-state cloning uses) shares the tile arrays and marks them
  read-only; a later stamp on either raster copies only the tiles it touches. A copy is
  therefore a frozen snapshot whatever happens to the original, and costs O(tiles) dict
  work, not a copy of the data.

Deterministic: pure elementwise numpy, results independent of call history other than
the sequence of stamps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = ["TrackProfile", "TrackRaster", "groove_profile"]

# A segment longer than this many cells is stamped in pieces, so the work per piece is
# proportional to the capsule's area and not to its bounding box.
_CHUNK_CELLS = 64


@dataclass(frozen=True)
class TrackProfile:
    """Cross-section and tread pattern of a wheel groove.

    Attributes:
        edge_fraction: fraction of the half-width, on each side, over which the depth
            rolls off to 0 with a half-cosine (so the rounded edges make up this
            fraction of the full width); in [0, 1]. The roll-off is never narrower
            than one cell (anti-aliasing). 0.15 is a look choice, not a measurement: the
            Apollo LRV and Lunokhod track photographs show steep-walled grooves whose
            rims crumble over a few centimetres (from memory).
        grouser_pitch_m: along-track spacing of grouser imprints (m); 0 = no pattern. For
            a wheel of radius r with n grousers the imprint spacing is ``2 pi r / n``
            (times 1 - slip; ignored here).
        grouser_fraction: depth modulation amplitude in [0, 1]: along the track the
            depth is multiplied by ``1 - grouser_fraction * (1 - cos(2 pi s / pitch)) /
            2``, with ``s`` the arc length of the wheel centre's path (m) -- full depth
            at the imprints ``s = k pitch``, ``1 - grouser_fraction`` of it midway.
    """

    edge_fraction: float = 0.15
    grouser_pitch_m: float = 0.0
    grouser_fraction: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.edge_fraction <= 1.0:
            raise OutOfRangeError(
                f"edge_fraction = {self.edge_fraction!r} is invalid; allowed [0, 1]"
            )
        if not (math.isfinite(self.grouser_pitch_m) and self.grouser_pitch_m >= 0.0):
            raise OutOfRangeError(
                f"grouser_pitch_m = {self.grouser_pitch_m!r} is invalid; must be >= 0 m "
                "(0 = no grouser pattern)"
            )
        if not 0.0 <= self.grouser_fraction <= 1.0:
            raise OutOfRangeError(
                f"grouser_fraction = {self.grouser_fraction!r} is invalid; allowed [0, 1]"
            )


def groove_profile(dist_m, *, half_width_m: float, edge_m: float) -> np.ndarray:
    """Cross-profile factor in [0, 1] at distance ``dist_m`` (m) from the groove axis:
    1 up to ``half_width_m - edge_m``, a half-cosine down to 0 at ``half_width_m``, 0
    beyond (float64)."""
    d = np.asarray(dist_m, dtype=np.float64)
    inner = half_width_m - edge_m
    if edge_m <= 0.0:
        return (d <= half_width_m).astype(np.float64)
    u = np.clip((d - inner) / edge_m, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


def _finite_xy(p, name: str) -> tuple[float, float]:
    try:
        a = np.asarray(p, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} = {p!r} is invalid; an (x, y) pair in m is required") from exc
    if a.shape not in ((2,), (3,)) or not np.isfinite(a[:2]).all():
        raise ConfigError(f"{name} = {p!r} is invalid; a finite (x, y) pair in m is required")
    return float(a[0]), float(a[1])


class TrackRaster:
    """Sparse tiled raster of wheel-groove depth over the site (see the module docstring).

    Args:
        cell_m: cell size (m), in (0, 1].
        tile_cells: tile side (cells), in [8, 4096].
    """

    def __init__(self, *, cell_m: float = 0.02, tile_cells: int = 256) -> None:
        if not (math.isfinite(cell_m) and 0.0 < cell_m <= 1.0):
            raise OutOfRangeError(f"cell_m = {cell_m!r} is invalid; allowed (0, 1] m")
        if int(tile_cells) != tile_cells or not 8 <= int(tile_cells) <= 4096:
            raise OutOfRangeError(
                f"tile_cells = {tile_cells!r} is invalid; an integer in [8, 4096] is required"
            )
        self._c = float(cell_m)
        self._T = int(tile_cells)
        self._tiles: dict[tuple[int, int], np.ndarray] = {}
        self._owned: set[tuple[int, int]] = set()  # tiles only this raster references

    # -- properties --------------------------------------------------------------------
    @property
    def cell_m(self) -> float:
        """Cell size (m)."""
        return self._c

    @property
    def tile_cells(self) -> int:
        """Tile side (cells)."""
        return self._T

    @property
    def tile_count(self) -> int:
        """Number of allocated tiles."""
        return len(self._tiles)

    @property
    def nbytes(self) -> int:
        """Bytes of tile data referenced (tiles shared with copies are counted in full)."""
        return sum(a.nbytes for a in self._tiles.values())

    def tile_keys(self) -> list[tuple[int, int]]:
        """Sorted ``(tile_row, tile_col)`` keys of the allocated tiles."""
        return sorted(self._tiles)

    def tile(self, key: tuple[int, int]) -> np.ndarray | None:
        """Read-only view of a tile's ``(T, T)`` float32 array (south-up), or None."""
        a = self._tiles.get((int(key[0]), int(key[1])))
        if a is None:
            return None
        v = a.view()
        v.flags.writeable = False
        return v

    def bounds(self) -> tuple[float, float, float, float] | None:
        """``(left, bottom, right, top)`` (site m) of the allocated tiles, or None."""
        if not self._tiles:
            return None
        k = np.array(list(self._tiles), dtype=np.int64)
        s = self._T * self._c
        return (
            float(k[:, 1].min() * s),
            float(k[:, 0].min() * s),
            float((k[:, 1].max() + 1) * s),
            float((k[:, 0].max() + 1) * s),
        )

    # -- copy-on-write -------------------------------------------------------------------
    def copy(self) -> TrackRaster:
        """A snapshot sharing the tile arrays (copy-on-write: O(tiles), no data copied).

        Both rasters stay independent: whichever is stamped next copies the tiles it
        touches first. The shared arrays are made read-only; the source only loses its
        private-tile bookkeeping (its values never change), so copying from a Drake
        output calculation is safe.
        """
        new = TrackRaster.__new__(TrackRaster)
        new._c = self._c
        new._T = self._T
        for k in self._owned:
            self._tiles[k].flags.writeable = False
        self._owned = set()
        new._tiles = dict(self._tiles)
        new._owned = set()
        return new

    def __copy__(self) -> TrackRaster:
        return self.copy()

    def __deepcopy__(self, memo) -> TrackRaster:
        return self.copy()

    def _writable_tile(self, key: tuple[int, int]) -> np.ndarray:
        a = self._tiles.get(key)
        if a is None:
            a = np.zeros((self._T, self._T), dtype=np.float32)
        elif key in self._owned:
            return a
        else:
            a = a.copy()  # copy-on-write: the old array may be referenced by a snapshot
        self._tiles[key] = a
        self._owned.add(key)
        return a

    # -- stamping ------------------------------------------------------------------------
    def stamp_segment(
        self,
        p0_xy,
        p1_xy,
        *,
        width_m: float,
        depth_m: float,
        depth_end_m: float | None = None,
        s0_m: float = 0.0,
        profile: TrackProfile = TrackProfile(),
    ) -> None:
        """Stamps the groove swept by a wheel from ``p0_xy`` to ``p1_xy`` (site m).

        Every cell whose centre lies within ``width_m / 2`` of the segment gets
        ``max(existing, depth(t) * groove_profile(dist) * grouser(s))`` with ``t`` in
        [0, 1] the position of the cell's nearest point on the segment, ``depth(t)``
        linear from ``depth_m`` to ``depth_end_m`` (default ``depth_m``) and ``s = s0_m
        + t' * length`` (m) the arc length used by the grouser pattern, ``t'`` the
        unclipped position along the segment's line (so the end caps continue the
        pattern rather than smear the end's phase). ``p0 == p1``
        stamps a disk of diameter ``width_m``. Only the cells in the capsule's bounding
        box are evaluated (long segments in pieces); tiles are created only where the
        stamp is non-zero.

        Args:
            p0_xy, p1_xy: start and end of the wheel path ((x, y) or (x, y, z); z ignored).
            width_m: tread width (m), > 0. depth_m, depth_end_m: groove depth (m), >= 0.
            s0_m: arc length of the wheel's path at p0 (m), for the grouser phase.
            profile: :class:`TrackProfile`.
        """
        x0, y0 = _finite_xy(p0_xy, "p0_xy")
        x1, y1 = _finite_xy(p1_xy, "p1_xy")
        if not (math.isfinite(width_m) and width_m > 0.0):
            raise OutOfRangeError(f"width_m = {width_m!r} is invalid; must be finite and > 0 m")
        d0 = float(depth_m)
        d1 = d0 if depth_end_m is None else float(depth_end_m)
        for name, d in (("depth_m", d0), ("depth_end_m", d1)):
            if not (math.isfinite(d) and d >= 0.0):
                raise OutOfRangeError(f"{name} = {d!r} is invalid; must be finite and >= 0 m")
        if not math.isfinite(s0_m):
            raise OutOfRangeError(f"s0_m = {s0_m!r} is invalid; must be finite (m)")
        if d0 == 0.0 and d1 == 0.0:
            return
        length = math.hypot(x1 - x0, y1 - y0)
        n = max(1, math.ceil(length / (_CHUNK_CELLS * self._c)))
        for k in range(n):
            ta, tb = k / n, (k + 1) / n
            self._stamp_capsule(
                (x0 + ta * (x1 - x0), y0 + ta * (y1 - y0)),
                (x0 + tb * (x1 - x0), y0 + tb * (y1 - y0)),
                half=0.5 * float(width_m),
                d0=d0 + ta * (d1 - d0),
                d1=d0 + tb * (d1 - d0),
                s0=float(s0_m) + ta * length,
                profile=profile,
            )

    def _stamp_capsule(self, p0, p1, *, half, d0, d1, s0, profile: TrackProfile) -> None:
        c, T = self._c, self._T
        x0, y0 = p0
        dx, dy = p1[0] - x0, p1[1] - y0
        L2 = dx * dx + dy * dy
        length = math.sqrt(L2)
        edge = min(half, max(profile.edge_fraction * half, c))
        # cells whose centre (i + 0.5) c lies in the capsule's bounding box
        ix_lo = math.ceil((min(x0, x0 + dx) - half) / c - 0.5)
        ix_hi = math.floor((max(x0, x0 + dx) + half) / c - 0.5)
        iy_lo = math.ceil((min(y0, y0 + dy) - half) / c - 0.5)
        iy_hi = math.floor((max(y0, y0 + dy) + half) / c - 0.5)
        if ix_hi < ix_lo or iy_hi < iy_lo:
            return
        grouser = profile.grouser_pitch_m > 0.0 and profile.grouser_fraction > 0.0
        for tr in range(iy_lo // T, iy_hi // T + 1):
            a_y, b_y = max(iy_lo, tr * T), min(iy_hi, tr * T + T - 1)
            yc = (np.arange(a_y, b_y + 1, dtype=np.float64) + 0.5) * c - y0
            for tc in range(ix_lo // T, ix_hi // T + 1):
                a_x, b_x = max(ix_lo, tc * T), min(ix_hi, tc * T + T - 1)
                xc = (np.arange(a_x, b_x + 1, dtype=np.float64) + 0.5) * c - x0
                qx = xc[None, :]
                qy = yc[:, None]
                if L2 > 0.0:
                    t_line = (qx * dx + qy * dy) / L2  # along the line, unclipped
                    t = np.clip(t_line, 0.0, 1.0)
                    dist = np.hypot(qx - t * dx, qy - t * dy)
                else:
                    t_line = t = np.zeros((yc.size, xc.size))
                    dist = np.hypot(qx, qy)
                f = groove_profile(dist, half_width_m=half, edge_m=edge)
                if not (f > 0.0).any():
                    continue
                val = (d0 + t * (d1 - d0)) * f
                if grouser:
                    # the cell's own along-track position, also in the round end caps, so
                    # overlapping caps of consecutive segments carry the same phase
                    s = s0 + t_line * length
                    g = 1.0 - profile.grouser_fraction * 0.5 * (
                        1.0 - np.cos((2.0 * np.pi / profile.grouser_pitch_m) * s)
                    )
                    val = val * g
                tile = self._writable_tile((tr, tc))
                sub = tile[a_y - tr * T : b_y - tr * T + 1, a_x - tc * T : b_x - tc * T + 1]
                np.maximum(sub, val.astype(np.float32), out=sub)

    # -- lookup --------------------------------------------------------------------------
    def depth_at(self, x, y) -> np.ndarray:
        """Groove depth (m, positive down) at site points ``(x, y)`` (broadcast arrays).

        Bilinear between cell centres; cells without a tile count as 0; non-finite
        coordinates give 0. Returns float32 of the broadcast shape.
        """
        xb, yb = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        shape = xb.shape
        out = np.zeros(xb.size, dtype=np.float32)
        if not self._tiles or out.size == 0:
            return out.reshape(shape)
        T, c = self._T, self._c
        P = T + 1  # padded tile side: a tile plus one row/column of its N/E neighbours
        keys = np.array(list(self._tiles), dtype=np.int64)  # (K, 2): tile_row, tile_col
        # Base tiles (of a point's south-west stencil cell) that can see a stamped cell:
        # the allocated tiles and their south / west / south-west neighbours.
        r0, q0 = keys.min(axis=0) - 1
        r1, q1 = keys.max(axis=0)
        nq = int(q1 - q0 + 1)
        fx = xb.reshape(-1) / c
        fx -= 0.5
        fy = yb.reshape(-1) / c
        fy -= 0.5
        near = (fx >= (q0 + 1) * T - 1) & (fx < (q1 + 1) * T)  # NaN compares False
        near &= fy >= (r0 + 1) * T - 1
        near &= fy < (r1 + 1) * T
        if near.all():
            idx = None
        else:
            idx = np.flatnonzero(near)
            if idx.size == 0:
                return out.reshape(shape)
            fx = fx[idx]
            fy = fy[idx]
        ix = np.floor(fx)
        wx = fx - ix  # in place would alias the caller's float64 input
        iy = np.floor(fy)
        wy = fy - iy
        q, lx = np.divmod(ix.astype(np.int64), T)
        r, ly = np.divmod(iy.astype(np.int64), T)
        g = r - r0
        g *= nq
        g += q
        g -= q0  # base tile, row-major in the extended bounding box
        used = np.flatnonzero(np.bincount(g, minlength=int(r1 - r0 + 1) * nq))
        pads = []
        local = np.zeros(int(r1 - r0 + 1) * nq, dtype=np.int64)  # 0 = all-zero tile
        tiles = self._tiles
        for b in used.tolist():
            tr, tc = int(r0) + b // nq, int(q0) + b % nq
            a, n, e, ne = (
                tiles.get((tr, tc)),
                tiles.get((tr + 1, tc)),
                tiles.get((tr, tc + 1)),
                tiles.get((tr + 1, tc + 1)),
            )
            if a is None and n is None and e is None and ne is None:
                continue
            pad = np.zeros((P, P), dtype=np.float32)
            if a is not None:
                pad[:T, :T] = a
            if n is not None:
                pad[T, :T] = n[0]
            if e is not None:
                pad[:T, T] = e[:, 0]
            if ne is not None:
                pad[T, T] = ne[0, 0]
            pads.append(pad)
            local[b] = len(pads)
        if not pads:
            return out.reshape(shape)
        flat = np.concatenate([np.zeros(P * P, np.float32)] + [p.reshape(-1) for p in pads])
        base = local[g]
        base *= P * P
        ly *= P
        base += ly
        base += lx
        v00 = flat[base]
        base += 1
        v01 = flat[base]
        base += P
        v11 = flat[base]
        base -= 1
        v10 = flat[base]
        v01 -= v00
        top = v00 + wx * v01
        v11 -= v10
        bot = v10 + wx * v11
        bot -= top
        bot *= wy
        bot += top
        if idx is None:
            out[:] = bot
        else:
            out[idx] = bot
        return out.reshape(shape)

    __call__ = depth_at

    # -- export --------------------------------------------------------------------------
    def window(
        self, *, left: float, bottom: float, right: float, top: float
    ) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """Cell values covering a site rectangle (m), snapped outward to cell edges.

        Returns ``(values, bounds)``: a north-up float32 ``(rows, cols)`` array (row 0 =
        north edge) and its ``(left, bottom, right, top)`` in site m, ready for
        :class:`lunar_drake.render.shading.RasterSampler` (``RasterSampler(values,
        bounds=bounds, outside=0.0)`` matches :meth:`depth_at` away from the edges and
        gives the shader analytic gradients).
        """
        return self._cells(*self._cell_span(left, bottom, right, top))

    def _cell_span(self, left, bottom, right, top) -> tuple[int, int, int, int]:
        """``(ix_lo, ix_hi, iy_lo, iy_hi)``: the global cells covering a site rectangle (m),
        snapped outward. Raises OutOfRangeError for a non-finite or empty rectangle."""
        lo = (float(left), float(bottom), float(right), float(top))
        if not all(math.isfinite(v) for v in lo) or not (lo[2] > lo[0] and lo[3] > lo[1]):
            raise OutOfRangeError(
                f"window ({left!r}, {bottom!r}, {right!r}, {top!r}) is invalid; need finite "
                "values with right > left and top > bottom (m)"
            )
        c = self._c
        return (math.floor(lo[0] / c), math.ceil(lo[2] / c) - 1,
                math.floor(lo[1] / c), math.ceil(lo[3] / c) - 1)  # fmt: skip

    def _cells(self, ix_lo: int, ix_hi: int, iy_lo: int, iy_hi: int):
        """:meth:`window` of the global cells ``ix_lo..ix_hi`` x ``iy_lo..iy_hi``."""
        c, T = self._c, self._T
        vals = np.zeros((iy_hi - iy_lo + 1, ix_hi - ix_lo + 1), dtype=np.float32)
        for (tr, tc), a in self._tiles.items():
            ay, by = max(iy_lo, tr * T), min(iy_hi, tr * T + T - 1)
            ax, bx = max(ix_lo, tc * T), min(ix_hi, tc * T + T - 1)
            if by < ay or bx < ax:
                continue
            vals[ay - iy_lo : by - iy_lo + 1, ax - ix_lo : bx - ix_lo + 1] = a[
                ay - tr * T : by - tr * T + 1, ax - tc * T : bx - tc * T + 1
            ]
        bounds = (ix_lo * c, iy_lo * c, (ix_hi + 1) * c, (iy_hi + 1) * c)
        return vals[::-1].copy(), bounds

    def tracked_window(
        self, *, left: float, bottom: float, right: float, top: float, margin_cells: int = 2
    ) -> tuple[np.ndarray, tuple[float, float, float, float]] | None:
        """:meth:`window` cut down to the allocated tiles inside the rectangle, grown by
        ``margin_cells`` cells of the rectangle (None when no tile meets it).

        Every cell of the rectangle outside the result is 0, and with the default margin
        (2) so are the result's two outermost rings wherever they are not the
        rectangle's own edge: ``RasterSampler(values, bounds=bounds, outside=0.0)`` then
        has the values and the central-difference gradients of the whole window
        everywhere (both 0 off the tiles), at a fraction of its cells -- a camera's
        50 m window holds 6.8 M cells at 2 cm, the rover's recent tracks a few tiles.
        """
        if int(margin_cells) != margin_cells or margin_cells < 0:
            raise OutOfRangeError(
                f"margin_cells = {margin_cells!r} is invalid; an integer >= 0 is required"
            )
        T = self._T
        ix_lo, ix_hi, iy_lo, iy_hi = self._cell_span(left, bottom, right, top)
        hit = [
            (tr, tc)
            for tr, tc in self._tiles
            if tr * T <= iy_hi and tr * T + T - 1 >= iy_lo and tc * T <= ix_hi
            and tc * T + T - 1 >= ix_lo
        ]  # fmt: skip
        if not hit:
            return None
        m = int(margin_cells)
        rows = [tr for tr, _ in hit]
        cols = [tc for _, tc in hit]
        ax, bx = max(ix_lo, min(cols) * T - m), min(ix_hi, max(cols) * T + T - 1 + m)
        ay, by = max(iy_lo, min(rows) * T - m), min(iy_hi, max(rows) * T + T - 1 + m)
        return self._cells(ax, bx, ay, by)

    def __repr__(self) -> str:
        return (
            f"TrackRaster(cell_m={self._c}, tile_cells={self._T}, tiles={len(self._tiles)}, "
            f"nbytes={self.nbytes})"
        )
