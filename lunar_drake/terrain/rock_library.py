"""Procedural rock height-field library and rock stamping (paper section 4, last paragraph).

"For each rock to be inserted, a model is randomly selected from a library of high
resolution rock heightfields. The model is scaled to the desired size, then overlaid onto
the terrain." A :class:`RockLibrary` holds ``n`` unit height-fields; :func:`stamp_rocks`
scales one per catalog rock onto a DEM tile and writes the rock mask.

Library conventions
-------------------
* ``shapes[k]`` is an ``s x s`` float32 array spanning one unit of width; pixel ``(i, j)``
  has its centre at ``u = (j + 0.5) / s - 0.5`` (east) and ``v = 0.5 - (i + 0.5) / s``
  (north), like a site grid (row 0 is the northern edge).
* Heights are in units of the rock's vertical extent: peak exactly 1.0, 0 outside the
  footprint. The footprint is a star-shaped blob around the array centre whose farthest
  point lies ``1.5`` library pixels inside the array edge, so the outer ring is all 0.
* With an odd ``s`` (default 65) the summit is the central pixel ``u = v = 0``.

Stamping conventions
--------------------
* A rock's catalog *diameter* ``D`` is the area-equivalent diameter of its visible
  footprint (the part standing above the ground it is seated on), the quantity rock
  counts report (Golombek & Rapp 1997, JGR 102(E2) 4117; Golombek et al. 2008, JGR
  113 E00A09). Its *height* ``H`` is how far its top stands above that ground.
* Each rock is embedded: a fraction :data:`EMBEDMENT` of its vertical extent ``Hs`` lies
  below ground, so ``Hs = H / (1 - EMBEDMENT)`` and its base sits at
  ``base_z - EMBEDMENT * Hs``. Lunar boulders sit partly buried in regolith (Surveyor
  and Apollo surface images); 15 % is an assumed, modest value that keeps the visible
  footprint close to the full model's.
* The seat height ``base_z`` is supplied by the caller (the pre-rock surface at the
  rock centre) so that a rock's geometry never depends on which tile is computed.
* Each rock is rotated by an angle hashed from its catalog id (or, without ids, from
  the bits of its coordinates), sampled bilinearly, merged with ``z = max(z, rock)``
  (order independent), and its summit pinned to the pixel(s) nearest its centre so every
  rock, even a sub-pixel one, shows its catalog height. Every step is elementwise on
  global pixel coordinates: a pixel's bytes do not depend on the tiling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.terrain.grid import window_batches

EMBEDMENT = 0.15
"""Fraction of a rock's vertical extent buried below its seat height (dimensionless)."""

MASK_THRESHOLD_M = 1e-3
"""A pixel is rock where the rock surface stands more than this above the terrain (m)."""

MAX_REACH_PER_DIAMETER = 0.75
"""Upper bound of (farthest rock-surface point from the rock centre) / D for every
library shape; callers select rocks per tile with ``reach = 0.75 * D + 2 * resolution``."""

_MIN_SHAPES = 16
_KINDS = ("dome", "flat", "pointy", "angular")
_ROTATION_KEY = rng.stream_key(0, "terrain/rock_rotation")
_ROTATION_KEY_XY = rng.stream_key(0, "terrain/rock_rotation_xy")


