"""Primary visibility straight on the DEM: one ray per pixel against the bilinear height
surface, without a triangle mesh (the fast engine of the Hapke camera).

Method (per frame, compiled with numba, both cores):

1. **Azimuth profiles.** The camera's view is cut into vertical half-planes through the
   camera centre, one per azimuth bin ``pixel_angle * bin_factor`` wide (a pinhole
   camera's rays sort into vertical planes by azimuth, whatever its roll and pitch).
   Along each bin's centre azimuth the DEM is sampled front to back at horizontal
   distances ``d_k`` (steps of ``step_fraction`` of the finest cell near the camera,
   growing with the pixel footprint farther out, where a coarser level of a mean-pooled
   mip pyramid is read -- the level of detail) and the running maximum of the elevation
   slope ``A_k = max_{j<=k} (Z(d_j) - z_cam) / d_j`` is stored.
2. **Pixels.** A pixel's ray with horizontal direction ``u`` and slope ``s = d_z / |d_xy|``
   first meets the terrain where ``A_k >= s`` (a galloping search from the neighbouring
   pixel's answer; 95% of pixels share their left neighbour's ``k``). Pixels go row by
   row in two passes: ray slopes and bins (float32 vector code: the profile it is
   compared with is float32), then per pixel the search and the crossing (while the
   search's lines of the profile are in cache). The crossing inside ``[d_(k-1), d_k]`` is
   found on the bin's centre ray by linear interpolation between the two samples and the
   pixel's hit is taken at that horizontal distance along its own ray; with ``iters > 0``
   it is refined on the pixel's *own* azimuth (the bracket moved up to four samples
   forward or back until it brackets the own ray) by Illinois regula falsi on
   ``Z(p + d u) - (z_cam + s d)``.

The result is the ray's intersection with the bilinear surface of the mip level used at
that distance (level 0 within ``cell / pixel_angle`` of the camera) -- exact on planes
along the bin's centre; elsewhere the depth error grows with the cross slope times the
half-bin offset, amplified at grazing incidence (``iters`` removes it). Approximations:
thin ridges narrower than a step are missed by the profile (as by any ray march);
silhouettes are decided by the bin centre's profile, so an occluding edge can be off by
up to half a bin (half a pixel by default) sideways. Terrain outside the DEM is sky.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.render.regolith import load_i32
from lunar_drake.render.row_queue import fetch_add, workers

__all__ = ["DemPyramid", "TraceResult", "trace_heightfield"]


@dataclass(frozen=True)
class DemPyramid:
    """Mean-pooled mip pyramid of a north-up DEM, packed for the compiled kernels.

    Attributes:
        data: float32 levels, concatenated row-major.
        offsets, heights, widths: (L,) int64 start, rows and columns of each level.
        cell_x, cell_y: (L,) float64 cell sizes of each level (m).
        bounds: (left, bottom, right, top) of level 0 (site m).
        max_data: float32 max-pooled levels, the same layout as ``data``: each cell the
            highest level-0 sample it covers (an upper bound of the mean levels too),
            used to skip profile samples that cannot be seen; None: no skipping.
    """

    data: np.ndarray
    offsets: np.ndarray
    heights: np.ndarray
    widths: np.ndarray
    cell_x: np.ndarray
    cell_y: np.ndarray
    bounds: tuple[float, float, float, float]
    max_data: np.ndarray | None = None

    @classmethod
    def build(cls, z, *, bounds, min_size: int = 4) -> DemPyramid:
        """Pyramid of ``z[row, col]`` (north-up, pixel-is-area over ``bounds`` = (left,
        bottom, right, top), m). NaN cells must be filled by the caller."""
        z0 = np.asarray(z, dtype=np.float32)
        if z0.ndim != 2 or min(z0.shape) < 2:
            raise ConfigError(f"DEM has shape {z0.shape}; a 2-D grid of at least 2x2 is required")
        if not np.isfinite(z0).all():
            raise ConfigError("DEM has NaN or infinite cells; fill them before building")
        left, bottom, right, top = (float(b) for b in bounds)
        if not (right > left and top > bottom):
            raise OutOfRangeError(f"bounds = {bounds!r} is empty; need right > left, top > bottom")
        levels = [z0]
        highs = [z0]
        cx = [(right - left) / z0.shape[1]]
        cy = [(top - bottom) / z0.shape[0]]
        while min(levels[-1].shape) > min_size:
            a, hi = _even(levels[-1]), _even(highs[-1])
            a = a.astype(np.float64)
            m = 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])
            levels.append(m.astype(np.float32))
            highs.append(
                np.maximum(
                    np.maximum(hi[0::2, 0::2], hi[1::2, 0::2]),
                    np.maximum(hi[0::2, 1::2], hi[1::2, 1::2]),
                )
            )
            cx.append(2.0 * cx[-1])
            cy.append(2.0 * cy[-1])
        sizes = np.array([lv.size for lv in levels], np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        return cls(
            data=np.concatenate([lv.reshape(-1) for lv in levels]),
            offsets=offsets,
            heights=np.array([lv.shape[0] for lv in levels], np.int64),
            widths=np.array([lv.shape[1] for lv in levels], np.int64),
            cell_x=np.array(cx, np.float64),
            cell_y=np.array(cy, np.float64),
            bounds=(left, bottom, right, top),
            max_data=np.concatenate([hi.reshape(-1) for hi in highs]),
        )

    @classmethod
    def from_heightfield(cls, heightfield, *, max_px: int = 8192) -> DemPyramid:
        """From a :class:`~lunar_drake.terrain.heightfield.Heightfield`, decimated to at
        most ``max_px`` a side; NaN holes take the mean height (they are not rendered as
        holes)."""
        z, _ = heightfield.decimated(max_size=int(max_px))
        z = np.asarray(z, np.float32)
        if np.isnan(z).any():
            z = np.where(np.isnan(z), np.float32(np.nanmean(z)), z)
        return cls.build(z, bounds=tuple(heightfield.bounds))

    @property
    def levels(self) -> int:
        return int(self.offsets.size)

    def height(self, x, y, *, level: int = 0) -> np.ndarray:
        """Bilinear height (m) of ``level`` at site points (edge-clamped), float64."""
        x = np.atleast_1d(np.asarray(x, np.float64))
        y = np.atleast_1d(np.asarray(y, np.float64))
        out = np.empty(np.broadcast(x, y).shape, np.float64)
        xb, yb = np.broadcast_arrays(x, y)
        _heights(self._packed(), int(level), xb.ravel(), yb.ravel(), out.reshape(-1))
        return out

    def _packed(self):
        left, _, _, top = self.bounds
        return (
            self.data,
            self.offsets,
            self.heights,
            self.widths,
            1.0 / self.cell_x,
            1.0 / self.cell_y,
            float(left),
            float(top),
        )


def _even(a: np.ndarray) -> np.ndarray:
    """``a`` with its last row / column repeated where the count is odd."""
    if a.shape[0] % 2:
        a = np.concatenate([a, a[-1:]], axis=0)
    if a.shape[1] % 2:
        a = np.concatenate([a, a[:, -1:]], axis=1)
    return a


@dataclass(frozen=True)
class TraceResult:
    """Per-pixel first hits on the DEM (row-major ``height x width``).

    Attributes:
        t: (H*W,) float32 distance along the unit pixel ray (m); inf = no terrain.
        level: (H*W,) int8 mip level that decided the hit (-1 = none).
        bins, steps: azimuth bins and distance samples of this frame's profiles.
        R_WC: camera orientation. intrinsics: (fx, fy, cx, cy, width, height).
        samples: profile samples of all bins (each bin up to where it leaves the DEM);
            skipped: those of them proven hidden and not read (``skip_hidden``).
    """

    t: np.ndarray
    level: np.ndarray
    bins: int
    steps: int
    R_WC: np.ndarray
    intrinsics: tuple
    samples: int = 0
    skipped: int = 0

    def directions(self, index=None) -> np.ndarray:
        """(3, N) float32 unit ray directions in W of the pixels ``index`` (flat,
        row-major; all when None), as the kernels compute them."""
        fx, fy, cx, cy, w, h = self.intrinsics
        idx = np.arange(w * h) if index is None else np.asarray(index, np.int64)
        out = np.empty((3, idx.size), np.float32)
        _directions(self.R_WC, fx, fy, cx, cy, w, idx, out)
        return out


# ----------------------------------------------------------------------------------------
# compiled kernels
# ----------------------------------------------------------------------------------------
@numba.njit(cache=True, inline="always")
def _bilinear(data, off, h, w, icx, icy, left, top, x, y):
    """Bilinear height of one level at (x, y) (edge-clamped); icx, icy: 1 / cell (1/m)."""
    col = (x - left) * icx - 0.5
    row = (top - y) * icy - 0.5
    if col < 0.0:
        col = 0.0
    elif col > w - 1.0:
        col = w - 1.0
    if row < 0.0:
        row = 0.0
    elif row > h - 1.0:
        row = h - 1.0
    c0 = min(int(col), w - 2)
    r0 = min(int(row), h - 2)
    fc = col - c0
    fr = row - r0
    i = off + r0 * w + c0
    z00 = data[i]
    z01 = data[i + 1]
    z10 = data[i + w]
    z11 = data[i + w + 1]
    top_ = z00 + fc * (z01 - z00)
    bot = z10 + fc * (z11 - z10)
    return top_ + fr * (bot - top_)


@numba.njit(cache=True, inline="always")
def _bilinear_cell(off, h, w, icx, icy, left, top, x, y):
    """:func:`_bilinear` without the reads: ``(i, fc, fr)``, the int32 flat index of the
    cell's (r0, c0) corner in the packed data (< 2**31 values) and the float64
    fractions, the same arithmetic."""
    col = (x - left) * icx - 0.5
    row = (top - y) * icy - 0.5
    col = min(max(col, 0.0), w - 1.0)
    row = min(max(row, 0.0), h - 1.0)
    # col, row >= 0: int32 truncation is int() (and vectorizes)
    c0 = min(np.int32(col), np.int32(w - 2))
    r0 = min(np.int32(row), np.int32(h - 2))
    fc = col - c0
    fr = row - r0
    return np.int32(off) + r0 * np.int32(w) + c0, fc, fr


_F32 = np.float32


@numba.njit(cache=True, inline="always", error_model="numpy")
def _atan2(y, x):
    """atan2 to ~1e-5 rad, float32 (a minimax polynomial on [0, 1]; bins only need ~1e-4)."""
    ax = abs(x)
    ay = abs(y)
    mx = max(ax, ay)
    a = min(ax, ay) / (mx if mx > _F32(0.0) else _F32(1.0))  # (0, 0): 0
    q = a * a
    r = _F32(-0.0117212) * q + _F32(0.05265332)
    r = ((r * q - _F32(0.11643287)) * q + _F32(0.19354346)) * q - _F32(0.33262347)
    r = (r * q + _F32(0.99997726)) * a
    # selects, not branches: the caller's loop stays vector code
    r = _F32(0.5 * math.pi) - r if ay > ax else r
    r = _F32(math.pi) - r if x < _F32(0.0) else r
    return -r if y < _F32(0.0) else r


@numba.njit(cache=True, inline="always", error_model="numpy")
def pixel_direction(R, fx, fy, cx, cy, r, c):
    """Unit ray direction in W of pixel (row r, column c) (float64)."""
    xc = (c - cx) / fx
    yc = (r - cy) / fy
    inv = 1.0 / math.sqrt(xc * xc + yc * yc + 1.0)
    xc *= inv
    yc *= inv
    dx = R[0, 0] * xc + R[0, 1] * yc + R[0, 2] * inv
    dy = R[1, 0] * xc + R[1, 1] * yc + R[1, 2] * inv
    dz = R[2, 0] * xc + R[2, 1] * yc + R[2, 2] * inv
    return dx, dy, dz


@numba.njit(cache=True, inline="always", error_model="numpy")
def direction_f32(R32, ifx, cx32, yc, c):
    """:func:`pixel_direction` in float32 for column c of a row at ``yc = (r - cy) / fy``
    (``ifx = 1 / fx``): within a few float32 ulps of it; and its camera-z component
    ``1 / |(xc, yc, 1)|`` (the depth per unit of ray length)."""
    one = _F32(1.0)
    xc = (_F32(c) - cx32) * ifx
    inv = one / _F32(math.sqrt(xc * xc + yc * yc + one))
    xc *= inv
    yq = yc * inv
    dx = R32[0, 0] * xc + R32[0, 1] * yq + R32[0, 2] * inv
    dy = R32[1, 0] * xc + R32[1, 1] * yq + R32[1, 2] * inv
    dz = R32[2, 0] * xc + R32[2, 1] * yq + R32[2, 2] * inv
    return dx, dy, dz, inv


@numba.njit(parallel=True, cache=True)
def _directions(R, fx, fy, cx, cy, width, idx, out):
    for j in numba.prange(idx.size):
        r = idx[j] // width
        c = idx[j] - r * width
        dx, dy, dz = pixel_direction(R, fx, fy, cx, cy, r, c)
        out[0, j] = dx
        out[1, j] = dy
        out[2, j] = dz


@numba.njit(cache=True)
def _heights(packed, level, x, y, out):
    data, offs, hs, ws, cxs, cys, left, top = packed
    for i in range(x.size):
        out[i] = _bilinear(
            data, offs[level], hs[level], ws[level], cxs[level], cys[level], left, top, x[i], y[i]
        )


@numba.njit(cache=True)
def _distance_steps(d_max, base_step, res0, pix, nlev):
    """Horizontal sample distances and the mip level read at each (numba)."""
    cap = 1 << 22
    ds = np.empty(0, np.float64)
    lv = np.empty(0, np.int8)
    for store in range(2):  # count, then fill arrays of the exact size
        n = 0
        d = base_step
        while d < d_max and n < cap:
            foot = d * pix
            lev = 0
            c = res0
            while lev + 1 < nlev and 2.0 * c <= foot:
                c *= 2.0
                lev += 1
            if store:
                ds[n] = d
                lv[n] = lev
            n += 1
            d += max(base_step, base_step / res0 * c, foot * 0.5)
        if store:
            ds[n] = d
            lv[n] = lv[n - 1] if n > 0 else 0
        else:
            ds = np.empty(n + 1, np.float64)
            lv = np.empty(n + 1, np.int8)
    return ds, lv


_NO_MAX = np.zeros(0, np.float32)
_ROWS = 8  # image rows a worker takes from the queue at a time (render/row_queue.py)
_GROUP = 32  # profile bins marched side by side (16: 10-15 % slower on AMD Zen 3)


@numba.njit(cache=True, inline="always")
def _level(offs, hs, ws, cxs, cys, lev):
    """(offset, rows, cols, 1/cell x, 1/cell y) of mip level ``lev`` in the packed data."""
    return offs[lev], hs[lev], ws[lev], cxs[lev], cys[lev]


@numba.njit(cache=True, inline="always")
def _region_max(mx, offs, hs, ws, icx0, icy0, left, top, x0, y0, x1, y1):
    """An upper bound (m) of every level-0 sample that a bilinear read anywhere in the
    box [x0, x1] x [y0, y1] (site m) can touch: the max-pooled cells (``mx``, the layout
    of :attr:`DemPyramid.max_data`) covering the box's samples and one more on each side,
    read at the finest level where they are at most 4 x 4 (or the top level)."""
    h0 = hs[0]
    w0 = ws[0]
    c_lo = max(math.floor((x0 - left) * icx0 - 0.5) - 1, 0)
    c_hi = min(math.floor((x1 - left) * icx0 - 0.5) + 2, w0 - 1)
    r_lo = max(math.floor((top - y1) * icy0 - 0.5) - 1, 0)
    r_hi = min(math.floor((top - y0) * icy0 - 0.5) + 2, h0 - 1)
    lev = 0
    while lev + 1 < offs.size and (
        (c_hi >> lev) - (c_lo >> lev) > _REGION_CELLS - 1
        or (r_hi >> lev) - (r_lo >> lev) > _REGION_CELLS - 1
    ):
        lev += 1
    w = ws[lev]
    m = -np.inf
    for r in range(r_lo >> lev, min(r_hi >> lev, hs[lev] - 1) + 1):
        for c in range(c_lo >> lev, min(c_hi >> lev, w - 1) + 1):
            m = max(m, mx[offs[lev] + r * w + c])
    return m


_REGION_CELLS = 4  # max-pooled cells read per axis at most (below the top level)
_SKIP_MIN = 8  # a skip's stretch J, at least (J - 1 samples bounded, J - 2 not read)
_SKIP_MAX = 64  # and at most (it doubles after each success, halves after a failure)


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _profiles(
    packed, mx, px, py, pz, th_lo, dth, nb, ds, lv, bx0, by0, bx1, by1, AZ, kend, skipped, nwork
):  # fmt: skip
    """AZ[k, b] = (running max of the elevation slope, terrain height) along bin b.

    Bins go in groups of ``_GROUP`` side by side (neighbouring DEM cells, a few cache
    lines of AZ per step).

    Hidden stretches are skipped when ``mx`` (the max-pooled pyramid; empty: never):
    where the highest DEM sample any read of samples ``k .. k + J - 2`` can touch lies
    below every bin's sight line so far (``(z_max - z_cam) / d <= A``, the worst ``d`` of
    the stretch), none of those samples can raise ``A``. Samples ``k .. k + J - 3`` then
    take ``A`` unchanged and no height (NaN), and ``k + J - 2`` is read as usual. A
    pixel reads the height only at its first sample with ``A >= s`` and the one before
    it, and that first sample is never inside a stretch where ``A`` is constant (its
    predecessor would qualify), nor right after a skipped one, whose ``A`` is the
    stretch's own: the profile answers every pixel exactly as without skipping.
    ``skipped[b]``: the samples of bin b skipped so."""
    data, offs, hs, ws, cxs, cys, left, top = packed
    K = ds.size
    G = _GROUP
    ngroups = (nb + G - 1) // G
    counter = np.zeros(1, np.int64)  # the next group to march (render/row_queue.py)
    for _w in numba.prange(nwork):
        while True:
            g = fetch_add(counter, 1)
            if g >= ngroups:
                break
            b0 = g * G
            nbg = min(G, nb - b0)
            ux = np.empty(G)
            uy = np.empty(G)
            amax = np.full(G, -np.inf)
            state = np.zeros(G, np.int8)  # 0 not entered, 1 inside, 2 left the DEM
            for j in range(nbg):
                th = th_lo + (b0 + j + 0.5) * dth
                ux[j] = math.cos(th)
                uy[j] = math.sin(th)
                kend[b0 + j] = K
                skipped[b0 + j] = 0
            # steps that every bin of the group takes well inside the DEM (camera inside):
            # no bounds or state tests there, and results go to row buffers first (stores
            # to AZ, which the compiler cannot prove apart from the DEM, kept the loop
            # scalar); this loop compiles to vector code (gathers), 13 -> 7 ms measured
            k0 = 0
            A0 = np.empty(G, np.float32)
            A1 = np.empty(G, np.float32)
            IX = np.empty(G, np.int32)
            FC = np.empty(G)
            FR = np.empty(G)
            Z4 = np.empty((4, G), np.float32)
            if bx0 < px < bx1 and by0 < py < by1:
                dexit = np.inf
                for j in range(nbg):
                    if ux[j] > 0.0:
                        dexit = min(dexit, (bx1 - px) / ux[j])
                    elif ux[j] < 0.0:
                        dexit = min(dexit, (bx0 - px) / ux[j])
                    if uy[j] > 0.0:
                        dexit = min(dexit, (by1 - py) / uy[j])
                    elif uy[j] < 0.0:
                        dexit = min(dexit, (by0 - py) / uy[j])
                dsafe = 0.999 * dexit - 1e-6 * (abs(px) + abs(py) + 1.0)
                while k0 < K and ds[k0] < dsafe:
                    k0 += 1
                jump = 16  # the next skip's length J (samples)
                wait = 4  # samples read after a failed try before the next (it doubles)
                next_try = 1  # the first sample at which a skip is tried
                k = 0
                while k < k0:
                    kb = k + jump - 2
                    if mx.size > 0 and k >= next_try and kb < k0:
                        # the stretch's box: every bin's segment from ds[k] to ds[kb]
                        da = ds[k]
                        db = ds[kb]
                        x0 = y0 = np.inf
                        x1 = y1 = -np.inf
                        amin = np.inf
                        for j in range(nbg):
                            xa = px + da * ux[j]
                            xb = px + db * ux[j]
                            ya = py + da * uy[j]
                            yb = py + db * uy[j]
                            x0 = min(x0, xa, xb)
                            x1 = max(x1, xa, xb)
                            y0 = min(y0, ya, yb)
                            y1 = max(y1, ya, yb)
                            amin = min(amin, amax[j])
                        # a coarser level's bilinear read reaches 1.5 of its cells out
                        lb = lv[kb]
                        mg = 2.0 / min(cxs[lb], cys[lb])
                        zmax = _region_max(
                            mx, offs, hs, ws, cxs[0], cys[0], left, top,
                            x0 - mg, y0 - mg, x1 + mg, y1 + mg,
                        )  # fmt: skip
                        num = zmax + 1e-6 * (abs(zmax) + 1.0) - pz
                        if num / (da if num >= 0.0 else db) <= amin:
                            for kk in range(k, kb):
                                for j in range(nbg):
                                    AZ[kk, b0 + j, 0] = np.float32(amax[j])
                                    AZ[kk, b0 + j, 1] = np.nan
                            for j in range(nbg):
                                skipped[b0 + j] += kb - k
                            k = kb
                            next_try = kb + 1
                            jump = min(2 * jump, _SKIP_MAX)
                            wait = 4
                            continue
                        jump = max(jump // 2, _SKIP_MIN)
                        next_try = k + wait
                        wait = min(2 * wait, _SKIP_MAX)
                    d = ds[k]
                    off, h, w, icx, icy = _level(offs, hs, ws, cxs, cys, lv[k])
                    w32 = np.int32(w)
                    # _bilinear in three loops: cells (vector code), the four reads (a loop
                    # of loads only: without gathers, loads through computed indices keep a
                    # loop scalar), the blend and running maximum (vector code)
                    for j in range(nbg):
                        x = px + d * ux[j]
                        y = py + d * uy[j]
                        i, fc, fr = _bilinear_cell(off, h, w, icx, icy, left, top, x, y)
                        IX[j] = i
                        FC[j] = fc
                        FR[j] = fr
                    for j in range(nbg):
                        i = IX[j]
                        Z4[0, j] = load_i32(data, i)
                        Z4[1, j] = load_i32(data, i + 1)
                        Z4[2, j] = load_i32(data, i + w32)
                        Z4[3, j] = load_i32(data, i + w32 + 1)
                    for j in range(nbg):
                        fc = FC[j]
                        z00 = Z4[0, j]
                        z10 = Z4[2, j]
                        top_ = z00 + fc * (Z4[1, j] - z00)
                        bot = z10 + fc * (Z4[3, j] - z10)
                        z = top_ + FR[j] * (bot - top_)
                        a = (z - pz) / d
                        am = max(amax[j], a)
                        amax[j] = am
                        A0[j] = am
                        A1[j] = z
                    for j in range(nbg):
                        AZ[k, b0 + j, 0] = A0[j]
                        AZ[k, b0 + j, 1] = A1[j]
                    k += 1
                if k0 > 0:
                    for j in range(nbg):
                        state[j] = 1
            live = nbg
            for k in range(k0, K):
                if live == 0:
                    break
                d = ds[k]
                off, h, w, icx, icy = _level(offs, hs, ws, cxs, cys, lv[k])
                for j in range(nbg):
                    st = state[j]
                    if st == 2:
                        continue
                    x = px + d * ux[j]
                    y = py + d * uy[j]
                    b = b0 + j
                    if x < bx0 or x > bx1 or y < by0 or y > by1:
                        if st == 1:
                            state[j] = 2
                            kend[b] = k
                            live -= 1
                            continue
                        AZ[k, b, 0] = amax[j]
                        AZ[k, b, 1] = np.inf
                        continue
                    state[j] = 1
                    z = _bilinear(data, off, h, w, icx, icy, left, top, x, y)
                    a = (z - pz) / d
                    if a > amax[j]:
                        amax[j] = a
                    AZ[k, b, 0] = amax[j]
                    AZ[k, b, 1] = z


@numba.njit(cache=True, inline="always")
def _ray_gap(packed, lev, px, py, pz, ux, uy, s, d):
    """Terrain height of mip level ``lev`` minus ray height at horizontal distance d (m)."""
    data, offs, hs, ws, cxs, cys, left, top = packed
    z = _bilinear(
        data, offs[lev], hs[lev], ws[lev], cxs[lev], cys[lev], left, top, px + d * ux, py + d * uy
    )
    return z - (pz + s * d)


@numba.njit(cache=True, inline="always")
def _bisect_first(AZ, b, s, lo, hi):
    """The first k in (lo, hi] with ``AZ[k, b, 0] >= s``, given ``AZ[lo] < s <= AZ[hi]``
    (the profile is non-decreasing)."""
    while hi - lo > 1:
        m = (lo + hi) // 2
        if AZ[m, b, 0] >= s:
            hi = m
        else:
            lo = m
    return hi


@numba.njit(cache=True, inline="always")
def _first_at_or_above(AZ, b, s, ke, kprev):
    """The first k < ke with ``AZ[k, b, 0] >= s`` (given ``AZ[ke - 1, b, 0] >= s``; the
    profile is non-decreasing), galloping from ``kprev``."""
    k = min(kprev, ke - 1)
    if AZ[k, b, 0] >= s:
        if k > 0 and AZ[k - 1, b, 0] >= s:
            step = 1
            lo = k
            while lo > 0 and AZ[lo - 1, b, 0] >= s:
                nxt = max(lo - step, 0)
                if AZ[nxt, b, 0] >= s:
                    lo = nxt
                    step *= 2
                else:
                    lo = _bisect_first(AZ, b, s, nxt, lo)
                    break
            k = lo
        return k
    step = 1
    a_ = k
    b_ = min(k + 1, ke - 1)
    while AZ[b_, b, 0] < s:
        a_ = b_
        step *= 2
        b_ = min(b_ + step, ke - 1)
    return _bisect_first(AZ, b, s, a_, b_)


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _pixels(
    packed, R, px, py, pz, fx, fy, cx, cy, width, height,
    th_ref, th_lo, dth, nb, bcos, bsin, ds, lv, AZ, kend, iters, z_below, t_out, lev_out, nwork,
):  # fmt: skip
    data, offs, hs, ws, cxs, cys, left, top = packed
    R32 = R.astype(np.float32)
    ifx = _F32(1.0 / fx)
    cx32 = _F32(cx)
    th_ref32 = _F32(th_ref)
    th_lo32 = _F32(th_lo)
    inv_dth32 = _F32(1.0 / dth)
    nb_last32 = _F32(nb - 1.0)
    pi32 = _F32(math.pi)
    two_pi32 = _F32(2.0 * math.pi)
    counter = np.zeros(1, np.int64)  # the next row (render/row_queue.py)
    for _w in numba.prange(nwork):
        S = np.empty(width, np.float32)
        RHO = np.empty(width, np.float32)
        UX = np.empty(width, np.float32)
        UY = np.empty(width, np.float32)
        BIN = np.empty(width, np.int32)
        r = -1
        r_end = 0
        while True:
            r += 1
            if r >= r_end:  # the next _ROWS rows from the queue
                r = fetch_add(counter, _ROWS)
                r_end = min(r + _ROWS, height)
            if r >= height:
                break
            # pass 1: ray slope, horizontal direction and azimuth bin (branch-free, float32:
            # twice the lanes of float64, and the profile it is compared with is float32)
            yc = _F32((r - cy) / fy)
            for c in range(width):
                dx, dy, dz, _ = direction_f32(R32, ifx, cx32, yc, c)
                rho = _F32(math.sqrt(dx * dx + dy * dy))
                rr = _F32(1.0) / max(rho, _F32(1e-30))
                S[c] = dz * rr
                RHO[c] = rho
                UX[c] = dx * rr
                UY[c] = dy * rr
                delta = _atan2(dy, dx) - th_ref32
                delta = delta - two_pi32 if delta > pi32 else delta
                delta = delta + two_pi32 if delta <= -pi32 else delta
                bf = (delta - th_lo32) * inv_dth32
                bf = min(max(bf, _F32(0.0)), nb_last32)
                BIN[c] = np.int32(bf)  # bf >= 0: truncation (int32 converts in vector code)
            # pass 2: per pixel, the first profile sample at or above the ray (a galloping
            # search from the left neighbour's), then the crossing between samples k - 1
            # and k, while the search's cache lines of AZ are fresh
            kprev = 0
            for c in range(width):
                i = r * width + c
                t_out[i] = np.inf
                lev_out[i] = -1
                rho = RHO[c]
                if rho < 1e-7:
                    _, _, dz = pixel_direction(R, fx, fy, cx, cy, r, c)
                    if dz < 0.0:  # straight down
                        z = _bilinear(
                            data, offs[0], hs[0], ws[0], cxs[0], cys[0], left, top, px, py
                        )
                        t_out[i] = (pz - z) / -dz
                        lev_out[i] = 0
                    continue
                b = BIN[c]
                s = S[c]
                ke = kend[b]
                if ke == 0 or AZ[ke - 1, b, 0] < s:
                    continue
                k = _first_at_or_above(AZ, b, s, ke, kprev)
                kprev = k
                ux = UX[c]
                uy = UY[c]
                # the crossing on the bin's centre azimuth, between samples k - 1 and k (where
                # A first reaches s: g_(k-1) < 0 <= g_k), linear between them
                d_hi = ds[k]
                g_hi = AZ[k, b, 1] - (pz + s * d_hi)
                if k > 0:
                    d_lo = ds[k - 1]
                    g_lo = AZ[k - 1, b, 1] - (pz + s * d_lo)
                else:
                    d_lo = 0.0
                    g_lo = z_below - pz
                if g_lo > 0.0:
                    g_lo = 0.0
                if g_hi < 0.0:
                    g_hi = 0.0
                den = g_hi - g_lo
                dm = d_hi if den <= 0.0 else d_lo - g_lo * (d_hi - d_lo) / den
                if iters > 0 and den > 0.0:
                    # Illinois regula falsi on the pixel's own ray and the bilinear surface of
                    # the step's level, when the bin's bracket also brackets the own ray
                    ubx = ux
                    uby = uy
                    lev = lv[k]
                    g_lo = _ray_gap(packed, lev, px, py, pz, ubx, uby, s, d_lo)
                    g_hi = _ray_gap(packed, lev, px, py, pz, ubx, uby, s, d_hi)
                    # a few samples forward or back until the own ray is bracketed
                    kh = k
                    kl = k - 1
                    for _ in range(4):
                        if g_hi < 0.0 and kh + 1 < ke:
                            kh += 1
                            kl += 1
                            d_lo = d_hi
                            g_lo = g_hi
                            d_hi = ds[kh]
                            g_hi = _ray_gap(packed, lev, px, py, pz, ubx, uby, s, d_hi)
                        elif g_lo >= 0.0 and kl > 0:
                            kh -= 1
                            kl -= 1
                            d_hi = d_lo
                            g_hi = g_lo
                            d_lo = ds[kl]
                            g_lo = _ray_gap(packed, lev, px, py, pz, ubx, uby, s, d_lo)
                        else:
                            break
                    if g_lo < 0.0 <= g_hi:
                        side = 0
                        for _ in range(iters):
                            dm = (d_lo * g_hi - d_hi * g_lo) / (g_hi - g_lo)
                            gm = _ray_gap(packed, lev, px, py, pz, ubx, uby, s, dm)
                            if gm >= 0.0:
                                d_hi = dm
                                g_hi = gm
                                if side == 1:
                                    g_lo *= 0.5
                                side = 1
                            else:
                                d_lo = dm
                                g_lo = gm
                                if side == -1:
                                    g_hi *= 0.5
                                side = -1
                        dm = (d_lo * g_hi - d_hi * g_lo) / (g_hi - g_lo)
                t_out[i] = dm / rho
                lev_out[i] = lv[k]


# ----------------------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------------------
def _azimuth_range(R, fx, fy, cx, cy, width, height, th_ref):
    """(lo, hi) of pixel azimuths relative to ``th_ref`` (rad); the full circle when the
    zenith or nadir projects into the image."""
    for sgn in (-1.0, 1.0):
        v = R.T @ np.array([0.0, 0.0, sgn])  # vertical in C
        if v[2] > 1e-9:
            u = fx * v[0] / v[2] + cx
            w = fy * v[1] / v[2] + cy
            if -1.0 <= u <= width and -1.0 <= w <= height:
                return -math.pi, math.pi
    us = np.concatenate(
        [np.arange(width), np.arange(width), np.zeros(height), np.full(height, width - 1)]
    ).astype(np.float64)
    vs = np.concatenate(
        [np.zeros(width), np.full(width, height - 1), np.arange(height), np.arange(height)]
    ).astype(np.float64)
    # half-pixel margin around the border covers every pixel centre
    us = np.concatenate([us - 0.5, us + 0.5])
    vs = np.concatenate([vs - 0.5, vs + 0.5])
    d = np.stack([(us - cx) / fx, (vs - cy) / fy, np.ones_like(us)])
    dw = R @ d
    a = np.arctan2(dw[1], dw[0]) - th_ref
    a = (a + math.pi) % (2.0 * math.pi) - math.pi
    return float(a.min()), float(a.max())


def trace_heightfield(
    pyramid: DemPyramid,
    *,
    width: int,
    height: int,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    X_WC,
    bin_factor: float = 1.0,
    step_fraction: float = 0.5,
    lod_factor: float = 1.0,
    iters: int = 0,
    skip_hidden: bool = True,
) -> TraceResult:
    """First hit of every pixel ray of a pinhole camera (Drake convention: +z forward,
    +x right, +y down) at pose ``X_WC`` (4x4, site frame W) on the DEM.

    Args:
        pyramid: the DEM. width, height, fx, fy, cx, cy: intrinsics (px).
        bin_factor: azimuth-bin width in pixel angles (1 / max(fx, fy)).
        step_fraction: profile step near the camera, in level-0 cells.
        lod_factor: a mip level is read once its cell is below ``lod_factor`` times the
            pixel footprint at that distance (1 = one cell per pixel).
        iters: regula-falsi refinements of each hit between two profile samples.
        skip_hidden: skip profile stretches the max-pooled pyramid proves hidden (the
            same hits to the bit; False reads every sample).

    Raises:
        OutOfRangeError: the camera is below the terrain surface or parameters are out of
            range.
    """
    X = np.asarray(X_WC.GetAsMatrix4() if hasattr(X_WC, "GetAsMatrix4") else X_WC, np.float64)
    if X.shape != (4, 4) or not np.isfinite(X).all():
        raise ConfigError(f"X_WC has shape {X.shape}; a finite 4x4 pose is required")
    for name, v, lo in (
        ("bin_factor", bin_factor, 0.05),
        ("step_fraction", step_fraction, 0.05),
        ("lod_factor", lod_factor, 0.1),
    ):
        if not (math.isfinite(v) and lo <= v <= 16.0):
            raise OutOfRangeError(f"{name} = {v!r}; allowed [{lo}, 16]")
    R = np.ascontiguousarray(X[:3, :3])
    px, py, pz = (float(v) for v in X[:3, 3])
    packed = pyramid._packed()
    left, bottom, right, top = pyramid.bounds
    inside = left <= px <= right and bottom <= py <= top
    z_below = -np.inf
    if inside:
        z_ground = float(pyramid.height(px, py)[0])
        z_below = z_ground
        if pz <= z_ground:
            raise OutOfRangeError(
                f"camera at ({px:.3f}, {py:.3f}, {pz:.3f}) m is inside the terrain (ground at "
                f"{z_ground:.3f} m); it must be above the surface"
            )
    pix = 1.0 / max(fx, fy)
    fwd = R[:, 2]
    if math.hypot(fwd[0], fwd[1]) < 1e-6:
        fwd = R[:, 1]
    th_ref = math.atan2(fwd[1], fwd[0])
    th_lo, th_hi = _azimuth_range(R, fx, fy, cx, cy, width, height, th_ref)
    dth = pix * bin_factor
    nb = max(1, math.ceil((th_hi - th_lo) / dth))
    corners = [(left, bottom), (left, top), (right, bottom), (right, top)]
    d_max = max(math.hypot(px - a, py - b) for a, b in corners) + pyramid.cell_x[-1]
    res0 = float(min(pyramid.cell_x[0], pyramid.cell_y[0]))
    ds, lv = _distance_steps(d_max, res0 * step_fraction, res0, pix * lod_factor, pyramid.levels)
    K = ds.size
    AZ = np.empty((K, nb, 2), np.float32)
    kend = np.empty(nb, np.int64)
    bx0, by0, bx1, by1 = float(left), float(bottom), float(right), float(top)
    nwork = workers()
    mx = _NO_MAX if pyramid.max_data is None or not skip_hidden else pyramid.max_data
    if mx.size and (mx.dtype != np.float32 or mx.shape != pyramid.data.shape):
        raise ConfigError(
            f"DemPyramid.max_data is {mx.dtype} {mx.shape}; the layout of data, float32 "
            f"{pyramid.data.shape}, is required (DemPyramid.build makes it), or None"
        )
    skipped = np.empty(nb, np.int64)
    _profiles(
        packed, mx, px, py, pz, th_ref + th_lo, dth, nb, ds, lv, bx0, by0, bx1, by1, AZ, kend,
        skipped, nwork,
    )  # fmt: skip
    bth = th_ref + th_lo + (np.arange(nb) + 0.5) * dth
    bcos, bsin = np.cos(bth), np.sin(bth)
    n = width * height
    t = np.empty(n, np.float32)
    lev = np.empty(n, np.int8)
    _pixels(
        packed, R, px, py, pz, float(fx), float(fy), float(cx), float(cy), int(width),
        int(height), th_ref, th_lo, dth, nb, bcos, bsin, ds, lv, AZ, kend, int(iters), z_below,
        t, lev, nwork,
    )  # fmt: skip
    return TraceResult(
        t=t, level=lev, bins=nb, steps=K, R_WC=R, intrinsics=(fx, fy, cx, cy, width, height),
        samples=int(kend.sum()), skipped=int(skipped.sum()),
    )  # fmt: skip
