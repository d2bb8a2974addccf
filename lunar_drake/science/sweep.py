"""Horizons from upper convex hulls along sweep lines, and sunlight per Sun sector
(numba; no Drake). The engine of the world model's illumination and view factors.

Conventions of :mod:`lunar_drake.render.horizon`: the grid is turned (never resampled)
into a canonical frame ``(R, C)`` in which the Sun lies towards decreasing ``C`` and one
step towards it moves ``(dR, dC) = (sigma, -1)``, ``|sigma| <= 1`` (see
:func:`~lunar_drake.render.horizon.sweep_orientation`). Sweep line ``k`` crosses column
``C`` at fractional row ``k - sigma C``, its height linear between the two rows around
it; its samples lie ``step = res sqrt(1 + sigma^2)`` apart at ``x_C = C step``.

**Hull sweep** (the horizon of every sample of a line in amortised O(1)). Along a line
the terrain a sample ``p`` sees towards the Sun is every earlier sample; its horizon is
the steepest of them, and that one is a vertex of the upper convex hull of the earlier
samples: the vertex before ``p`` once ``p`` is pushed onto the hull (Andrew's monotone
chain pops the vertices ``p`` hides). Lunar curvature is exact to the parabolic
approximation: in ``zhat = z - x^2 / (2 R)`` a caster ``j`` seen from ``i`` has
``tan h = (zhat_j - zhat_i) / (x_i - x_j) - x_i / R`` (see
:mod:`lunar_drake.render.horizon`), and hulls of ``zhat`` hold whatever the receiver.
Every caster on the line up to the DEM's edge counts (no reach limit); terrain beyond
the DEM belongs to the outside horizon mask.

**Far field.** Each line keeps its hull over its samples at least ``near`` columns
back and, per column, the hull vertex steepest from its own sample there. A pixel lies
between lines ``a = R + floor(sigma C)`` and ``a + 1`` at weight ``w = sigma C -
floor(sigma C)``; it sees each line's vertex from its own height and takes ``(1 - w)
t_a + w t_a+1`` (exact where ``w = 0``: axis and diagonal azimuths). Seen from a height
close to the line's, the steepest vertex hardly changes (the maximum is flat to first
order), but the far field is interpolated between lines: the approximation.

**Near field** (:func:`near_plan`): over its first ``near`` column steps a pixel's own ray
is followed exactly on the bilinear surface -- the slope leaving the pixel centre and
every column and row crossing -- because the nearest casters decide most shadows on
rough ground and interpolating them between lines errs most.

**Tiling.** Lines are computed whole, each by one thread, in chunks of ``chunk`` lines
(a chunk recomputes its first line); a pixel only meets its two lines and the exact
arithmetic of its own column, so its value is bit-identical whatever the chunking.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from lunar_drake.render.horizon import line_shifts, sweep_orientation
from lunar_drake.terrain.crs import MOON_RADIUS_M

#: The kernels may fuse a multiply and an add into one FMA (LLVM's ``contract``, nothing
#: else of fastmath: NaN and infinity tests keep their meaning). The same instructions
#: run for a pixel whatever the chunking, so tiles stay byte-identical; about 5 % faster.
_FUSED = {"contract"}

#: Horizon tangent of a sample with nothing towards the Sun (about -90 deg).
NO_CASTER = -1.0e6
_HALF_NO = 0.5 * NO_CASTER

#: Pixel operations of :func:`_sweep`: the horizon tangent; a sector's sunlight
#: (highest and mean flux, ever lit); the epoch's (lit fraction and flux; ever lit); the far
#: field alone (its tangent from the pixel's height and 1 / its distance, 1/m).
TANGENT, SECTOR, EPOCH, FAR = 0, 1, 2, 3


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _line_height(zc, k, c, s, w, x, inv_r):  # pragma: no cover - numba
    """``zhat`` of line ``k`` at column ``c``; NaN off the grid."""
    nr = zc.shape[0]
    a = k - s[c]  # the line lies at row a - w[c], between rows a - 1 and a
    wc = w[c]
    if not (1 <= a <= nr - 1 or (a == 0 and wc == 0.0)):
        return np.nan
    xc = x[c]
    return wc * zc[max(a - 1, 0), c] + (1.0 - wc) * zc[a, c] - 0.5 * xc * xc * inv_r


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _push(hx, hz, n, xc, zh):  # pragma: no cover - numba
    """Pushes ``(xc, zh)`` onto the upper hull ``hx[:n], hz[:n]``; returns the new size."""
    while n >= 2:
        cross = (hx[n - 1] - hx[n - 2]) * (zh - hz[n - 2]) - (hz[n - 1] - hz[n - 2]) * (
            xc - hx[n - 2]
        )
        if cross >= 0.0:
            n -= 1
        else:
            break
    hx[n] = xc
    hz[n] = zh
    return n + 1


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _tangent(hx, hz, n, xq, zq, j):  # pragma: no cover - numba
    """``(t, j)``: the steepest ``t = (hz - zq) / (xq - hx)`` over the hull's vertices,
    at vertex ``j`` (found by walking from the guess ``j``: the slope from a point
    beyond the hull is unimodal along it); ``(NO_CASTER, 0)`` when empty."""
    if n == 0:
        return NO_CASTER, 0
    j = min(max(j, 0), n - 1)
    while j + 1 < n and (hz[j + 1] - zq) * (xq - hx[j]) >= (hz[j] - zq) * (xq - hx[j + 1]):
        j += 1
    while j > 0 and (hz[j - 1] - zq) * (xq - hx[j]) > (hz[j] - zq) * (xq - hx[j - 1]):
        j -= 1
    return (hz[j] - zq) / (xq - hx[j]), j


def near_plan(sigma: float, step_m: float, near: int, moon_radius_m: float) -> np.ndarray:
    """The samples of every pixel's own ray over its first ``near`` column steps on the
    bilinear surface, as offsets from the pixel (the same for every pixel of a sweep):
    rows ``(dr, dc, frac, along, inv_d, drop)`` -- heights at ``(r + dr, c + dc)`` and
    ``(r + dr + 1, c + dc)`` mixed by ``frac`` (``along`` 0: along the column) or at
    ``(r + dr, c + dc)`` and ``(r + dr, c + dc + 1)`` (``along`` 1: a row crossing),
    ``1 / distance`` (1/m) and the curvature drop ``d / (2 R)``."""
    rows = []
    g = 1 if sigma > 0 else -1
    prev = 0.0
    for j in range(1, near + 1):
        rho = sigma * j
        q = math.floor(rho) if g > 0 else math.ceil(rho)
        if sigma != 0.0 and (q - prev) * g > 0.0 and (rho - q) * g > 0.0:
            u = q / sigma  # columns from the pixel, in (j - 1, j)
            c0 = math.floor(-u)
            d = u * step_m
            rows.append((q, c0, -u - c0, 1.0, 1.0 / d, 0.5 * d / moon_radius_m))
        r0 = math.floor(rho)
        d = j * step_m
        rows.append((r0, -j, rho - r0, 0.0, 1.0 / d, 0.5 * d / moon_radius_m))
        prev = rho
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _near(zc, r, c, sigma, step_m, p_i, p_f, reach):  # pragma: no cover - numba
    """Steepest caster tangent along the pixel's own ray on the bilinear surface: the
    slope leaving the pixel centre and the samples of the plan ``p_i, p_f``
    (:func:`near_plan`; ``reach`` its largest row/column offset); NO_CASTER when the
    ray leaves the grid at once."""
    nr, _nc = zc.shape
    z0 = np.float64(zc[r, c])
    if c == 0:
        return NO_CASTER
    best = NO_CASTER
    g = 1 if sigma > 0 else -1
    a_s = abs(sigma)
    # Leaving the centre: the bilinear cell's derivative along the ray (per column step).
    rn = r + g
    if 0 <= rn < nr or a_s == 0.0:
        dz = np.float64(zc[r, c - 1]) - z0
        if a_s > 0.0:
            dz += a_s * (np.float64(zc[rn, c]) - z0)
        best = dz / step_m
    inside = c >= reach and r >= reach and r + reach < nr
    for i in range(p_i.shape[0]):
        rr = r + p_i[i, 0]
        cc = c + p_i[i, 1]
        f = p_f[i, 0]
        if p_f[i, 1] == 0.0:  # a column crossing: between rows rr and rr + 1
            if not inside and (cc < 0 or rr < 0 or rr > nr - 1 or (f > 0.0 and rr + 1 > nr - 1)):
                break
            z1 = np.float64(zc[rr, cc])
            zs = z1 if f == 0.0 else z1 + f * (np.float64(zc[rr + 1, cc]) - z1)
        else:  # a row crossing: between columns cc and cc + 1
            if not inside and (cc < 0 or rr < 0 or rr > nr - 1):
                break
            z1 = np.float64(zc[rr, cc])
            zs = z1 + f * (np.float64(zc[rr, cc + 1]) - z1)
        t = (zs - z0) * p_f[i, 2] - p_f[i, 3]
        if t > best:
            best = t
    return best


_LUT_N = 4097
_LUT_V = np.linspace(-1.0, 1.0, _LUT_N)
#: Visible fraction of a uniform disk whose centre is ``v`` radii above a straight
#: horizon, ``1 - (acos v - v sqrt(1 - v^2)) / pi``, tabulated over ``v`` in [-1, 1].
_DISK_LUT = (np.pi - np.arccos(_LUT_V) + _LUT_V * np.sqrt(1.0 - _LUT_V**2)) / np.pi
_DISK_LUT[0], _DISK_LUT[-1] = 0.0, 1.0


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _disk_fraction(v):  # pragma: no cover - numba
    """Visible fraction of a uniform disk whose centre is ``v`` radii above a straight
    horizon (the table, interpolated linearly: within 2e-6 of the closed form)."""
    if v <= -1.0:
        return 0.0
    if v >= 1.0:
        return 1.0
    u = (v + 1.0) * (0.5 * (_LUT_N - 1))
    i = min(int(u), _LUT_N - 2)
    return _DISK_LUT[i] + (u - i) * (_DISK_LUT[i + 1] - _DISK_LUT[i])


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _fraction(t, lev, j, r, c, par):  # pragma: no cover - numba
    """Visible fraction of the Sun's disk at level ``j`` for horizon tangent ``t``:
    decided in tangent space where the disk is wholly above or below the horizon
    (``lev[3:5]``, widened by the largest curvature tilt); else from ``tan(h - e) =
    (t - tan e) / (1 + t tan e)``, which equals ``h - e`` to 4e-8 rad within the disk."""
    if t >= lev[4, j]:
        return 0.0
    if t <= lev[3, j] and par[7] <= lev[0, j] - par[8]:
        return 1.0
    # The Sun stands higher by delta at a cell displaced towards it (curvature).
    delta = ((r - par[3]) * par[0] + (c - par[4]) * par[1]) * par[2] * par[5]
    te = lev[5, j]
    y = max((t - te) / (1.0 + t * te) - delta, par[7] - lev[0, j])  # h_eff - e
    return _disk_fraction(-y / par[8])


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _slope(zc, r, c, inv_res):  # pragma: no cover - numba
    """``(dz/dR, dz/dC)`` per metre by central differences (one-sided at the edges);
    ``inv_res`` = 1 / pixel (1/m)."""
    nr, nc = zc.shape
    if 0 < r < nr - 1:
        g_r = (np.float64(zc[r + 1, c]) - np.float64(zc[r - 1, c])) * (0.5 * inv_res)
    elif nr == 1:
        g_r = 0.0
    elif r == 0:
        g_r = (np.float64(zc[1, c]) - np.float64(zc[0, c])) * inv_res
    else:
        g_r = (np.float64(zc[r, c]) - np.float64(zc[r - 1, c])) * inv_res
    if 0 < c < nc - 1:
        g_c = (np.float64(zc[r, c + 1]) - np.float64(zc[r, c - 1])) * (0.5 * inv_res)
    elif nc == 1:
        g_c = 0.0
    elif c == 0:
        g_c = (np.float64(zc[r, 1]) - np.float64(zc[r, 0])) * inv_res
    else:
        g_c = (np.float64(zc[r, c]) - np.float64(zc[r, c - 1])) * inv_res
    return g_r, g_c


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _pixel(mode, zc, r, c, t, par, lev, acc_a, acc_b, acc_lit):  # pragma: no cover
    """The pixel operation of :func:`_sweep` at canonical ``(r, c)`` with horizon tangent
    ``t`` (see :meth:`Sweep.sun_par` for ``par``, :meth:`Sweep.run` for ``lev``)."""
    if mode == TANGENT:
        acc_a[r, c] = t
        return
    if mode == EPOCH:
        f = _fraction(t, lev, 0, r, c, par)
        acc_a[r, c] = f
        q = 0.0
        if f > 0.0:
            if acc_lit.shape == acc_a.shape:  # (else a placeholder: no flags kept)
                acc_lit[r, c] = 1  # the epoch is a moment of the year: lit once
            g_r, g_c = _slope(zc, r, c, par[10])
            tilt_h = -(g_r * par[0] + g_c * par[1])
            cos_i = (lev[1, 0] + lev[2, 0] * tilt_h) / math.sqrt(1.0 + g_r * g_r + g_c * g_c)
            q = par[6] * f * max(cos_i, 0.0)
        acc_b[r, c] = q
        return
    # SECTOR: level 0 is the sector's highest elevation (the others are at or below
    # it: dark there, dark everywhere), the rest its mean levels.
    f0 = _fraction(t, lev, 0, r, c, par)
    if f0 <= 0.0:
        return
    acc_lit[r, c] = 1
    g_r, g_c = _slope(zc, r, c, par[10])
    tilt_h = -(g_r * par[0] + g_c * par[1])
    inv_norm = 1.0 / math.sqrt(1.0 + g_r * g_r + g_c * g_c)
    q0 = par[6] * f0 * max((lev[1, 0] + lev[2, 0] * tilt_h) * inv_norm, 0.0)
    if q0 > acc_a[r, c]:
        acc_a[r, c] = q0
    total = 0.0
    for j in range(1, lev.shape[1]):
        f = _fraction(t, lev, j, r, c, par)
        if f > 0.0:
            total += f * max((lev[1, j] + lev[2, j] * tilt_h) * inv_norm, 0.0)
    acc_b[r, c] += par[9] * par[6] * total


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED)
def _line(zc, k, s, w, x, inv_r, near, c_start, c_end, hx, hz, zl, vx, vz):  # pragma: no cover
    """The far-field horizon of line ``k`` at every column ``c`` of ``[c_start, c_end)``
    (the columns where it lies on the grid, or a prefix of them): the hull vertex
    steepest from the line's own sample at ``c`` among its samples at columns
    ``<= c - near``, as ``(vx, vz)`` in ``(x, zhat)`` (``vx = NaN`` when there is none).
    ``hx, hz`` hold the hull and ``zl`` the line's heights (scratch)."""
    n, j = 0, 0
    for c in range(c_start, c_end):
        zl[c] = _line_height(zc, k, c, s, w, x, inv_r)
        cd = c - near
        if cd >= c_start and not np.isnan(zl[cd]):
            n = _push(hx, hz, n, x[cd], zl[cd])
        zh = zl[c]
        if n == 0 or np.isnan(zh):
            vx[c] = np.nan
            continue
        _, j = _tangent(hx, hz, n, x[c], zh, j)
        vx[c] = hx[j]
        vz[c] = hz[j]


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _columns(s, lo, hi):  # pragma: no cover - numba
    """``[c0, c1)``: the columns where ``lo <= s[c] <= hi`` (``s`` is monotone)."""
    nc = s.size
    if s[nc - 1] >= s[0]:
        c0 = np.searchsorted(s, lo, side="left")
        c1 = np.searchsorted(s, hi, side="right")
    else:  # decreasing: search the negated order
        c0 = nc - np.searchsorted(s[::-1], hi, side="right")
        c1 = nc - np.searchsorted(s[::-1], lo, side="left")
    return c0, c1