@dataclass(frozen=True)
class RockLibrary:
    """Unit rock height-fields.

    Attributes:
        shapes: float32 ``(n, s, s)``; peak 1.0, 0 outside each footprint (see module doc).
        kinds: name of each shape's profile family ("dome", "flat", "pointy", "angular").
        visible_diameter: float64 ``(n,)``; area-equivalent diameter (in array widths) of
            the part of each shape above :data:`EMBEDMENT` (derived, not an argument).
        reach: float64 ``(n,)``; farthest nonzero-pixel distance from the array centre
            (in array widths, including the bilinear spill of one library pixel) (derived).
    """

    shapes: np.ndarray
    kinds: tuple[str, ...] = ()
    visible_diameter: np.ndarray = field(init=False, repr=False)
    reach: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        shapes = np.asarray(self.shapes)
        if shapes.ndim != 3 or shapes.shape[1] != shapes.shape[2] or shapes.shape[1] < 8:
            raise ConfigError(f"shapes has shape {shapes.shape!r}; expected (n, s, s) with s >= 8")
        if shapes.shape[0] < 1:
            raise ConfigError("shapes holds no rock; expected at least one (n >= 1)")
        shapes = np.ascontiguousarray(shapes, dtype=np.float32)
        if not np.all(np.isfinite(shapes)) or shapes.min() < 0:
            raise OutOfRangeError("shapes must be finite and >= 0 everywhere")
        peaks = shapes.max(axis=(1, 2))
        if not np.all(peaks == 1.0):
            k = int(np.flatnonzero(peaks != 1.0)[0])
            raise OutOfRangeError(f"shapes[{k}] peaks at {float(peaks[k])!r}; must peak at 1.0")
        if (
            shapes[:, 0, :].any()
            or shapes[:, -1, :].any()
            or shapes[:, :, 0].any()
            or shapes[:, :, -1].any()
        ):
            raise OutOfRangeError("shapes must be 0 on their outer ring (footprint inside array)")
        if self.kinds and len(self.kinds) != shapes.shape[0]:
            raise ConfigError(f"kinds has {len(self.kinds)} entries for {shapes.shape[0]} shapes")
        shapes.setflags(write=False)
        vis = np.array([_visible_diameter(sh) for sh in shapes])
        if not np.all(vis > 0):
            k = int(np.flatnonzero(~(vis > 0))[0])
            raise OutOfRangeError(f"shapes[{k}] has no part above EMBEDMENT = {EMBEDMENT}")
        reach = np.array([_reach(sh) for sh in shapes])
        object.__setattr__(self, "shapes", shapes)
        object.__setattr__(self, "visible_diameter", vis)
        object.__setattr__(self, "reach", reach)

    @property
    def n_shapes(self) -> int:
        return int(self.shapes.shape[0])

    @property
    def size_px(self) -> int:
        return int(self.shapes.shape[1])

    def reach_per_diameter(self) -> np.ndarray:
        """Farthest reach of each shape's stamped surface from the rock centre, per D."""
        return self.reach / self.visible_diameter


def _visible_diameter(sh: np.ndarray) -> float:
    """Area-equivalent diameter (array widths) of the part of a shape above EMBEDMENT."""
    return 2.0 * math.sqrt(np.count_nonzero(sh > EMBEDMENT) / math.pi) / sh.shape[0]


def _reach(sh: np.ndarray) -> float:
    """Farthest nonzero pixel centre from the array centre plus one pixel (array widths)."""
    s = sh.shape[0]
    c = (np.arange(s) + 0.5) / s - 0.5
    return float(np.hypot(c[:, None], c[None, :])[sh > 0].max()) + 1.0 / s


def _reach_per_diameter(sh: np.ndarray) -> float:
    vis = _visible_diameter(sh)
    return _reach(sh) / vis if vis > 0 else math.inf


