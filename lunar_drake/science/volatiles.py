"""Volatile layers from temperature and shadow (numpy/scipy; no Drake).

The relations and their sources are documented on the config classes of
:mod:`lunar_drake.science.config` (:class:`~.config.FrostConfig`,
:class:`~.config.OHConfig`, :class:`~.config.IceConfig`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy import ndimage

from lunar_drake.science.config import FrostConfig, IceConfig, OHConfig

#: 8-connectivity for shadow patches.
_EIGHT = np.ones((3, 3), bool)


def label_patches(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(labels, areas_px)``: 8-connected patches of ``mask`` (0 = outside; patch k has
    ``areas_px[k]`` cells, ``areas_px[0] = 0``)."""
    labels, n = ndimage.label(np.asarray(mask, bool), structure=_EIGHT)
    areas = np.bincount(labels.ravel(), minlength=n + 1)
    areas[0] = 0
    return labels, areas


class StripLabels:
    """8-connected patches of a mask handed over a block of rows at a time, top down
    (:meth:`add`): labels unique over the grid, patches that cross a seam joined by
    union-find. :meth:`areas` gives each label its whole patch's area, so that
    ``frost_of_areas(self.areas())[labels]`` equals :func:`frost_area_fraction`'s."""

    def __init__(self) -> None:
        self.n = 0
        self._parent = [np.zeros(1, np.int64)]
        self._areas = [np.zeros(1, np.int64)]
        self._last = None  # the previous block's last row of labels
        self._pairs = []

    def add(self, mask: np.ndarray) -> np.ndarray:
        """Labels (int64, 0 outside) of the next block of rows of the mask."""
        lab, n = ndimage.label(np.asarray(mask, bool), structure=_EIGHT)
        lab = lab.astype(np.int64)
        areas = np.bincount(lab.ravel(), minlength=n + 1)[1:]
        lab[lab > 0] += self.n
        self._parent.append(np.arange(self.n + 1, self.n + n + 1, dtype=np.int64))
        self._areas.append(areas.astype(np.int64))
        if self._last is not None and lab.shape[0]:
            first, cols = lab[0], lab.shape[1]
            for d in (-1, 0, 1):  # the previous row's c joins this row's c + d
                a = self._last[max(0, -d) : cols - max(0, d)]
                b = first[max(0, d) : cols - max(0, -d)]
                both = (a > 0) & (b > 0)
                if both.any():
                    self._pairs.append(np.unique(np.stack([a[both], b[both]], 1), axis=0))
        if lab.shape[0]:
            self._last = lab[-1].copy()
        self.n += n
        return lab

    def roots(self) -> np.ndarray:
        """The root label of every label (index 0: 0)."""
        parent = np.concatenate(self._parent)
        if self._pairs:
            pairs = np.unique(np.concatenate(self._pairs), axis=0)

            def find(i):
                while parent[i] != i:
                    parent[i] = parent[parent[i]]
                    i = parent[i]
                return i

            for a, b in pairs.tolist():
                ra, rb = find(a), find(b)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
        while True:  # full path compression
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                return parent
            parent = nxt

    def areas(self) -> np.ndarray:
        """The area (cells) of each label's whole patch (index 0: 0)."""
        roots = self.roots()
        per_root = np.bincount(roots, weights=np.concatenate(self._areas), minlength=roots.size)
        out = per_root[roots].astype(np.int64)
        out[0] = 0
        return out


def frost_of_areas(areas_px: np.ndarray, *, resolution_m: float,
                   config: FrostConfig | None = None) -> np.ndarray:  # fmt: skip
    """Frost area fraction of each patch (-) from its area in cells (``areas_px[0]``: the
    cells outside every patch, 0): ``max_area_frac (1 - exp(-A / area_scale_m2))``."""
    cfg = config or FrostConfig()
    area_m2 = np.asarray(areas_px, np.float64) * resolution_m**2
    per_patch = cfg.max_area_frac * -np.expm1(-area_m2 / cfg.area_scale_m2)
    per_patch[0] = 0.0
    return per_patch


def frost_area_fraction(
    psr: np.ndarray,
    t_max_k: np.ndarray,
    *,
    resolution_m: float,
    config: FrostConfig | None = None,
    stable_k: float = 110.0,
) -> np.ndarray:
    """Surface frost area fraction (-): in permanent shadow colder than ``stable_k`` at
    its warmest, ``max_area_frac (1 - exp(-A / area_scale_m2))`` for a patch of area A."""
    cfg = config or FrostConfig()
    cold = np.asarray(psr, bool) & (np.asarray(t_max_k) < stable_k)
    labels, areas = label_patches(cold)
    return frost_of_areas(areas, resolution_m=resolution_m, config=cfg)[labels]


