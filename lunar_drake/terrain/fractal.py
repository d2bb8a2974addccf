"""Fractal upscaling of a coarse DEM (paper section 4, paragraphs 4-5), tile by tile.

The coarse DEM is split into a smooth low-frequency part and a high-frequency residual
(:func:`split_frequencies`). The low part is upscaled by a smooth interpolant
(:func:`upscale_low`; craters are stamped into it by :mod:`craters`), the high part by
diamond-square refinement with Catmull-Rom interpolation plus fractal noise
(:func:`upscale_high`); their sum is the fine DEM (:func:`upscale_dem`). Splitting keeps
the diamond-square interpolation artifacts away from the large, smooth landforms
(paper refs [18]-[20]; random midpoint displacement after Fournier, Fussell & Carpenter
1982, CACM 25, 371; its grid-aligned creases are discussed by Miller 1986, SIGGRAPH).

Alignment (point-registered)
----------------------------
Fine pixel ``(r, c)`` sits at coarse fractional index ``(r / F, c / F)`` with
``F = factor = 2**L``; ``fine[::F, ::F]`` corresponds to ``coarse[:, :]``. The fine grid
has ``coarse.shape * F`` pixels, so its last ``F - 1`` rows/columns lie beyond the last
coarse sample. There, and for any position outside the grid, the low part extends the
coarse grid *linearly* (ghost node ``z[n-1+k] = z[n-1] + k (z[n-1] - z[n-2])``, so ramps
stay exact) and the high part extends it by *clamping* (edge replication; detail is
zero-mean, so extrapolating its slope would only amplify noise) while the noise simply
continues, keyed by global indices. A single coarse sample along an axis is extended as a
constant.

Tile invariance
---------------
Every output pixel is a fixed sequence of float32 (high) or float64 (low) elementwise
operations on coarse values and on :func:`lunar_drake.rng.hash_normal` noise keyed by
(per-level key, global row, global column) at that level. A window is computed from the
coarse sub-window it needs plus a halo that is large enough at every level (a new point
reads previous-level points at most 3 away, see :func:`_level_ranges`; a fine pixel
depends on coarse nodes less than 4 cells away) and cropped after each level, so any
window returns exactly the bytes of the whole-grid computation. Cost: ~2 s CPU for the
high part and ~0.6 s for the low part of an 8192^2 grid (F = 128) in 1024^2 tiles;
prefer tiles -- one whole-grid call of that size needs ~1.7 GB and ~3x the time.

Noise model
-----------
Target roughness is fractional-Brownian: RMS height deviation (Shepard et al. 2001)
``nu(dx) = rms_deviation_m * (dx / ref_baseline_m) ** hurst``. Each level is two half
steps on congruent stencils: the *diamond* step creates cell centres from the 4x4
neighbourhood of the axis-aligned lattice (separable Catmull-Rom at t = 1/2, taps
``(-1, 9, 9, -1) / 16``); the *square* step creates edge midpoints with the same 4x4
Catmull-Rom stencil applied in the 45-degree-rotated lattice formed by old points and
cell centres (4 nearest neighbours weight 81/256, 8 knight-move points -9/256, 4 points
at distance 3 weight 1/256). A half step whose new points lie at distance ``h`` from
their nearest neighbours adds noise of std
``sigma(h) = rms_deviation_m * (h / ref_baseline_m) ** hurst * c(H)`` at the new points
only, with ``c(H)**2 = 1 - G(H)``, ``G(H) = E[(interp - z_nn)**2] / nu(h)**2`` evaluated
for an fBm prior (the 2-D, Catmull-Rom analogue of the classic midpoint-displacement
factor ``1 - 2**(2H-2)``). Because both half steps use the same stencil up to a 45 deg
rotation and a sqrt(2) scale, and ``h`` shrinks by sqrt(2) per half step, the variance
at diamond and square points is consistent and no periodic variance pattern or
axis-aligned anisotropy appears (tests check the 2-D power spectrum and the variance of
the Laplacian at every phase within a coarse cell).

The calibration is that of a *conditional* simulation: the coarse samples are assumed to
carry the variance at scales at and above the coarse spacing T. Upscaling a coarse fBm of
the same law (e.g. :func:`coarse_fractal`) then reproduces ``nu(dx)`` within ~10 % at all
lags. On a flat coarse input the detail alone lacks the part of ``nu(dx)**2`` that comes
from wavelengths > T, roughly a fraction ``(dx / T) ** (2 - 2H)``, and matches the law
only at lags well below T (e.g. H = 0.8, F = 256, 0.04 m pixels: H fitted over lags
1-64 px ~0.72, nu(1 m) ~0.8 of target).

Literature for defaults
-----------------------
* Hurst exponent: Rosenburg et al. (2011, JGR 116, E02001) find lunar Hurst exponents
  mostly between ~0.7 (maria) and ~0.95 (highlands) from LOLA deviograms at 57 m-2.7 km
  baselines; Helfenstein & Shepard (1999, Icarus 141, 107) report lower values (~0.5)
  at sub-centimetre scale. We use 0.8 as a metre-scale compromise.
* RMS deviation 0.05 m at 1 m baseline (RMS slope ~2.9 deg): lunar RMS slopes at metre
  scale are a few degrees (Shepard et al. 2001, JGR 106, 32777, compilation; Rosenburg
  et al. 2011 for the trend with baseline). Craters and rocks are added separately, so
  the fractal part alone is kept at the low end.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage

from lunar_drake import rng
from lunar_drake.errors import ConfigError, NoDataError, OutOfRangeError

__all__ = [
    "FractalParams",
    "coarse_fractal",
    "level_noise_std",
    "low_surface_at",
    "split_frequencies",
    "upscale_dem",
    "upscale_high",
    "upscale_low",
]

_LOW_METHODS = ("cubic", "linear")
# Max fine-level reach (in points of the new level) of the square-step stencil; the
# diamond step reaches (i +- 3) / 2 in the previous level. Together: input range [lo, hi)
# at level l yields a complete level l+1 on [2 lo + 6, 2 hi - 6).
_HALO = 6


@dataclass(frozen=True)
class FractalParams:
    """Fractal-upscaling parameters.

    Attributes:
        hurst: Hurst exponent H of the added roughness, 0 < H < 1 (Rosenburg et al.
            2011: ~0.7-0.95 on the Moon; default 0.8).
        rms_deviation_m: RMS height deviation nu (m) of the added roughness at
            ``ref_baseline_m`` (Shepard et al. 2001 definition); 0 disables the noise.
            Default 0.05 m, i.e. RMS slope ~2.9 deg at 1 m.
        ref_baseline_m: baseline (m) at which ``rms_deviation_m`` applies; default 1 m.
        lowpass_sigma_coarse_px: std (coarse pixels) of the Gaussian that splits the
            coarse DEM into low and high frequencies; 0 puts everything in the low part.
        low_interpolation: ``"cubic"`` (Catmull-Rom, C1 -- no slope creases along coarse
            grid lines under a low sun; the default) or ``"linear"`` (bilinear, as in
            the paper) for the low-frequency part in :func:`upscale_dem`.
    """

    hurst: float = 0.8
    rms_deviation_m: float = 0.05
    ref_baseline_m: float = 1.0
    lowpass_sigma_coarse_px: float = 1.0
    low_interpolation: str = "cubic"

    def __post_init__(self) -> None:
        _check_real("hurst", self.hurst, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
        _check_real("rms_deviation_m", self.rms_deviation_m, lo=0.0)
        _check_real("ref_baseline_m", self.ref_baseline_m, lo=0.0, lo_open=True)
        _check_real("lowpass_sigma_coarse_px", self.lowpass_sigma_coarse_px, lo=0.0)
        if self.low_interpolation not in _LOW_METHODS:
            raise ConfigError(
                f"FractalParams.low_interpolation={self.low_interpolation!r} is not one of "
                f"{_LOW_METHODS}"
            )

    @property
    def rms_slope_rad(self) -> float:
        """RMS slope (rad) at the reference baseline, ``atan(nu / baseline)``."""
        return math.atan(self.rms_deviation_m / self.ref_baseline_m)


def _check_real(name, value, *, lo=None, hi=None, lo_open=False, hi_open=False) -> None:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    ok = ok and math.isfinite(value)
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value < hi if hi_open else value <= hi
    if not ok:
        lo_s = "" if lo is None else f"{lo}{' <' if lo_open else ' <='} "
        hi_s = "" if hi is None else f" {'<' if hi_open else '<='} {hi}"
        raise OutOfRangeError(
            f"FractalParams.{name}={value!r} is not allowed; need a finite number "
            f"{lo_s}{name}{hi_s}"
        )


def _levels(factor) -> int:
    """L with ``factor == 2**L``; ConfigError naming the value otherwise."""
    if (
        not isinstance(factor, numbers.Integral)
        or isinstance(factor, bool)
        or factor < 1
        or (int(factor) & (int(factor) - 1)) != 0
    ):
        raise ConfigError(
            f"factor={factor!r} is not allowed; the upscaling factor must be a power of "
            "two (1, 2, 4, 8, ...)"
        )
    return int(factor).bit_length() - 1


def _check_coarse(coarse, name: str) -> np.ndarray:
    z = np.asarray(coarse, dtype=np.float64)
    if z.ndim != 2 or z.shape[0] < 1 or z.shape[1] < 1:
        raise ConfigError(f"{name} must be a non-empty 2-D array, got shape {z.shape}")
    bad = ~np.isfinite(z)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise NoDataError(
            f"{name} has {int(bad.sum())} non-finite cells (first at row {r}, col {c}: "
            f"{float(z[r, c])}); fill them before upscaling"
        )
    return z


def _check_window(window, shape, factor: int) -> tuple[int, int, int, int]:
    nr, nc = shape[0] * factor, shape[1] * factor
    if window is None:
        return 0, 0, nr, nc
    try:
        r0, c0, h, w = (int(v) for v in window)
        exact = all(int(v) == v for v in window)
    except (TypeError, ValueError):
        exact = False
    if not exact or h < 1 or w < 1 or r0 < 0 or c0 < 0 or r0 + h > nr or c0 + w > nc:
        raise OutOfRangeError(
            f"window={window!r} is not allowed; need integers (row0, col0, nrows, ncols) "
            f"with nrows, ncols >= 1 inside the fine grid of {nr} x {nc} pixels"
        )
    return r0, c0, h, w


# --------------------------------------------------------------------------------------
# Frequency split
# --------------------------------------------------------------------------------------


def split_frequencies(coarse, *, params: FractalParams) -> tuple[np.ndarray, np.ndarray]:
    """Splits a coarse DEM (m) into ``(low, high)`` float64 arrays on the coarse grid.

    ``low`` is a Gaussian low-pass (std ``params.lowpass_sigma_coarse_px`` coarse
    pixels, ``reflect`` edges, scipy.ndimage); ``high = coarse - low`` is computed by
    subtraction so ``low + high`` reproduces ``coarse`` to float64 rounding (one ulp).
    """
    z = _check_coarse(coarse, "coarse")
    if params.lowpass_sigma_coarse_px == 0:
        low = z.copy()
    else:
        low = ndimage.gaussian_filter(z, params.lowpass_sigma_coarse_px, mode="reflect")
    return low, z - low


# --------------------------------------------------------------------------------------
# Low frequencies: smooth interpolation
# --------------------------------------------------------------------------------------


def _weights(t: np.ndarray, method: str) -> tuple[np.ndarray, ...]:
    """4-tap weights for nodes i0-1, i0, i0+1, i0+2 at fraction t in [0, 1)."""
    if method == "linear":
        zero = np.zeros_like(t)
        return zero, 1.0 - t, t, zero
    t2 = t * t
    t3 = t2 * t
    return (
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    )


def _extend_linear_1d(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clamped index, inward edge neighbour and distance beyond the edge (linear ghosts)."""
    ic = np.clip(idx, 0, n - 1)
    k = np.abs(idx - ic).astype(np.float64)
    if n == 1:
        return ic, ic, k
    nb = np.where(idx < 0, 1, np.where(idx > n - 1, n - 2, ic))
    return ic, nb, k