def _profile(kind: str, rho: np.ndarray, q: np.ndarray, g: np.random.Generator, r_of):
    """Height (peak 1 at rho = 0, 0 at rho >= 1) for one profile family."""
    rho = np.minimum(rho, 1.0)
    if kind == "dome":
        # Ellipsoidal cap (p = 0.5) to squat domes / steep-sided blocks.
        p = g.uniform(0.35, 0.75)
        return (1.0 - rho**2) ** p
    if kind == "flat":
        # Flat-topped slab: rounded edges rising to a plateau.
        m = g.uniform(2.0, 4.0)
        c = g.uniform(1.3, 2.2)
        return np.minimum(1.0, c * (1.0 - rho**m))
    if kind == "pointy":
        # Cone-like with concave flanks and a sharp summit.
        m = g.uniform(1.1, 1.5)
        p = g.uniform(0.8, 1.2)
        return (1.0 - rho**m) ** p
    # Angular: a faceted pyramid (planes through the footprint edge in K directions),
    # truncated by a steep dome so it reaches 0 smoothly at the footprint edge.
    n_facets = int(g.integers(4, 8))
    phis = np.sort(g.uniform(0.0, 2.0 * math.pi, n_facets))
    h = np.full(rho.shape, np.inf)
    for phi in phis:
        nx, ny = math.cos(phi), math.sin(phi)
        slope = g.uniform(1.0, 1.8)
        edge = r_of(np.array([phi]))[0]
        h = np.minimum(h, slope * (1.0 - (q[0] * nx + q[1] * ny) / edge))
    cap = g.uniform(1.2, 1.6) * np.sqrt(np.maximum(1.0 - rho**2, 0.0))
    return np.clip(np.minimum(h, cap), 0.0, 1.0)


def _make_shape(kind: str, s: int, shape_seed: int) -> np.ndarray:
    """One unit shape; drawn twice from the same seed, the second time zoomed so the
    farthest footprint pixel lies 1.5 pixels inside the array edge."""
    h = _draw_shape(kind, s, np.random.Generator(np.random.PCG64(shape_seed)), 1.0)
    c = (np.arange(s) + 0.5) / s - 0.5
    far = float(np.hypot(c[:, None], c[None, :])[h > 0].max())
    return _draw_shape(
        kind, s, np.random.Generator(np.random.PCG64(shape_seed)), far / (0.5 - 1.5 / s)
    )


def _draw_shape(kind: str, s: int, g: np.random.Generator, zoom: float) -> np.ndarray:
    c = ((np.arange(s) + 0.5) / s - 0.5) * zoom
    u = c[None, :]
    v = -c[:, None]
    # Footprint: polar radius with a few random Fourier harmonics, in a frame rotated by
    # alpha and stretched by `aspect` along its x axis (elongated rocks).
    ks = np.arange(2, 7)
    amps = g.uniform(0.0, 0.18, ks.size) / np.sqrt(ks)
    phases = g.uniform(0.0, 2.0 * math.pi, ks.size)
    aspect = g.uniform(1.0, 1.25) if g.uniform() < 0.5 else g.uniform(1.3, 1.7)
    alpha = g.uniform(0.0, math.pi)

    def r_of(theta):
        r = 1.0 + np.sum(amps[:, None] * np.cos(ks[:, None] * theta[None, :] + phases[:, None]), 0)
        return np.maximum(r, 0.45)

    ca, sa = math.cos(alpha), math.sin(alpha)
    px = ca * u + sa * v
    py = -sa * u + ca * v
    qx, qy = px / aspect, py
    # Scale so the farthest footprint point lies 1.5 library pixels inside the edge.
    th = np.linspace(0.0, 2.0 * math.pi, 4096, endpoint=False)
    rb = r_of(th)
    far = np.max(rb * np.hypot(aspect * np.cos(th), np.sin(th)))
    r0 = (0.5 - 1.5 / s) / far
    theta = np.arctan2(qy, qx)
    rho = np.hypot(qx, qy) / (r0 * r_of(theta.ravel()).reshape(theta.shape))
    q = (qx / r0, qy / r0)
    h = _profile(kind, rho, q, g, r_of)
    # Surface relief: dents from a few smooth random modes; they only lower the surface
    # (never at the summit), so the peak stays 1 at the centre.
    n_modes = 6
    freq = g.uniform(1.5, 5.0, n_modes)
    ang = g.uniform(0.0, 2.0 * math.pi, n_modes)
    ph = g.uniform(0.0, 2.0 * math.pi, n_modes)
    w = np.zeros_like(h)
    for f, a, p in zip(freq, ang, ph, strict=True):
        w += np.cos(2.0 * math.pi * f * (math.cos(a) * u + math.sin(a) * v) + p)
    w = 0.5 + 0.5 * w / np.sqrt(n_modes / 2.0)
    dent = g.uniform(0.05, 0.2)
    h = h * (1.0 - dent * np.minimum(rho, 1.0) ** 2 * np.clip(w, 0.0, 1.0))
    h = np.where(rho < 1.0, np.maximum(h, 0.0), 0.0)
    h[0, :] = h[-1, :] = h[:, 0] = h[:, -1] = 0.0
    return (h / h.max()).astype(np.float32)


