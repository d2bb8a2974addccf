"""Level-of-detail terrain meshes from a Heightfield ("terrain to the horizon", paper section 5).

The raster is cut into square tiles of ``tile_px`` x ``tile_px`` level-0 pixels. Each tile
is meshed at one level ``L`` (post spacing ``s = 2**L`` pixels, ``tile_px / s`` cells per
side) chosen from its distance to a centre point (the rover):

* level 0 (every DEM posting a vertex) for tiles closer than ``near_radius_m``;
* level ``L = floor(log2(d / near_radius_m)) + 1`` (capped at ``levels - 1``) for a tile
  at distance ``d`` (from the centre to the tile's xy box), i.e. each ring twice as far
  out has cells twice as large, so the angular size of a cell seen from the centre
  stays roughly constant, out to the whole raster extent.

Vertices ("posts") sit on pixel centres with indices that are multiples of ``s`` (the
last post of the raster is always its last pixel, so the final cell of a row may be
shorter). The outermost posts of the raster are moved out by half a pixel to the raster
edge (heights unchanged), so the mesh covers the whole :attr:`Heightfield.bounds`, with
the same edge clamping as :meth:`Heightfield.height`.

Heights at level ``L > 0`` are a tent (triangle) filter of half-width ``s`` pixels
centred on the post: two ``s x s`` block means convolved, i.e. a block mean that stays
registered to the pixel-centre posts (NaN-aware; edges clamped; computed per tile with
running sums in float64). It is exact for planes and never leaves the range of the
pixels within ``s - 1`` of the post, so the mesh deviates from the DEM at a point by at
most the local relief within ``2 s`` pixels (``test_raycast`` checks this bound). Level
0 uses the DEM values themselves. (Block means, not the min/max pyramid: a max-filtered
far field would raise the horizon line; the mean keeps it unbiased on average.)

Cost: every tile reads its full-resolution window (plus a halo of ``s - 1`` pixels), so
building all tiles touches the whole raster once -- about 0.1-0.3 s for 2048^2 here;
moving the centre rebuilds only tiles whose level changed. For rasters far larger than
the camera needs (tens of thousands of pixels a side), give the far field a decimated
:class:`Heightfield` of its own.

Cracks: adjacent tiles at different levels (or at the same level, where float rounding
could differ) do not share vertices. Every tile edge not on the raster border therefore
carries a *skirt*: a vertical curtain hanging from the edge polyline down to the lowest
DEM value within one tile of that edge (from the min/max pyramid), minus
``skirt_margin_m``. Any neighbour's edge polyline is a convex combination of pixels
within ``s_neighbour - 1 <= tile_px - 1`` pixels of the shared edge, so it lies above
that bottom and the gap between the two polylines is always closed by a skirt: no ray
can pass between tiles. Skirt faces follow the surface faces in each tile
(``faces[n_surface_faces:]``); they are seen only through such gaps, and the shader
gives them an upward normal. Faces touching a NaN (nodata) height are dropped: nodata
holes are see-through.

Tiles are pure functions of (heightfield, level, tile index, tile size, albedo), cached
in a :class:`TileCache` keyed by them, so moving the centre re-uses every tile whose
level did not change.
"""

from __future__ import annotations

import math
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.terrain.heightfield import Heightfield

__all__ = [
    "LODStats",
    "TerrainLOD",
    "TerrainTile",
    "TileCache",
    "default_tile_cache",
    "select_tile_levels",
]