def _ghost_rows(z: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows ``idx`` (any integers) of ``z`` extended linearly beyond the edges."""
    ic, nb, k = _extend_linear_1d(idx, z.shape[0])
    zc = z[ic]
    return zc + k[:, None] * (zc - z[nb])


def _ghost(z: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``z`` on the (rows x cols) index grid, extended linearly (rows first, then cols)."""
    zr = _ghost_rows(z, rows)
    return _ghost_rows(zr.T, cols).T


def _check_method(method: str) -> None:
    if method not in _LOW_METHODS:
        raise ConfigError(f"method={method!r} is not one of {_LOW_METHODS}")


def _upscale_low64(low: np.ndarray, factor: int, window, method: str) -> np.ndarray:
    r0, c0, h, w = window
    # Coarse interval of each fine row/col and its fraction (exact: F is a power of 2).
    rows = np.arange(r0, r0 + h)
    cols = np.arange(c0, c0 + w)
    ci = cols // factor
    wc = _weights((cols - ci * factor) / factor, method)
    ri_first, ri_last = r0 // factor, (r0 + h - 1) // factor
    need_r = np.arange(ri_first - 1, ri_last + 3)
    need_c = np.arange(ci[0] - 1, ci[-1] + 3)
    zg = _ghost(low, need_r, need_c)  # (len(need_r), len(need_c)) float64
    jc = ci - need_c[0]
    # Interpolate along columns at every needed coarse row: (len(need_r), w).
    tc = ((zg[:, jc - 1] * wc[0] + zg[:, jc] * wc[1]) + zg[:, jc + 1] * wc[2]) + zg[:, jc + 2] * wc[
        3
    ]
    out = np.empty((h, w), dtype=np.float64)
    for ri in range(ri_first, ri_last + 1):
        sel = slice(
            max(ri * factor, r0) - r0,
            min((ri + 1) * factor, r0 + h) - r0,
        )
        t = ((rows[sel] - ri * factor) / factor)[:, None]
        wr = _weights(t, method)
        j = ri - need_r[0]
        out[sel] = ((wr[0] * tc[j - 1] + wr[1] * tc[j]) + wr[2] * tc[j + 1]) + wr[3] * tc[j + 2]
    return out


def upscale_low(low_coarse, *, factor: int, window=None, method: str = "cubic") -> np.ndarray:
    """Smooth interpolation of the low-frequency coarse grid at the fine pixels of a window.

    Args:
        low_coarse: (n, m) low-frequency coarse DEM (m).
        factor: F = 2**L, fine pixels per coarse pixel.
        window: ``(row0, col0, nrows, ncols)`` in global fine pixels; None = whole grid.
        method: ``"cubic"`` (separable Catmull-Rom, C1) or ``"linear"`` (bilinear).

    Returns:
        float32 (nrows, ncols) heights (m); evaluated in float64 and rounded once.
    """
    _check_method(method)
    L = _levels(factor)
    low = _check_coarse(low_coarse, "low_coarse")
    win = _check_window(window, low.shape, 1 << L)
    return _upscale_low64(low, 1 << L, win, method).astype(np.float32)


def low_surface_at(low_coarse, *, factor: int, rows, cols, method: str = "cubic") -> np.ndarray:
    """The :func:`upscale_low` interpolant at fractional fine-pixel positions (float64, m).

    ``rows``/``cols`` broadcast; any finite position is allowed (outside the grid the
    coarse grid is extended linearly). At integer positions inside the grid this equals
    :func:`upscale_low` before its float32 rounding (same operations, same order).
    """
    _check_method(method)
    L = _levels(factor)
    F = 1 << L
    low = _check_coarse(low_coarse, "low_coarse")
    r, c = np.broadcast_arrays(np.asarray(rows, dtype=np.float64), np.asarray(cols, float))
    bad = ~(np.isfinite(r) & np.isfinite(c))
    if bad.any():
        i = int(np.flatnonzero(bad.ravel())[0])
        raise OutOfRangeError(
            f"low_surface_at: position (rows, cols)=({r.ravel()[i]!r}, {c.ravel()[i]!r}) is "
            "not allowed; positions must be finite (fine pixels)"
        )
    shape = r.shape
    r = r.ravel()
    c = c.ravel()
    # Same arithmetic as _upscale_low64: fractions from (pos - i*F) / F.
    ri = np.floor(r / F).astype(np.int64)
    ci = np.floor(c / F).astype(np.int64)
    wr = _weights((r - ri * F) / F, method)
    wc = _weights((c - ci * F) / F, method)
    n, m = low.shape

    def node(ir, ic):
        # Linear extension, rows first then columns, exactly as _ghost does.
        icr, nbr, kr = _extend_linear_1d(ir, n)
        icc, nbc, kc = _extend_linear_1d(ic, m)
        a = low[icr, icc] + kr * (low[icr, icc] - low[nbr, icc])
        b = low[icr, nbc] + kr * (low[icr, nbc] - low[nbr, nbc])
        return a + kc * (a - b)

    tc = []
    for dr in (-1, 0, 1, 2):
        ir = ri + dr
        tc.append(
            ((node(ir, ci - 1) * wc[0] + node(ir, ci) * wc[1]) + node(ir, ci + 1) * wc[2])
            + node(ir, ci + 2) * wc[3]
        )
    out = ((wr[0] * tc[0] + wr[1] * tc[1]) + wr[2] * tc[2]) + wr[3] * tc[3]
    return out.reshape(shape)


# --------------------------------------------------------------------------------------
# High frequencies: diamond-square with Catmull-Rom and fractal noise
# --------------------------------------------------------------------------------------

_SQUARE_STENCIL = (
    [(0, 1), (0, -1), (1, 0), (-1, 0)],
    [(2, 1), (2, -1), (-2, 1), (-2, -1), (1, 2), (1, -2), (-1, 2), (-1, -2)],
    [(0, 3), (0, -3), (3, 0), (-3, 0)],
)
_SQUARE_WEIGHTS = (81.0 / 256.0, -9.0 / 256.0, 1.0 / 256.0)


@lru_cache(maxsize=256)
def _noise_factor(hurst: float) -> float:
    """c(H): noise std at a half step relative to nu(h), for an fBm prior (see module)."""
    pts, w = [], []
    for group, wk in zip(_SQUARE_STENCIL, _SQUARE_WEIGHTS, strict=True):
        pts += group
        w += [wk] * len(group)
    p = np.asarray(pts, dtype=np.float64)
    a = np.asarray(w)
    a[0] -= 1.0  # interp minus the nearest neighbour at (0, 1)
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1))
    g = -0.5 * a @ (d ** (2.0 * hurst)) @ a
    return math.sqrt(max(1.0 - g, 0.0))