def make_rock_library(*, n_shapes: int = 16, size_px: int = 65, seed: int = 0) -> RockLibrary:
    """Deterministic library of varied procedural rocks.

    Args:
        n_shapes: number of shapes (>= 16); families cycle dome, flat-topped, pointy,
            angular, each with random footprint (Fourier-perturbed, some elongated up to
            1.8:1), profile exponents and surface dents.
        size_px: library resolution ``s`` (pixels per side, >= 16; odd puts the summit
            on the central pixel).
        seed: random seed; the stream is ``rng.generator(seed, "rock_library")``.
    """
    if isinstance(n_shapes, bool) or not isinstance(n_shapes, (int, np.integer)):
        raise ConfigError(f"n_shapes = {n_shapes!r} must be an integer >= {_MIN_SHAPES}")
    if n_shapes < _MIN_SHAPES:
        raise OutOfRangeError(f"n_shapes = {n_shapes!r}; allowed >= {_MIN_SHAPES}")
    if isinstance(size_px, bool) or not isinstance(size_px, (int, np.integer)):
        raise ConfigError(f"size_px = {size_px!r} must be an integer in [16, 1024]")
    if not 16 <= size_px <= 1024:
        raise OutOfRangeError(f"size_px = {size_px!r}; allowed [16, 1024]")
    g = rng.generator(seed, "rock_library")
    kinds = tuple(_KINDS[k % len(_KINDS)] for k in range(int(n_shapes)))
    shapes = []
    for kind in kinds:
        # Redraw (from the same stream, so still deterministic) the rare shape whose
        # visible part is too small for its extent: callers rely on the reach bound.
        for _ in range(100):
            sh = _make_shape(kind, int(size_px), int(g.integers(0, 2**63)))
            if _reach_per_diameter(sh) <= MAX_REACH_PER_DIAMETER:
                break
        else:  # pragma: no cover - practically unreachable
            raise ConfigError(f"could not draw a {kind!r} rock within the reach bound")
        shapes.append(sh)
    return RockLibrary(shapes=np.stack(shapes), kinds=kinds)


def _as_1d(name: str, a, n: int | None, dtype=np.float64) -> np.ndarray:
    arr = np.asarray(a, dtype=dtype)
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        want = "1-D" if n is None else f"shape ({n},)"
        raise ConfigError(f"{name} has shape {arr.shape!r}; expected {want}")
    return arr


def _rotation(rock_ids, rocks_x, rocks_y) -> tuple[np.ndarray, np.ndarray]:
    """cos/sin of each rock's in-plane rotation, from its id or (failing that) position."""
    if rock_ids is not None:
        ids = np.asarray(rock_ids, dtype=np.int64)
        u = rng.hash_uniform(_ROTATION_KEY, ids >> 31, ids & 0x7FFFFFFF)
    else:
        lo = np.uint64(0x7FFFFFFF)
        bx = np.ascontiguousarray(rocks_x, dtype=np.float64).view(np.uint64)
        by = np.ascontiguousarray(rocks_y, dtype=np.float64).view(np.uint64)
        i = ((bx ^ (bx >> np.uint64(32))) & lo).astype(np.int64)
        j = ((by ^ (by >> np.uint64(32))) & lo).astype(np.int64)
        u = rng.hash_uniform(_ROTATION_KEY_XY, i, j)
    # math.cos/sin per rock (libm), not a vectorized ufunc whose SIMD path could depend
    # on where a rock sits in the per-tile array.
    ang = [2.0 * math.pi * float(v) for v in u]
    return np.array([math.cos(a) for a in ang]), np.array([math.sin(a) for a in ang])