def oh_ppm(t_k: np.ndarray, *, config: OHConfig | None = None) -> np.ndarray:
    """Surface OH (ppm, float32) at temperature ``t_k`` (K): a falling logistic."""
    cfg = config or OHConfig()
    t = np.ascontiguousarray(t_k)
    out = np.empty(t.shape, np.float32)
    _oh(t.reshape(-1), cfg.min_ppm, cfg.max_ppm, cfg.half_K, cfg.width_K, out.reshape(-1))
    return out


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _oh(t, lo, hi, half, width, out):  # pragma: no cover - numba
    for i in numba.prange(t.size):
        out[i] = lo + (hi - lo) * 0.5 * (1.0 - math.tanh(0.5 * (t[i] - half) / width))


def dry_layer_m(
    t_max_k: np.ndarray, t_mean_k: np.ndarray, *, config: IceConfig | None = None
) -> np.ndarray:
    """Depth of the ice-free top layer (m, float32): where the decaying temperature wave's
    maximum falls to ``stable_K`` (see :class:`~.config.IceConfig`), within ``[0,
    max_depth_m]``."""
    cfg = config or IceConfig()
    t_max, t_mean = np.asarray(t_max_k), np.asarray(t_mean_k)
    shape = np.broadcast_shapes(t_max.shape, t_mean.shape)
    t_max = np.ascontiguousarray(np.broadcast_to(t_max, shape))
    t_mean = np.ascontiguousarray(np.broadcast_to(t_mean, shape))
    out = np.empty(t_max.shape, np.float32)
    _dry(t_max.reshape(-1), t_mean.reshape(-1), cfg.stable_K, cfg.skin_depth_m,
         cfg.max_depth_m, out.reshape(-1))  # fmt: skip
    return out


@numba.njit(parallel=True, cache=True, error_model="numpy")
def _dry(t_max, t_mean, stable, skin, deepest, out):  # pragma: no cover - numba
    for i in numba.prange(t_max.size):
        hi = t_max[i]
        lo = min(t_mean[i], hi)
        if hi <= stable:
            out[i] = 0.0
        elif lo >= stable:
            out[i] = deepest
        else:
            out[i] = min(skin * math.log((hi - lo) / (stable - lo)), deepest)


def rim_factor(
    shape,
    *,
    resolution_m: float,
    x0_m: float,
    y1_m: float,
    craters,
    config: IceConfig | None = None,
) -> np.ndarray:
    """``1 - prod_k (1 - a_k exp(-d_k / (falloff_radii R_k)))`` over the craters of
    ``craters`` (x_m, y_m, diameter_m, age_yr arrays, site metres) of diameter >=
    ``min_crater_m``, on a grid whose west edge is ``x0_m`` and north edge ``y1_m``.
    Each crater is evaluated within ``(1 + 12 falloff_radii) R`` of its centre (its
    factor is below 1e-5 beyond)."""
    cfg = config or IceConfig()
    rows, cols = shape
    log_keep = np.zeros((rows, cols))
    x = np.asarray(craters.x_m, np.float64)
    y = np.asarray(craters.y_m, np.float64)
    d = np.asarray(craters.diameter_m, np.float64)
    age = np.asarray(craters.age_yr, np.float64)
    sel = d >= cfg.min_crater_m
    for cx, cy, dk, ak in zip(x[sel], y[sel], d[sel], age[sel], strict=True):
        rad = 0.5 * dk
        a = float(np.exp(-ak / cfg.age_scale_yr))
        if a < 1e-6:
            continue
        reach = rad * (1.0 + 12.0 * cfg.falloff_radii)
        c0 = max(0, int(np.floor((cx - reach - x0_m) / resolution_m)))
        c1 = min(cols, int(np.ceil((cx + reach - x0_m) / resolution_m)) + 1)
        r0 = max(0, int(np.floor((y1_m - (cy + reach)) / resolution_m)))
        r1 = min(rows, int(np.ceil((y1_m - (cy - reach)) / resolution_m)) + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        xs = x0_m + (np.arange(c0, c1) + 0.5) * resolution_m
        ys = y1_m - (np.arange(r0, r1) + 0.5) * resolution_m
        dist = np.abs(np.hypot(xs[None, :] - cx, ys[:, None] - cy) - rad)
        g = a * np.exp(-dist / (cfg.falloff_radii * rad))
        log_keep[r0:r1, c0:c1] += np.log1p(-np.minimum(g, 1.0 - 1e-12))
    return -np.expm1(log_keep)


def ice_wt_pct(
    dry_m: np.ndarray, rim: np.ndarray, *, config: IceConfig | None = None
) -> np.ndarray:
    """Water ice below the dry layer (wt%): ``background + rim_wt_pct * rim`` where the dry
    layer is shallower than ``max_depth_m``, 0 elsewhere."""
    cfg = config or IceConfig()
    ice = cfg.background_wt_pct + cfg.rim_wt_pct * np.asarray(rim, np.float64)
    return np.where(np.asarray(dry_m) < cfg.max_depth_m, ice, 0.0)


__all__ = [
    "dry_layer_m",
    "frost_area_fraction",
    "frost_of_areas",
    "ice_wt_pct",
    "label_patches",
    "oh_ppm",
    "rim_factor",
]