@numba.njit(cache=True, error_model="numpy", fastmath=_FUSED, inline="always")
def _far_at(fa, fb, f_i, f_w, z_ref, transpose, flip, n_rows, nc, r, c, z):  # pragma: no cover
    """The far tangent (float32) of canonical pixel ``(r, c)`` (``nc`` canonical columns)
    of height ``z``: ``fa - (z - z_ref) fb`` interpolated bilinearly at the pixel's grid
    position (:class:`FarField`; its tables hold ``n_rows`` grid rows, then the
    columns)."""
    cc = nc - 1 - c if flip else c
    gr, gc = (cc, r) if transpose else (r, cc)
    gc += n_rows
    r0, r1, fr = f_i[0, gr], f_i[1, gr], f_w[gr]
    c0, c1, fc = f_i[0, gc], f_i[1, gc], f_w[gc]
    av = (fa[r0, c0] * (1.0 - fc) + fa[r0, c1] * fc) * (1.0 - fr) + (
        fa[r1, c0] * (1.0 - fc) + fa[r1, c1] * fc) * fr  # fmt: skip
    bv = (fb[r0, c0] * (1.0 - fc) + fb[r0, c1] * fc) * (1.0 - fr) + (
        fb[r1, c0] * (1.0 - fc) + fb[r1, c1] * fc) * fr  # fmt: skip
    return np.float32(av - (z - z_ref) * bv)