def stamp_rocks(
    z: np.ndarray,
    mask: np.ndarray,
    *,
    x: np.ndarray,
    y: np.ndarray,
    rocks_x,
    rocks_y,
    diameters,
    heights,
    shape_index,
    base_z,
    library: RockLibrary,
    resolution_m: float,
    rock_ids=None,
) -> None:
    """Overlays rocks onto a DEM tile and sets the rock mask, in place.

    Each rock's library shape is rotated (angle from ``rock_ids`` when given, else from
    its position; either way the same in every tile), scaled so its visible footprint has
    area-equivalent diameter ``diameters[i]`` and its top stands ``heights[i]`` above
    ``base_z[i]``, sampled bilinearly at the tile's pixel centres, and merged as
    ``z = max(z, base + h)`` inside its footprint, with ``base = base_z - EMBEDMENT * Hs``.
    ``mask`` is set to 1 where the result exceeds the pre-rock terrain (``z`` on entry)
    by more than :data:`MASK_THRESHOLD_M` (a rock buried by steeper ground uphill is not
    rock there). The pixel(s) whose centre lies within half a pixel of the
    rock centre (the summit) are lifted to the rock top ``base_z + H``: bilinear sampling
    of a small, pointed rock at an arbitrary sub-pixel offset would otherwise shave up to
    ~15 % off its height at 5 px across, and a rock narrower than ~1.5 px could miss every
    pixel centre. So every rock, however small, shows its catalog height on at least one
    pixel. Only each rock's bounding box is touched; every operation is elementwise, so a
    pixel's result does not depend on the tile.

    Args:
        z: float32 ``(nrows, ncols)`` tile heights (m); modified in place.
        mask: uint8 ``(nrows, ncols)`` rock mask; set to 1 on rock pixels in place.
        x: ``(ncols,)`` site x of the tile's pixel centres (m, increasing east).
        y: ``(nrows,)`` site y of the tile's pixel centres (m, decreasing southward).
        rocks_x, rocks_y: rock centres (m, site frame); may lie outside the tile.
        diameters: visible area-equivalent diameters (m, > 0).
        heights: heights of rock tops above ``base_z`` (m, > 0).
        shape_index: library shape of each rock (ints in ``[0, library.n_shapes)``).
        base_z: seat height of each rock (m): the pre-rock surface at its centre.
        library: the :class:`RockLibrary`.
        resolution_m: pixel size (m).
        rock_ids: optional global catalog index of each rock (seeds its rotation).
    """
    if not isinstance(z, np.ndarray) or z.dtype != np.float32 or z.ndim != 2:
        raise ConfigError("z must be a 2-D float32 numpy array (modified in place)")
    if not isinstance(mask, np.ndarray) or mask.dtype != np.uint8 or mask.shape != z.shape:
        raise ConfigError(f"mask must be a uint8 array of shape {z.shape!r} like z")
    if not (isinstance(resolution_m, (int, float, np.floating)) and resolution_m > 0):
        raise OutOfRangeError(f"resolution_m = {resolution_m!r} must be > 0 m")
    nrows, ncols = z.shape
    x = _as_1d("x", x, ncols)
    y = _as_1d("y", y, nrows)
    rx = _as_1d("rocks_x", rocks_x, None)
    n = rx.shape[0]
    ry = _as_1d("rocks_y", rocks_y, n)
    d = _as_1d("diameters", diameters, n)
    hgt = _as_1d("heights", heights, n)
    bz = _as_1d("base_z", base_z, n)
    k = _as_1d("shape_index", shape_index, n, dtype=np.int64)
    ids = None if rock_ids is None else _as_1d("rock_ids", rock_ids, n, dtype=np.int64)
    for name, arr in (("rocks_x", rx), ("rocks_y", ry), ("base_z", bz)):
        if not np.all(np.isfinite(arr)):
            i = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise OutOfRangeError(f"{name}[{i}] = {float(arr[i])!r} must be finite")
    for name, arr in (("diameters", d), ("heights", hgt)):
        bad = ~(np.isfinite(arr) & (arr > 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise OutOfRangeError(f"{name}[{i}] = {float(arr[i])!r}; must be finite and > 0 m")
    bad = (k < 0) | (k >= library.n_shapes)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise OutOfRangeError(
            f"shape_index[{i}] = {int(k[i])}; allowed [0, {library.n_shapes - 1}]"
        )
    if n == 0 or nrows == 0 or ncols == 0:
        return
    res = float(resolution_m)
    s = library.size_px
    if s * s * library.n_shapes >= 2**31:  # pragma: no cover - int32 library offsets
        raise ConfigError("rock library too large for int32 indexing")
    width = d / library.visible_diameter[k]  # library array width on the ground (m)
    hs = hgt / (1.0 - EMBEDMENT)  # full vertical extent (m)
    base = bz - EMBEDMENT * hs
    half = library.reach[k] * width + res  # half-width of each rock's box (m)
    # Bounding boxes in tile pixel indices (generous: pixels outside a footprint are left
    # untouched, so the box never changes a result).
    x0, y0 = float(x[0]), float(y[0])
    c_lo = np.maximum(np.floor((rx - half - x0) / res).astype(np.int64) - 1, 0)
    c_hi = np.minimum(np.ceil((rx + half - x0) / res).astype(np.int64) + 2, ncols)
    r_lo = np.maximum(np.floor((y0 - ry - half) / res).astype(np.int64) - 1, 0)
    r_hi = np.minimum(np.ceil((y0 - ry + half) / res).astype(np.int64) + 2, nrows)
    hit = np.flatnonzero((c_hi > c_lo) & (r_hi > r_lo))
    if hit.size == 0:
        return
    cosr, sinr = _rotation(None if ids is None else ids[hit], rx[hit], ry[hit])
    scale = s / width[hit]
    rk = _Rocks(
        x=rx[hit],
        y=ry[hit],
        cs=cosr * scale,
        sn=sinr * scale,
        off=(k[hit] * (s * s)).astype(np.int32),
        base=base[hit].astype(np.float32),
        hs=hs[hit].astype(np.float32),
        top=(bz[hit] + hgt[hit]).astype(np.float32),
    )
    c_lo, c_hi, r_lo, r_hi = c_lo[hit], c_hi[hit], r_lo[hit], r_hi[hit]
    z0 = z.copy()
    flat = library.shapes.ravel()
    halfpx = 0.5 * res * (1.0 + 1e-9)
    # z = max(z, rock surface) is order independent, so rocks are evaluated in batches
    # of equal-size windows by one elementwise kernel (batching never changes a value).
    big, batches = window_batches(
        r_lo,
        r_hi,
        c_lo,
        c_hi,
        nrows=nrows,
        ncols=ncols,
        classes=_SIZE_CLASSES,
        chunk_pixels=_CHUNK_PIXELS,
    )
    for m in big:
        a0, a1, b0, b1 = r_lo[m], r_hi[m], c_lo[m], c_hi[m]
        surf = _rock_surface(x[None, b0:b1], y[None, a0:a1], rk.take([m]), flat, s, halfpx)
        view = z[a0:a1, b0:b1]
        np.maximum(view, surf[0], out=view)
    for mm, rows, cols in batches:
        surf = _rock_surface(x[cols], y[rows], rk.take(mm), flat, s, halfpx)
        for j, m in enumerate(mm):
            a0, a1, b0, b1 = r_lo[m], r_hi[m], c_lo[m], c_hi[m]
            view = z[a0:a1, b0:b1]
            np.maximum(view, surf[j, : a1 - a0, : b1 - b0], out=view)
    # Rock wherever some rock surface stands above the pre-rock terrain by > threshold;
    # z = max(z0, surfaces), so that is exactly z > z0 + threshold.
    z0 += np.float32(MASK_THRESHOLD_M)
    mask |= (z > z0).view(np.uint8)


_SIZE_CLASSES = (4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128)
_CHUNK_PIXELS = 1 << 17


@dataclass(frozen=True)
class _Rocks:
    """Per-rock scalars of a batch (arrays of equal length)."""

    x: np.ndarray  # centre (m)
    y: np.ndarray
    cs: np.ndarray  # cos(angle) * s / width (library pixels per metre)
    sn: np.ndarray  # sin(angle) * s / width
    off: np.ndarray  # int32 offset of the shape in the flattened library
    base: np.ndarray  # float32 base height (m)
    hs: np.ndarray  # float32 vertical extent (m)
    top: np.ndarray  # float32 top height (m)

    def take(self, idx) -> _Rocks:
        return _Rocks(**{f: getattr(self, f)[idx] for f in self.__dataclass_fields__})


def _rock_surface(xw, yw, rk: _Rocks, flat, s: int, halfpx: float) -> np.ndarray:
    """Rock surface heights (float32 ``(m, H, W)``; -inf off the rock) on windows.

    Args:
        xw: ``(m, W)`` site x of each window's columns (m).
        yw: ``(m, H)`` site y of each window's rows (m).
        rk: the batch's per-rock scalars.
        flat: the library shapes, flattened (float32).
        s: library size (pixels).
        halfpx: half a pixel (m), for the summit pixel rule.
    """
    mid = 0.5 * (s - 1)
    dx = xw - rk.x[:, None]
    dy = yw - rk.y[:, None]
    cs = rk.cs[:, None]
    sn = rk.sn[:, None]
    # Fractional library indices: col = (c dx + s dy) * scale + mid,
    # row = mid - (c dy - s dx) * scale (library rows run south like the grid's).
    fc = (cs * dx + mid)[:, None, :] + (sn * dy)[:, :, None]
    fr = (mid - cs * dy)[:, :, None] + (sn * dx)[:, None, :]
    np.clip(fc, 0.0, s - 1.0, out=fc)
    np.clip(fr, 0.0, s - 1.0, out=fr)
    ic = fc.astype(np.int32)
    np.minimum(ic, s - 2, out=ic)
    ir = fr.astype(np.int32)
    np.minimum(ir, s - 2, out=ir)
    tc = (fc - ic).astype(np.float32)
    tr = (fr - ir).astype(np.float32)
    idx = ir * np.int32(s)
    idx += ic
    idx += rk.off[:, None, None]
    h00 = np.take(flat, idx)
    idx += 1
    h01 = np.take(flat, idx)
    idx += s
    h11 = np.take(flat, idx)
    idx -= 1
    h10 = np.take(flat, idx)
    h01 -= h00
    h01 *= tc
    h00 += h01
    h11 -= h10
    h11 *= tc
    h10 += h11
    h10 -= h00
    h10 *= tr
    h = h00
    h += h10
    inside = h > np.float32(0.0)
    surf = h
    surf *= rk.hs[:, None, None]
    surf += rk.base[:, None, None]
    # The summit is pinned to the pixel(s) within half a pixel of the rock centre.
    near = (np.abs(dy) <= halfpx)[:, :, None] & (np.abs(dx) <= halfpx)[:, None, :]
    np.maximum(surf, np.where(near, rk.top[:, None, None], -np.inf), out=surf)
    surf[~(inside | near)] = -np.inf
    return surf