@dataclass(frozen=True)
class TerrainTile:
    """One tile's triangle mesh in the site frame.

    Attributes:
        level: LOD level (post spacing ``2**level`` pixels).
        tile_row, tile_col: tile index (row 0 = north edge, col 0 = west edge).
        vertices: ``(V, 3)`` float32 site-frame positions (m, x east, y north, z up).
        faces: ``(F, 3)`` int32 vertex indices, counter-clockwise seen from above for
            surface faces; ``faces[:n_surface_faces]`` are terrain surface,
            the rest skirts.
        n_surface_faces: number of surface faces.
        albedo: ``(V,)`` float32 per-vertex albedo (same filter as the heights) or None.
    """

    level: int
    tile_row: int
    tile_col: int
    vertices: np.ndarray
    faces: np.ndarray
    n_surface_faces: int
    albedo: np.ndarray | None = None

    @property
    def key(self) -> tuple[int, int, int]:
        """``(level, tile_row, tile_col)``."""
        return (self.level, self.tile_row, self.tile_col)

    @property
    def triangle_count(self) -> int:
        return int(self.faces.shape[0])

    @property
    def skirt_triangle_count(self) -> int:
        return int(self.faces.shape[0]) - self.n_surface_faces


@dataclass(frozen=True)
class LODStats:
    """Triangle/tile counts of one :class:`TerrainLOD`.

    Attributes:
        tiles_per_level: ``{level: number of tiles}``.
        triangles_per_level: ``{level: triangles (surface + skirt)}``.
        surface_triangles, skirt_triangles, vertices: totals.
        cache_hits, cache_misses: tiles re-used from / built into the cache by this build.
    """

    tiles_per_level: dict[int, int]
    triangles_per_level: dict[int, int]
    surface_triangles: int
    skirt_triangles: int
    vertices: int
    cache_hits: int
    cache_misses: int

    @property
    def triangles(self) -> int:
        return self.surface_triangles + self.skirt_triangles


class TileCache:
    """LRU cache of :class:`TerrainTile` keyed by (heightfield, parameters, level, tile).

    Heightfields (and albedo rasters) are keyed by identity and held through weak
    references where possible, so a cache never answers for a different object that
    reused an ``id``. Tiles are deterministic functions of their key, so caching never
    changes a result.
    """

    def __init__(self, *, max_tiles: int = 1024) -> None:
        if int(max_tiles) < 1:
            raise OutOfRangeError(f"max_tiles = {max_tiles!r} is invalid; must be >= 1")
        self.max_tiles = int(max_tiles)
        self._tiles: OrderedDict[tuple, tuple] = OrderedDict()
        self._bottoms: OrderedDict[tuple, tuple] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def clear(self) -> None:
        self._tiles.clear()
        self._bottoms.clear()

    def __len__(self) -> int:
        return len(self._tiles)

    @staticmethod
    def _alive(refs: tuple, objs: tuple) -> bool:
        return all(
            (r() if isinstance(r, weakref.ref) else r) is o for r, o in zip(refs, objs, strict=True)
        )

    @staticmethod
    def _refs(objs: tuple) -> tuple:
        out = []
        for o in objs:
            try:
                out.append(weakref.ref(o))
            except TypeError:
                out.append(o)  # None or an object without weakref support: hold it
        return tuple(out)

    def _lookup(self, table: OrderedDict, key: tuple, objs: tuple):
        entry = table.get(key)
        if entry is not None and self._alive(entry[0], objs):
            table.move_to_end(key)
            return entry[1]
        return None

    def _store(self, table: OrderedDict, key: tuple, objs: tuple, value, limit: int) -> None:
        table[key] = (self._refs(objs), value)
        table.move_to_end(key)
        while len(table) > limit:
            table.popitem(last=False)

    def tile(self, hf, albedo, params: tuple, key: tuple, build):
        """The cached tile for ``key`` or ``build()`` stored under it."""
        objs = (hf, albedo)
        full = (id(hf), id(albedo), params, key)
        t = self._lookup(self._tiles, full, objs)
        if t is not None:
            self.hits += 1
            return t, True
        self.misses += 1
        t = build()
        self._store(self._tiles, full, objs, t, self.max_tiles)
        return t, False

    def skirt_bottoms(self, hf, tile_px: int, build) -> np.ndarray:
        """Cached per-tile skirt bottom heights for ``(hf, tile_px)``."""
        full = (id(hf), int(tile_px))
        b = self._lookup(self._bottoms, full, (hf,))
        if b is None:
            b = build()
            self._store(self._bottoms, full, (hf,), b, 16)
        return b