@numba.njit(parallel=True, cache=True, error_model="numpy", fastmath=_FUSED)
def _sweep(zc, s, w, x, inv_r, sigma, near, p_i, p_f, k_min, k_max, chunk, mode, par, lev, acc_a,
           acc_b, acc_lit, fa, fb, f_i, f_w, f_par, region):  # fmt: skip  # pragma: no cover
    """Runs the hull sweep over the pixels between lines ``k_min..k_max`` of canonical
    DEM ``zc`` and applies ``_pixel`` to each (see the module docstring) inside
    ``region`` = ``(R0, R1, C0, C1)`` (canonical); ``fa, fb, f_i, f_w``: the far field's
    arrays (:class:`FarField`; ``fa`` empty: none), a further horizon tangent from
    terrain the DEM does not hold; ``f_par``: its ``z_ref``, the orientation's
    transpose and flip, and its grid rows. A pixel already dark at every level from its
    lines skips the far and near fields (they only raise its horizon)."""
    nr, nc = zc.shape
    step_m = x[1] - x[0] if nc > 1 else 1.0
    reach = near + 2
    R0, R1, C0, C1 = region[0], region[1], region[2], region[3]
    has_far = fa.shape[0] > 0
    z_ref, f_tr, f_fl, f_rows = f_par[0], f_par[1] != 0.0, f_par[2] != 0.0, int(f_par[3])
    n_chunks = (k_max - k_min + chunk - 1) // chunk
    for ci in numba.prange(n_chunks):
        k0 = k_min + ci * chunk
        k1 = min(k0 + chunk, k_max)
        hx, hz, zl = np.empty(nc), np.empty(nc), np.empty(nc)
        ax, az, bx, bz = np.empty(nc), np.empty(nc), np.empty(nc), np.empty(nc)
        # A line runs from where it enters the grid (towards the Sun) to where it leaves
        # the region's rows or columns on the far side.
        l0, l1 = _columns(s, k0 - nr, k0)
        _, e1 = _columns(s, k0 - R1 - 1, k0 - R0 + 1)
        _line(zc, k0, s, w, x, inv_r, near, l0, min(l1, e1, C1), hx, hz, zl, ax, az)
        for k in range(k0, k1):  # the pixels between lines k and k + 1
            l0, l1 = _columns(s, k + 1 - nr, k + 1)
            _, e1 = _columns(s, k - R1, k - R0 + 2)
            _line(zc, k + 1, s, w, x, inv_r, near, l0, min(l1, e1, C1), hx, hz, zl, bx, bz)
            c_lo, c_hi = _columns(s, k - nr + 1, k)
            for c in range(max(c_lo, C0), min(c_hi, C1)):
                r = k - s[c]
                if r < R0 or r >= R1:
                    continue
                xc = x[c]
                zp = zc[r, c] - 0.5 * xc * xc * inv_r
                wc = w[c]
                # Each line's far-field vertex, seen from the pixel's own height.
                ta = NO_CASTER if np.isnan(ax[c]) else (az[c] - zp) / (xc - ax[c])
                if wc == 0.0:
                    t = ta
                    d = xc - ax[c]
                else:
                    tb = NO_CASTER if np.isnan(bx[c]) else (bz[c] - zp) / (xc - bx[c])
                    if ta > _HALF_NO and tb > _HALF_NO:
                        t = (1.0 - wc) * ta + wc * tb
                        d = (1.0 - wc) * (xc - ax[c]) + wc * (xc - bx[c])
                    elif ta >= tb:  # at the grid's edge or the start of a line: the one
                        t = ta  # that sees
                        d = xc - ax[c]
                    else:
                        t = tb
                        d = xc - bx[c]
                if t > _HALF_NO:
                    t -= xc * inv_r
                if mode == FAR:
                    acc_a[r, c] = t
                    acc_b[r, c] = 1.0 / d if t > _HALF_NO else 0.0
                    continue
                # Far and near casters only raise t: at or above lev[4, 0] the pixel is
                # dark at every level already.
                if mode == TANGENT or t < lev[4, 0]:
                    if has_far:
                        t = max(t, _far_at(fa, fb, f_i, f_w, z_ref, f_tr, f_fl, f_rows, nc, r, c,
                                           zc[r, c]))  # fmt: skip
                    if mode == TANGENT or t < lev[4, 0]:
                        t = max(t, _near(zc, r, c, sigma, step_m, p_i, p_f, reach))
                _pixel(mode, zc, r, c, t, par, lev, acc_a, acc_b, acc_lit)
            ax, bx = bx, ax
            az, bz = bz, az


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _turn(z, transpose, flip, out):  # pragma: no cover - numba
    """``out[R, C]`` = ``z`` turned into the canonical frame, in 64-px blocks."""
    nr, nc = out.shape
    nb_r, nb_c = (nr + 63) // 64, (nc + 63) // 64
    for b in numba.prange(nb_r * nb_c):
        r0, c0 = (b // nb_c) * 64, (b % nb_c) * 64
        for r in range(r0, min(r0 + 64, nr)):
            for c in range(c0, min(c0 + 64, nc)):
                cc = nc - 1 - c if flip else c
                out[r, c] = z[cc, r] if transpose else z[r, cc]


def canonical_dem(z: np.ndarray, orient) -> np.ndarray:
    """``orient.canon(z)`` as a C-contiguous copy (a blocked, threaded turn): float32
    heights stay float32 (half the memory and traffic; the kernels widen every height
    to float64 as they load it, so the results are those of a float64 copy), others
    become float64."""
    z = np.asarray(z)
    if z.dtype not in (np.float32, np.float64):
        z = z.astype(np.float64)
    out = np.empty(orient.shape, z.dtype)
    _turn(z, bool(orient.transpose), bool(orient.flip), out)
    return out


class FarField(NamedTuple):
    """A horizon tangent from terrain beyond a DEM, for :meth:`Sweep.run`: coarse cells
    ``a, b`` (float32) give, at height ``z``, ``a - (z - z_ref) b``; a pixel takes that
    interpolated bilinearly between the cells around it, from the tables ``index``
    (``(2, rows + cols)`` int64: the lower and upper cell of each grid row of the DEM,
    then of each column) and ``weight`` (the upper cell's weight), ``rows`` being the
    DEM's grid rows (see :func:`~lunar_drake.science.strips.far_field`)."""

    a: np.ndarray
    b: np.ndarray
    index: np.ndarray
    weight: np.ndarray
    z_ref: float
    rows: int


class Sweep:
    """The sweep geometry of one azimuth over a grid, and its canonical DEM.

    Args:
        z: heights (m), row 0 north (finite). azimuth_deg: deg clockwise from grid north.
        resolution_m: pixel (m). chunk: lines per thread task (never changes a byte).
    """

    def __init__(self, z: np.ndarray, *, azimuth_deg: float, resolution_m: float,
                 chunk: int = 512, near: int = 8, moon_radius_m: float = MOON_RADIUS_M,
                 canonical: np.ndarray | None = None) -> None:  # fmt: skip
        self.orient = sweep_orientation(azimuth_deg, z.shape)
        self.azimuth_deg = float(azimuth_deg)
        self.resolution_m = float(resolution_m)
        self.zc = canonical if canonical is not None else canonical_dem(z, self.orient)
        nr, nc = self.orient.shape
        s, w = line_shifts(self.orient.sigma, np.arange(nc))
        self.s, self.w = s.astype(np.int64), w
        self.x = np.arange(nc, dtype=np.float64) * (self.orient.step_px * self.resolution_m)
        self.inv_r = 1.0 / float(moon_radius_m)
        # Pixel row r of column c lies between lines r + s[c] and r + s[c] + 1.
        self.k_min, self.k_max = int(s.min()), int(nr - 1 + s.max() + 1)
        self.chunk = max(1, int(chunk))
        self.near = max(1, int(near))
        plan = near_plan(self.orient.sigma, self.orient.step_px * self.resolution_m,
                         self.near, float(moon_radius_m))  # fmt: skip
        self.plan_i = np.ascontiguousarray(plan[:, :2].astype(np.int64))
        self.plan_f = np.ascontiguousarray(plan[:, 2:])

    def run(self, mode, par, elevations_deg, acc_a, acc_b, acc_lit, *, far=None,
            region=None, extent_px=None) -> None:  # fmt: skip
        """Applies pixel operation ``mode`` with canonical accumulators, at the Sun
        ``elevations_deg`` (sector: its highest first, then its mean levels).

        ``far``: a :class:`FarField` of this DEM's grid, a further horizon tangent
        per pixel (terrain beyond this DEM). ``region``: canonical ``(R0, R1, C0,
        C1)``, the only pixels computed (default all). ``extent_px``: ``(rows, cols)``
        of the whole grid when this DEM is a window of it (bounds the Sun's tilt over
        it; default this DEM's).
        """
        e = np.radians(np.asarray(elevations_deg, np.float64).ravel())
        nr, nc = self.orient.shape
        # The largest Sun tilt over the grid (rad): half its diagonal over R.
        ext = (nr, nc) if extent_px is None else extent_px
        bound = 0.5 * math.hypot(*ext) * self.resolution_m * self.inv_r
        radius = float(par[8]) if len(par) > 8 else 0.0
        cap = 0.5 * math.pi - 1e-6
        lo = np.tan(np.clip(e - radius - bound, -cap, cap))
        hi = np.tan(np.clip(e + radius + bound, -cap, cap))
        lev = np.ascontiguousarray(np.stack([e, np.sin(e), np.cos(e), lo, hi, np.tan(e)]))
        R0, R1, C0, C1 = (0, nr, 0, nc) if region is None else (int(v) for v in region)
        k_min = max(self.k_min, R0 + int(self.s[C0:C1].min()) if C1 > C0 else self.k_max)
        k_max = min(self.k_max, R1 + int(self.s[C0:C1].max()) if C1 > C0 else self.k_min)
        if far is None:
            far = FarField(np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32),
                           np.zeros((2, 0), np.int64), np.zeros(0), 0.0, 0)  # fmt: skip
        o = self.orient
        grid = o.shape[::-1] if o.transpose else o.shape  # this DEM's grid (rows, cols)
        if far.a.size and (far.rows != grid[0] or far.index.shape != (2, sum(grid))
                           or far.weight.shape != (sum(grid),)):  # fmt: skip
            raise ValueError(f"far field of {far.rows} rows and {far.index.shape[1]} entries "
                             f"for a grid of {grid}")  # fmt: skip
        f_par = np.array([far.z_ref, float(o.transpose), float(o.flip), far.rows])
        # Chunks differ in work (lines near the corners are short): hand them out one
        # at a time.
        with numba.parallel_chunksize(1):
            _sweep(self.zc, self.s, self.w, self.x, self.inv_r, self.orient.sigma, self.near,
                   self.plan_i, self.plan_f, k_min, max(k_min, k_max), self.chunk, mode,
                   np.asarray(par, np.float64), lev, acc_a, acc_b, acc_lit, far.a, far.b,
                   far.index, far.weight, f_par,
                   np.array([R0, R1, C0, C1], np.int64))  # fmt: skip

    def sun_par(self, *, flux_w_m2: float, mask_deg: float, radius_deg: float,
                w_mean: float = 0.0, centre=None) -> np.ndarray:  # fmt: skip
        """``par`` of the Sun along this azimuth: the horizontal unit towards it
        (canonical axes), the resolution, the grid centre (canonical ``(R, C)``, default
        this DEM's), 1/R, the flux, the outside horizon, the disk's radius, the weight
        of each mean level and 1 / pixel."""
        o = self.orient
        nr, nc = o.shape
        cr, cc = (0.5 * (nr - 1), 0.5 * (nc - 1)) if centre is None else centre
        return np.array([
            o.sigma / o.step_px, -1.0 / o.step_px, self.resolution_m,
            float(cr), float(cc), self.inv_r, float(flux_w_m2),
            math.radians(mask_deg), math.radians(radius_deg), float(w_mean),
            1.0 / self.resolution_m,
        ])  # fmt: skip