def level_noise_std(
    level: int, *, params: FractalParams, coarse_resolution_m: float
) -> tuple[float, float]:
    """Noise std (m) added at the diamond and square half steps of ``level`` (1 = first).

    Level ``l`` creates fine spacing ``s = coarse_resolution_m / 2**l``; diamond points
    lie ``s * sqrt(2)`` from their nearest neighbours, square points ``s``.
    """
    s = coarse_resolution_m / float(1 << level)
    k = params.rms_deviation_m * _noise_factor(params.hurst)
    H = params.hurst
    ref = params.ref_baseline_m
    return k * (s * math.sqrt(2.0) / ref) ** H, k * (s / ref) ** H


def _level_ranges(lo: int, hi: int, levels: int) -> list[tuple[int, int]]:
    """Index ranges [lo, hi) needed at levels 0..levels for output [lo, hi) at the last."""
    out = [(lo, hi)]
    for _ in range(levels):
        lo = (lo - _HALO) // 2  # floor: 2 * lo' + 6 <= lo
        hi = -((-(hi + _HALO)) // 2)  # ceil: 2 * hi' - 6 >= hi
        out.append((lo, hi))
    return out[::-1]


def _level_keys(key: int, levels: int) -> list[int]:
    return [rng.stream_key(key, f"fractal/level{lev}") for lev in range(1, levels + 1)]


def _cr_half(a, b, c, d):
    """Catmull-Rom at t = 1/2: (-a + 9b + 9c - d) / 16, fixed float32 operation order."""
    return (b + c) * np.float32(9.0 / 16.0) - (a + d) * np.float32(1.0 / 16.0)


def _refine(z: np.ndarray, r_lo: int, c_lo: int, key: int, sig_d, sig_s) -> np.ndarray:
    """One level: level-l array ``z`` (rows from r_lo, cols from c_lo, global level-l
    indices) -> level l+1 array on rows [2 r_lo + 6, 2 r_hi - 6) x same for cols."""
    n, m = z.shape
    # --- diamond: D[p, q] at (2p+1, 2q+1) for p in [r_lo+1, r_lo+n-2) ----------------
    tc = _cr_half(z[:, :-3], z[:, 1:-2], z[:, 2:-1], z[:, 3:])  # (n, m-3), cols q=c_lo+1..
    d = _cr_half(tc[:-3], tc[1:-2], tc[2:-1], tc[3:])  # (n-3, m-3)
    # global level-(l+1) indices of D
    dr = 2 * np.arange(r_lo + 1, r_lo + n - 2) + 1
    dc = 2 * np.arange(c_lo + 1, c_lo + m - 2) + 1
    if sig_d:
        d += rng.hash_normal(key, dr[:, None], dc[None, :]) * sig_d

    # E[p,q] = z[p-r_lo, q-c_lo]; D[p,q] = d[p-r_lo-1, q-c_lo-1].
    # Output level-(l+1) rows/cols [2 r_lo + 6, 2 (r_lo + n) - 6): p from r_lo+3.
    pn = n - 6  # number of output row pairs
    qn = m - 6
    w0, w1, w2 = (np.float32(w) for w in _SQUARE_WEIGHTS)

    def E(dp, dq, rows, cols):  # E[p+dp, q+dq] for p from r_lo+3, q from c_lo+3
        return z[3 + dp : 3 + dp + rows, 3 + dq : 3 + dq + cols]

    def D(dp, dq, rows, cols):
        return d[2 + dp : 2 + dp + rows, 2 + dq : 2 + dq + cols]

    # --- square, horizontal-edge points H[p, q] at (2p, 2q+1) ------------------------
    a, b = pn, qn
    hs = (E(0, 0, a, b) + E(0, 1, a, b)) + (D(0, 0, a, b) + D(-1, 0, a, b))
    hk = ((E(1, 0, a, b) + E(1, 1, a, b)) + (E(-1, 0, a, b) + E(-1, 1, a, b))) + (
        (D(0, 1, a, b) + D(0, -1, a, b)) + (D(-1, 1, a, b) + D(-1, -1, a, b))
    )
    hf = (E(0, -1, a, b) + E(0, 2, a, b)) + (D(1, 0, a, b) + D(-2, 0, a, b))
    hh = (hs * w0 + hk * w1) + hf * w2
    # --- square, vertical-edge points V[p, q] at (2p+1, 2q): transpose roles ---------
    vs = (E(0, 0, a, b) + E(1, 0, a, b)) + (D(0, 0, a, b) + D(0, -1, a, b))
    vk = ((E(0, 1, a, b) + E(1, 1, a, b)) + (E(0, -1, a, b) + E(1, -1, a, b))) + (
        (D(1, 0, a, b) + D(-1, 0, a, b)) + (D(1, -1, a, b) + D(-1, -1, a, b))
    )
    vf = (E(-1, 0, a, b) + E(2, 0, a, b)) + (D(0, 1, a, b) + D(0, -2, a, b))
    vv = (vs * w0 + vk * w1) + vf * w2
    if sig_s:
        pr = 2 * np.arange(r_lo + 3, r_lo + 3 + a)
        qc = 2 * np.arange(c_lo + 3, c_lo + 3 + b)
        hh += rng.hash_normal(key, pr[:, None], qc[None, :] + 1) * sig_s
        vv += rng.hash_normal(key, pr[:, None] + 1, qc[None, :]) * sig_s

    out = np.empty((2 * a, 2 * b), dtype=np.float32)
    out[0::2, 0::2] = E(0, 0, a, b)
    out[1::2, 1::2] = D(0, 0, a, b)
    out[0::2, 1::2] = hh
    out[1::2, 0::2] = vv
    return out


def _clamped(z: np.ndarray, r_lo: int, r_hi: int, c_lo: int, c_hi: int) -> np.ndarray:
    ri = np.clip(np.arange(r_lo, r_hi), 0, z.shape[0] - 1)
    ci = np.clip(np.arange(c_lo, c_hi), 0, z.shape[1] - 1)
    return z[np.ix_(ri, ci)]


def upscale_high(
    high_coarse,
    *,
    factor: int,
    window=None,
    key: int,
    params: FractalParams,
    coarse_resolution_m: float,
) -> np.ndarray:
    """Diamond-square refinement (Catmull-Rom, fractal noise) of the high-frequency grid.

    Existing points keep their values, so the result at fine pixels ``(i F, j F)``
    equals ``float32(high_coarse[i, j])``; noise is added only at newly created points,
    from :func:`lunar_drake.rng.hash_normal` under a distinct key per level derived from
    ``key`` and keyed by global indices at that level (bit-identical for any window).

    Args:
        high_coarse: (n, m) high-frequency coarse DEM (m).
        factor: F = 2**L.
        window: ``(row0, col0, nrows, ncols)`` in global fine pixels; None = whole grid.
        key: 64-bit noise key (e.g. ``rng.stream_key(seed, "terrain/high")``).
        params: roughness parameters.
        coarse_resolution_m: coarse pixel size (m); fine pixel = this / F.

    Returns:
        float32 (nrows, ncols) heights (m).
    """
    L = _levels(factor)
    F = 1 << L
    z0 = _check_coarse(high_coarse, "high_coarse")
    r0, c0, h, w = _check_window(window, z0.shape, F)
    if not isinstance(key, numbers.Integral) or isinstance(key, bool) or not 0 <= key < 2**64:
        raise ConfigError(f"key={key!r} is not allowed; need an integer in [0, 2**64)")
    if not (
        isinstance(coarse_resolution_m, numbers.Real)
        and math.isfinite(coarse_resolution_m)
        and coarse_resolution_m > 0
    ):
        raise OutOfRangeError(
            f"coarse_resolution_m={coarse_resolution_m!r} is not allowed; need a finite "
            "number > 0 (m)"
        )
    rr = _level_ranges(r0, r0 + h, L)
    cr = _level_ranges(c0, c0 + w, L)
    z = _clamped(z0, rr[0][0], rr[0][1], cr[0][0], cr[0][1]).astype(np.float32)
    keys = _level_keys(int(key), L)
    for lev in range(1, L + 1):
        sd, ss = level_noise_std(lev, params=params, coarse_resolution_m=coarse_resolution_m)
        (r_lo, r_hi), (c_lo, c_hi) = rr[lev - 1], cr[lev - 1]
        assert z.shape == (r_hi - r_lo, c_hi - c_lo)
        zn = _refine(z, r_lo, c_lo, keys[lev - 1], np.float32(sd), np.float32(ss))
        # crop to the range the next level (or the output) needs
        nr_lo, nr_hi = rr[lev]
        nc_lo, nc_hi = cr[lev]
        br, bc = 2 * r_lo + _HALO, 2 * c_lo + _HALO
        z = zn[nr_lo - br : nr_hi - br, nc_lo - bc : nc_hi - bc]
    return np.ascontiguousarray(z)


def upscale_dem(
    coarse,
    *,
    factor: int,
    key: int,
    params: FractalParams,
    coarse_resolution_m: float,
    window=None,
) -> np.ndarray:
    """Fine DEM (float32, m) = upscaled low part + upscaled high part, for a window.

    Convenience for :func:`split_frequencies`, :func:`upscale_low` (with
    ``params.low_interpolation``) and :func:`upscale_high`; the sum is formed in
    float64 and rounded once. ``window`` = ``(row0, col0, nrows, ncols)`` or None.
    """
    L = _levels(factor)
    low, high = split_frequencies(coarse, params=params)
    win = _check_window(window, low.shape, 1 << L)
    z = _upscale_low64(low, 1 << L, win, params.low_interpolation)
    z += upscale_high(
        high,
        factor=factor,
        window=win,
        key=key,
        params=params,
        coarse_resolution_m=coarse_resolution_m,
    )
    return z.astype(np.float32)


# --------------------------------------------------------------------------------------
# Coarse synthesis from scratch
# --------------------------------------------------------------------------------------


def coarse_fractal(
    shape, *, resolution_m: float, rng: np.random.Generator, params: FractalParams
) -> np.ndarray:
    """An isotropic random fractal surface (float64, m) by spectral synthesis.

    Power spectral density ~ |k|**-(2H + 2) (2-D fBm with Hurst exponent H), synthesised
    on a grid padded to at least twice ``shape`` (so the result is not periodic) and
    cropped. Scaled so the *expected* RMS deviation at one pixel is
    ``params.rms_deviation_m * (resolution_m / params.ref_baseline_m) ** H``, i.e. the
    same fBm law the fine noise follows; zero mean over the returned grid.

    Args:
        shape: (nrows, ncols) of the coarse grid.
        resolution_m: coarse pixel size (m).
        rng: numpy Generator (e.g. ``lunar_drake.rng.generator(seed, "terrain/coarse")``).
        params: roughness parameters (hurst, rms_deviation_m, ref_baseline_m).
    """
    try:
        nr, nc = (int(v) for v in shape)
    except (TypeError, ValueError):
        nr = nc = 0
    if nr < 1 or nc < 1:
        raise OutOfRangeError(f"shape={shape!r} is not allowed; need two integers >= 1")
    if not (isinstance(resolution_m, numbers.Real) and math.isfinite(resolution_m)) or (
        resolution_m <= 0
    ):
        raise OutOfRangeError(
            f"resolution_m={resolution_m!r} is not allowed; need a finite number > 0 (m)"
        )
    H = params.hurst
    pr = sp_fft.next_fast_len(2 * nr, real=True)
    pc = sp_fft.next_fast_len(2 * nc, real=True)
    ky = sp_fft.fftfreq(pr)[:, None]
    kx = sp_fft.rfftfreq(pc)[None, :]
    k2 = kx * kx + ky * ky
    k2[0, 0] = 1.0
    amp = k2 ** (-(H + 1.0) / 2.0)  # sqrt of PSD ~ k^-(2H+2)
    amp[0, 0] = 0.0
    # Expected squared increment at a 1-pixel lag, averaged over x and y lags; the
    # rfft half-plane counts columns 1..(pc-1)//2 twice (conjugate partners).
    mult = np.full(kx.shape, 2.0)
    mult[0, 0] = 1.0
    if pc % 2 == 0:
        mult[0, -1] = 1.0
    lag = 2.0 - np.cos(2 * np.pi * kx) - np.cos(2 * np.pi * ky)
    expected = float((mult * amp**2 * lag).sum()) / (pr * pc)
    white = rng.standard_normal((pr, pc))
    z = sp_fft.irfft2(sp_fft.rfft2(white) * amp, s=(pr, pc))[:nr, :nc]
    target = params.rms_deviation_m * (resolution_m / params.ref_baseline_m) ** H
    z *= target / math.sqrt(expected) if expected > 0 else 0.0
    return z - z.mean()