_DEFAULT_CACHE = TileCache()


def default_tile_cache() -> TileCache:
    """The process-wide cache used when :meth:`TerrainLOD.build` is given none."""
    return _DEFAULT_CACHE


# ----------------------------------------------------------------------------------------
# Tile geometry
# ----------------------------------------------------------------------------------------
def _tile_counts(shape: tuple[int, int], tile_px: int) -> tuple[int, int]:
    return (
        max(1, -(-(shape[0] - 1) // tile_px)),
        max(1, -(-(shape[1] - 1) // tile_px)),
    )


def _posts(start: int, tile_px: int, step: int, n: int) -> np.ndarray:
    """Post (pixel-centre) indices of one tile side: multiples of ``step``, last = n - 1."""
    p = np.minimum(np.arange(start, start + tile_px + 1, step, dtype=np.int64), n - 1)
    return np.unique(p)


def _post_coords(p: np.ndarray, n: int) -> np.ndarray:
    """Fractional pixel coordinate of posts, the raster's outermost moved to its edge."""
    c = p.astype(np.float64)
    c[p == 0] = -0.5
    c[p == n - 1] = n - 0.5
    return c


def _tent_axis0(x: np.ndarray, q: np.ndarray, s: int) -> np.ndarray:
    """Tent filter (weights ``s - |k|``, ``|k| < s``, unnormalized) along axis 0 at rows q."""
    c = np.zeros((x.shape[0] + 1, *x.shape[1:]), dtype=np.float64)
    np.cumsum(x, axis=0, out=c[1:])
    b = c[s:] - c[:-s]  # box sums of s rows starting at each row
    d = np.zeros((b.shape[0] + 1, *b.shape[1:]), dtype=np.float64)
    np.cumsum(b, axis=0, out=d[1:])
    return d[q + 1] - d[q - s + 1]


def _sample_posts(read, shape, pr: np.ndarray, pc: np.ndarray, s: int) -> np.ndarray:
    """Tent-filtered values (float64, NaN-aware, edge-clamped) at posts ``pr x pc``."""
    nrows, ncols = shape
    if s == 1:
        r0, c0 = int(pr[0]), int(pc[0])
        w = read(r0, c0, int(pr[-1]) - r0 + 1, int(pc[-1]) - c0 + 1)
        return np.asarray(w, dtype=np.float64)[np.ix_(pr - r0, pc - c0)]
    h = s - 1
    lo_r, hi_r = int(pr[0]) - h, int(pr[-1]) + h
    lo_c, hi_c = int(pc[0]) - h, int(pc[-1]) + h
    r0, r1 = max(lo_r, 0), min(hi_r, nrows - 1)
    c0, c1 = max(lo_c, 0), min(hi_c, ncols - 1)
    w = np.asarray(read(r0, c0, r1 - r0 + 1, c1 - c0 + 1), dtype=np.float64)
    w = np.pad(w, ((r0 - lo_r, hi_r - r1), (c0 - lo_c, hi_c - c1)), mode="edge")
    valid = ~np.isnan(w)
    if valid.all():
        a = _tent_axis0(w, pr - lo_r, s)
        return _tent_axis0(a.T, pc - lo_c, s).T / float(s * s) ** 2
    wv = np.where(valid, w, 0.0)
    num = _tent_axis0(_tent_axis0(wv, pr - lo_r, s).T, pc - lo_c, s).T
    den = _tent_axis0(_tent_axis0(valid.astype(np.float64), pr - lo_r, s).T, pc - lo_c, s).T
    out = np.full(num.shape, np.nan)
    np.divide(num, den, out=out, where=den > 0.5)  # den counts weight units (>= 1 when any)
    return out


def _grid_faces(nr: int, nc: int) -> np.ndarray:
    """Two CCW (seen from +z) triangles per cell of an ``nr x nc`` post grid (row = south)."""
    i = (np.arange(nr - 1, dtype=np.int64)[:, None] * nc + np.arange(nc - 1)[None, :]).ravel()
    t1 = np.stack([i, i + nc, i + 1], axis=1)
    t2 = np.stack([i + 1, i + nc, i + nc + 1], axis=1)
    return np.stack([t1, t2], axis=1).reshape(-1, 3)


def _build_tile(
    hf: Heightfield,
    albedo: np.ndarray | None,
    level: int,
    tr: int,
    tc: int,
    tile_px: int,
    bottom: float,
    skirts: bool,
) -> TerrainTile:
    nrows, ncols = hf.shape
    s = 1 << level
    pr = _posts(tr * tile_px, tile_px, s, nrows)
    pc = _posts(tc * tile_px, tile_px, s, ncols)
    z = _sample_posts(hf.read_window, hf.shape, pr, pc, s)
    res = hf.resolution_m
    yc = (0.5 * nrows - 0.5 - _post_coords(pr, nrows)) * res
    xc = (_post_coords(pc, ncols) + 0.5 - 0.5 * ncols) * res
    nr, nc = z.shape
    bad = np.isnan(z)
    zf = z.ravel().copy()
    verts = np.empty((nr * nc, 3), dtype=np.float64)
    verts[:, 0] = np.broadcast_to(xc[None, :], (nr, nc)).ravel()
    verts[:, 1] = np.broadcast_to(yc[:, None], (nr, nc)).ravel()
    faces = _grid_faces(nr, nc)
    if bad.any():
        badf = bad.ravel()
        faces = faces[~badf[faces].any(axis=1)]
        zf[badf] = np.nanmin(zf) if (~badf).any() else 0.0
    verts[:, 2] = zf
    n_surface = int(faces.shape[0])
    edges = list(_skirt_edges(nr, nc, tr, tc, pr, pc, nrows, ncols)) if skirts else []
    if edges and n_surface:
        extra_v, extra_f = [], []
        nv = nr * nc
        badf = bad.ravel()
        for e in edges:
            keep = ~badf[e]
            seg = keep[:-1] & keep[1:]
            a, b = e[:-1], e[1:]
            bot = np.arange(nv, nv + e.size, dtype=np.int64)
            ba, bb = bot[:-1], bot[1:]
            bv = verts[e].copy()
            bv[:, 2] = bottom
            extra_v.append(bv)
            extra_f.append(
                np.concatenate(
                    [np.stack([a, b, bb], axis=1)[seg], np.stack([a, bb, ba], axis=1)[seg]]
                )
            )
            nv += e.size
        verts = np.concatenate([verts, *extra_v])
        faces = np.concatenate([faces, *extra_f])
    else:
        edges = []
    alb = None
    if albedo is not None:
        a = _sample_posts(
            lambda r0, c0, h, w: albedo[r0 : r0 + h, c0 : c0 + w], albedo.shape, pr, pc, s
        ).ravel()
        a = np.where(np.isnan(a), 0.0, a)
        # skirt vertices repeat their edge vertex's albedo
        alb = a[np.concatenate([np.arange(a.size), *edges])].astype(np.float32)
    faces32 = faces.astype(np.int32)
    verts32 = verts.astype(np.float32)
    verts32.flags.writeable = False
    faces32.flags.writeable = False
    if alb is not None:
        alb.flags.writeable = False
    return TerrainTile(
        level=level,
        tile_row=tr,
        tile_col=tc,
        vertices=verts32,
        faces=faces32,
        n_surface_faces=n_surface,
        albedo=alb,
    )


def _skirt_edges(nr, nc, tr, tc, pr, pc, nrows, ncols):
    """Vertex-index runs of the tile edges that are not on the raster border."""
    idx = np.arange(nr * nc, dtype=np.int64).reshape(nr, nc)
    if tr > 0:
        yield idx[0, :]
    if int(pr[-1]) < nrows - 1:
        yield idx[-1, :]
    if tc > 0:
        yield idx[:, 0]
    if int(pc[-1]) < ncols - 1:
        yield idx[:, -1]


def _skirt_bottoms(hf: Heightfield, tile_px: int, margin: float) -> np.ndarray:
    """Per tile: min DEM value over the 3 x 3 tiles around it, minus ``margin`` (m)."""
    # A tile larger than the raster uses the coarsest level (the global min: conservative).
    top = max(0, math.ceil(math.log2(max(hf.shape))))
    lvl = min(round(math.log2(tile_px)), top)
    pyr = hf.pyramid(start_level=lvl)
    zmin = pyr.levels[lvl][0].astype(np.float64)  # type: ignore[index]
    nt = _tile_counts(hf.shape, tile_px)
    # cells beyond the tile grid (the last pixel row/col) still bound the edge posts
    p = np.pad(zmin, 1, constant_values=np.nan)
    m = p[1:-1, 1:-1].copy()
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            m = np.fmin(m, p[1 + dr : p.shape[0] - 1 + dr, 1 + dc : p.shape[1] - 1 + dc])
    out = np.full(nt, np.nan)
    h, w = min(nt[0], m.shape[0]), min(nt[1], m.shape[1])
    out[:h, :w] = m[:h, :w]
    finite = np.isfinite(out)
    fallback = float(np.nanmin(zmin)) if np.isfinite(zmin).any() else 0.0
    out[~finite] = fallback
    return out - float(margin)


def select_tile_levels(
    shape: tuple[int, int],
    resolution_m: float,
    *,
    center_xy: tuple[float, float],
    tile_px: int,
    levels: int,
    near_radius_m: float,
) -> np.ndarray:
    """LOD level of every tile, ``(tile_rows, tile_cols)`` int array.

    Level 0 where the tile's xy box is closer than ``near_radius_m`` to ``center_xy``,
    else ``min(levels - 1, floor(log2(d / near_radius_m)) + 1)``.
    """
    nrows, ncols = shape
    ntr, ntc = _tile_counts(shape, tile_px)
    res = float(resolution_m)
    cx, cy = float(center_xy[0]), float(center_xy[1])
    c0 = np.arange(ntc) * tile_px
    c1 = np.minimum(c0 + tile_px, ncols - 1)
    r0 = np.arange(ntr) * tile_px
    r1 = np.minimum(r0 + tile_px, nrows - 1)
    x0 = (c0 + 0.5 - 0.5 * ncols) * res
    x1 = (c1 + 0.5 - 0.5 * ncols) * res
    ytop = (0.5 * nrows - 0.5 - r0) * res
    ybot = (0.5 * nrows - 0.5 - r1) * res
    dx = np.maximum(np.maximum(x0 - cx, cx - x1), 0.0)
    dy = np.maximum(np.maximum(ybot - cy, cy - ytop), 0.0)
    d = np.hypot(dy[:, None], dx[None, :])
    out = np.zeros((ntr, ntc), dtype=np.int64)
    far = d >= near_radius_m
    with np.errstate(divide="ignore"):
        lv = np.floor(np.log2(np.where(far, d, near_radius_m) / near_radius_m)).astype(np.int64)
    out[far] = lv[far] + 1
    return np.clip(out, 0, levels - 1)


# ----------------------------------------------------------------------------------------
# TerrainLOD
# ----------------------------------------------------------------------------------------
class TerrainLOD:
    """A set of LOD tiles covering a Heightfield, fine near ``center_xy``.

    Build with :meth:`build`; move with :meth:`recenter` (re-uses cached tiles).

    Attributes:
        heightfield: the source raster.
        center_xy: site-frame centre (m) the levels were chosen for.
        tile_px, levels, near_radius_m, skirts, skirt_margin_m: build parameters.
        tiles: tuple of :class:`TerrainTile`, ordered by (tile_row, tile_col).
        stats: :class:`LODStats`.
    """

    def __init__(self, *, heightfield, albedo, center_xy, params, tiles, stats, cache) -> None:
        self.heightfield = heightfield
        self.albedo = albedo
        self.center_xy = center_xy
        self.tile_px, self.levels, self.near_radius_m, self.skirts, self.skirt_margin_m = params
        self.tiles: tuple[TerrainTile, ...] = tiles
        self.stats: LODStats = stats
        self._cache = cache

    @classmethod
    def build(
        cls,
        heightfield: Heightfield,
        *,
        center_xy: tuple[float, float] = (0.0, 0.0),
        tile_px: int = 256,
        levels: int | None = None,
        near_radius_m: float = 20.0,
        albedo: np.ndarray | None = None,
        skirts: bool = True,
        skirt_margin_m: float = 0.01,
        cache: TileCache | None = None,
    ) -> TerrainLOD:
        """Tiles covering the whole raster, full resolution within ``near_radius_m``.

        Args:
            heightfield: the DEM (site frame); at least 2 x 2 pixels.
            center_xy: site point (m) the detail is centred on (the rover).
            tile_px: tile side in level-0 pixels; a power of two in 4..4096.
            levels: number of levels (coarsest ``levels - 1``); default
                ``log2(tile_px) - 1`` (>= 4 cells per tile side); at most
                ``log2(tile_px) + 1``.
            near_radius_m: radius (m) of full resolution; level ``L`` starts at
                ``near_radius_m * 2**(L-1)``. > 0.
            albedo: optional ``(nrows, ncols)`` raster aligned with the DEM; each vertex
                gets its filtered value (``TerrainTile.albedo``).
            skirts: add crack-closing skirts (see module docstring).
            skirt_margin_m: extra skirt depth (m) below the bounding minimum, >= 0.
            cache: tile cache; default :func:`default_tile_cache`.

        Raises:
            ConfigError / OutOfRangeError: bad parameters or albedo shape.
        """
        nrows, ncols = heightfield.shape
        if nrows < 2 or ncols < 2:
            raise ConfigError(
                f"heightfield shape {heightfield.shape} is too small; at least 2 x 2 pixels"
            )
        tp = int(tile_px)
        if tp < 4 or tp > 4096 or tp & (tp - 1):
            raise OutOfRangeError(
                f"tile_px = {tile_px!r} is invalid; a power of two in 4..4096 is required"
            )
        max_levels = round(math.log2(tp)) + 1
        nl = max(1, max_levels - 2) if levels is None else int(levels)
        if not 1 <= nl <= max_levels:
            raise OutOfRangeError(
                f"levels = {levels!r} is invalid; allowed 1..{max_levels} for tile_px = {tp}"
            )
        r = float(near_radius_m)
        if not (math.isfinite(r) and r > 0.0):
            raise OutOfRangeError(f"near_radius_m = {near_radius_m!r} is invalid; must be > 0 (m)")
        m = float(skirt_margin_m)
        if not (math.isfinite(m) and m >= 0.0):
            raise OutOfRangeError(
                f"skirt_margin_m = {skirt_margin_m!r} is invalid; must be >= 0 (m)"
            )
        try:
            cxy = (float(center_xy[0]), float(center_xy[1]))
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(
                f"center_xy = {center_xy!r} is invalid; expected (x, y) in m"
            ) from exc
        if not all(math.isfinite(v) for v in cxy):
            raise OutOfRangeError(f"center_xy = {center_xy!r} is invalid; must be finite (m)")
        if albedo is not None:
            albedo = np.asarray(albedo)
            if albedo.shape != heightfield.shape:
                raise ConfigError(
                    f"albedo has shape {albedo.shape}; the heightfield's {heightfield.shape} "
                    "is required"
                )
        params = (tp, nl, r, bool(skirts), m)
        return cls._assemble(
            heightfield, albedo, cxy, params, _DEFAULT_CACHE if cache is None else cache
        )

    @classmethod
    def _assemble(cls, hf, albedo, cxy, params, cache: TileCache) -> TerrainLOD:
        tp, nl, r, skirts, margin = params
        lv = select_tile_levels(
            hf.shape, hf.resolution_m, center_xy=cxy, tile_px=tp, levels=nl, near_radius_m=r
        )
        bottoms = (
            cache.skirt_bottoms(hf, tp, lambda: _skirt_bottoms(hf, tp, 0.0)) - margin
            if skirts
            else None
        )
        tiles = []
        hits = misses = 0
        for tr in range(lv.shape[0]):
            for tc in range(lv.shape[1]):
                level = int(lv[tr, tc])
                bottom = float(bottoms[tr, tc]) if bottoms is not None else 0.0
                t, hit = cache.tile(
                    hf,
                    albedo,
                    (tp, skirts, margin),
                    (level, tr, tc),
                    lambda level=level, tr=tr, tc=tc, bottom=bottom: _build_tile(
                        hf, albedo, level, tr, tc, tp, bottom, skirts
                    ),
                )
                hits += int(hit)
                misses += int(not hit)
                tiles.append(t)
        tpl: dict[int, int] = {}
        trl: dict[int, int] = {}
        for t in tiles:
            tpl[t.level] = tpl.get(t.level, 0) + 1
            trl[t.level] = trl.get(t.level, 0) + t.triangle_count
        stats = LODStats(
            tiles_per_level=dict(sorted(tpl.items())),
            triangles_per_level=dict(sorted(trl.items())),
            surface_triangles=sum(t.n_surface_faces for t in tiles),
            skirt_triangles=sum(t.skirt_triangle_count for t in tiles),
            vertices=sum(int(t.vertices.shape[0]) for t in tiles),
            cache_hits=hits,
            cache_misses=misses,
        )
        return cls(
            heightfield=hf,
            albedo=albedo,
            center_xy=cxy,
            params=params,
            tiles=tuple(tiles),
            stats=stats,
            cache=cache,
        )

    def recenter(self, center_xy: tuple[float, float]) -> TerrainLOD:
        """The LOD for a new centre (m), re-using cached tiles whose level is unchanged."""
        return TerrainLOD.build(
            self.heightfield,
            center_xy=center_xy,
            tile_px=self.tile_px,
            levels=self.levels,
            near_radius_m=self.near_radius_m,
            albedo=self.albedo,
            skirts=self.skirts,
            skirt_margin_m=self.skirt_margin_m,
            cache=self._cache,
        )

    def changes_at(self, center_xy: tuple[float, float]) -> bool:
        """True if :meth:`recenter` at ``center_xy`` would change any tile's level (and so
        the geometry a ray caster must rebuild); cheap, builds nothing."""
        lv = select_tile_levels(
            self.heightfield.shape,
            self.heightfield.resolution_m,
            center_xy=center_xy,
            tile_px=self.tile_px,
            levels=self.levels,
            near_radius_m=self.near_radius_m,
        )
        return not np.array_equal(lv, self.level_grid())

    @property
    def tile_keys(self) -> tuple[tuple[int, int, int], ...]:
        """``(level, tile_row, tile_col)`` of every tile (identifies the geometry)."""
        return tuple(t.key for t in self.tiles)

    @property
    def triangle_count(self) -> int:
        return self.stats.triangles

    def level_grid(self) -> np.ndarray:
        """``(tile_rows, tile_cols)`` array of the level of each tile."""
        ntr, ntc = _tile_counts(self.heightfield.shape, self.tile_px)
        out = np.empty((ntr, ntc), dtype=np.int64)
        for t in self.tiles:
            out[t.tile_row, t.tile_col] = t.level
        return out

    def merged(self) -> tuple[np.ndarray, np.ndarray]:
        """All tiles as one ``(vertices float32 (V, 3), faces int32 (F, 3))`` mesh."""
        vs, fs, off = [], [], 0
        for t in self.tiles:
            vs.append(t.vertices)
            fs.append(t.faces.astype(np.int64) + off)
            off += t.vertices.shape[0]
        return np.concatenate(vs), np.concatenate(fs).astype(np.int32)

    def __repr__(self) -> str:
        s = self.stats
        return (
            f"TerrainLOD({len(self.tiles)} tiles, {s.triangles} triangles "
            f"({s.skirt_triangles} skirt), levels {s.tiles_per_level}, "
            f"center_xy={self.center_xy})"
        )