def set_threads(workers: int) -> None:
    """Numba threads for the sweeps: ``workers``, at most what numba was started with."""
    numba.set_num_threads(max(1, min(int(workers), numba.config.NUMBA_NUM_THREADS)))


def horizon_tangents(z: np.ndarray, *, azimuth_deg: float, resolution_m: float,
                     chunk: int = 512, near: int = 8, workers: int = 2,
                     moon_radius_m: float = MOON_RADIUS_M) -> np.ndarray:  # fmt: skip
    """``tan`` of each cell's horizon elevation along ``azimuth_deg`` (float32; about
    :data:`NO_CASTER` where no terrain of the DEM lies towards the Sun)."""
    z = np.asarray(z, np.float64)
    sw = Sweep(z, azimuth_deg=azimuth_deg, resolution_m=resolution_m, chunk=chunk, near=near,
               moon_radius_m=moon_radius_m)  # fmt: skip
    out = np.full(z.shape, NO_CASTER, np.float32)
    view = sw.orient.canon(out)
    set_threads(workers)
    sw.run(TANGENT, np.zeros(11), [0.0], view, view, np.zeros((1, 1), np.uint8))
    return out


__all__ = [
    "EPOCH",
    "FAR",
    "NO_CASTER",
    "SECTOR",
    "TANGENT",
    "FarField",
    "Sweep",
    "canonical_dem",
    "horizon_tangents",
    "near_plan",
    "set_threads",
]
