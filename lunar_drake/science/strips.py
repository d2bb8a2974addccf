"""Illumination strip by strip, for DEMs too big to hold whole (numba; no Drake).

:func:`~lunar_drake.science.thermal.illumination` sweeps the whole DEM at once: exact
(to its hull sweep) but about 45 bytes a pixel held, 42 GB for the paper's 30720^2 site.
:func:`illumination_strips` reads the DEM a window of rows at a time instead:

* **Strips.** The grid is cut into strips of ``ThermalConfig.strip_px`` rows, anchored at
  row 0 (a property of the model, like its sectors: ``WorldConfig.tile_px`` never
  changes a byte). Each strip is swept with every sector inside a *window* of the DEM:
  the strip and ``near_field_m`` of terrain on either side (full width), so every
  caster within ``near_field_m`` of a pixel, and every one on the window, is seen at
  full resolution exactly as the whole-grid sweep sees it.
* **Far field.** Terrain beyond the window enters through a DEM block-averaged to about
  ``far_cell_m`` (:func:`far_fields`): one hull sweep of it per sector keeps, for each
  coarse cell, the steepest caster at least ``near_field_m`` away (``FAR`` mode of
  :mod:`.sweep`) as its tangent ``t`` and inverse distance ``b``. A pixel of height
  ``z`` takes ``t + (z_cell - z) b`` interpolated bilinearly, and its horizon is the
  higher of that and the window's. Approximations: far casters are block means (a rock
  beyond ``near_field_m`` is averaged into its cell), seen from the cell's centre
  rather than the pixel's.

Memory: the window's DEM (float32 read and a float32 canonical copy: 8 bytes a window
pixel), the strip's accumulators (17 bytes a strip pixel; the window's arrays are
allocated whole but their halo rows are never touched), plus the far fields (8 bytes a
coarse cell a sweep; :func:`far_factor` keeps that under 32 MB a sweep). The sweep
kernel interpolates a pixel's far tangent itself (:class:`~.sweep.FarField`), and only
where its window's horizon leaves it lit at some level.
With one strip that covers the grid the result equals
:func:`~lunar_drake.science.thermal.illumination` byte for byte.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lunar_drake.render.horizon import sweep_orientation
from lunar_drake.render.lightmap import SUN_ANGULAR_RADIUS_DEG
from lunar_drake.science.config import ThermalConfig
from lunar_drake.science.sweep import (
    EPOCH,
    FAR,
    NO_CASTER,
    SECTOR,
    FarField,
    Sweep,
    canonical_dem,
    set_threads,
)
from lunar_drake.science.thermal import _axis  # coarse index and weight of a pixel


def coarse_dem(read_rows, shape, k: int) -> np.ndarray:
    """Means of ``k x k`` blocks of the DEM read by ``read_rows(r0, r1)`` (a multiple of
    ``k`` rows at a time; edge rows and columns repeated, as
    :func:`~lunar_drake.science.thermal.block_mean`)."""
    from lunar_drake.science.thermal import block_mean

    rows, cols = shape
    out = np.empty((-(-rows // k), -(-cols // k)))
    step = max(1, (1 << 22) // max(cols, 1) // k) * k
    for r0 in range(0, rows, step):
        r1 = min(rows, r0 + step)
        out[r0 // k : -(-r1 // k)] = block_mean(read_rows(r0, r1), k)
    return out


def far_fields(zk: np.ndarray, jobs, *, resolution_m: float, near_field_m: float,
               z_ref: float = 0.0,
               workers: int = 2) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Per sweep of ``jobs`` (:func:`~lunar_drake.science.thermal.sweep_jobs`), the far
    field of coarse DEM ``zk`` (pixel ``resolution_m``): ``(a, b)`` float32 with the
    steepest caster from a coarse step short of ``near_field_m`` on, seen from height
    ``z`` at tangent ``a - (z - z_ref) b`` (``b`` = 1 / its distance, 1/m; ``a`` =
    NO_CASTER, ``b`` = 0 where there is none; ``z_ref`` keeps float32 exact whatever the
    height datum)."""
    set_threads(workers)
    out = []
    for az, *_ in jobs:
        # Casters from a column step short of near_field_m on: the window holds at
        # least that many column steps, so the two overlap (a pixel's far field is
        # interpolated from cells up to one step nearer).
        sw = Sweep(zk, azimuth_deg=az, resolution_m=resolution_m, chunk=64,
                   near=max(1, math.floor(near_field_m / resolution_m) - 1))  # fmt: skip
        o = sw.orient
        t = np.full(zk.shape, NO_CASTER, np.float64)
        inv_d = np.zeros(zk.shape, np.float64)
        sw.run(FAR, np.zeros(11), [0.0], o.canon(t), o.canon(inv_d), np.zeros((1, 1), np.uint8))
        none = t <= 0.5 * NO_CASTER
        a = np.where(none, NO_CASTER, t + (zk - z_ref) * inv_d).astype(np.float32)
        out.append((a, np.where(none, 0.0, inv_d).astype(np.float32)))
    return out


@numba.njit(cache=True, error_model="numpy")
def _axes(i0, n_idx, k, n):  # pragma: no cover - numba
    """:func:`~lunar_drake.science.thermal._axis` of pixel indices ``i0..i0+n_idx-1``:
    lower and upper coarse indices and weights (the same values, computed once)."""
    lo = np.empty(n_idx, np.int64)
    hi = np.empty(n_idx, np.int64)
    f = np.empty(n_idx)
    for i in range(n_idx):
        lo[i], hi[i], f[i] = _axis(i0 + i, k, n)
    return lo, hi, f


def far_field(a: np.ndarray, b: np.ndarray, *, k: int, z_ref: float, row0: int,
              shape) -> FarField:  # fmt: skip
    """The :class:`~lunar_drake.science.sweep.FarField` of one sweep's ``(a, b)``
    (:func:`far_fields`, cells of ``k`` pixels) for a window of ``shape`` whose row 0
    is the DEM's ``row0``."""
    rows, cols = (int(v) for v in shape)
    r_lo, r_hi, r_w = _axes(int(row0), rows, int(k), a.shape[0])
    c_lo, c_hi, c_w = _axes(0, cols, int(k), a.shape[1])
    index = np.stack([np.concatenate([r_lo, c_lo]), np.concatenate([r_hi, c_hi])])
    return FarField(a, b, index, np.concatenate([r_w, c_w]), float(z_ref), rows)


#: The far field's coarse grid holds at most this many cells (8 bytes each a sweep).
MAX_FAR_CELLS = 4_000_000


def far_factor(shape, resolution_m: float, config: ThermalConfig) -> int:
    """Pixels per side of the far field's cells: about ``config.far_cell_m``, coarser
    where the grid would have more than :data:`MAX_FAR_CELLS` of them."""
    k = max(1, round(config.far_cell_m / resolution_m))
    return max(k, math.ceil(math.sqrt(int(shape[0]) * int(shape[1]) / MAX_FAR_CELLS)))


def _canonical(o, gr: float, gc: float, window_shape) -> tuple[float, float]:
    """Canonical ``(R, C)`` of window grid point ``(gr, gc)`` (fractional)."""
    nr, nc = window_shape
    if o.transpose:
        return gc, (nr - 1 - gr) if o.flip else gr
    return gr, (nc - 1 - gc) if o.flip else gc


def illumination_strips(read_rows, shape, *, resolution_m: float, jobs, config: ThermalConfig,
                        horizon_mask=None, chunk: int = 64, near: int = 3, workers: int = 2,
                        progress=None):  # fmt: skip
    """Yields ``(row0, Illumination)`` strip by strip, top down, for the DEM read by
    ``read_rows(r0, r1)`` (rows ``r0..r1-1`` as a float array, full width) of ``shape``
    (see the module docstring; ``jobs`` from
    :func:`~lunar_drake.science.thermal.sweep_jobs`). ``progress(done, total)`` is called
    after each strip."""
    from lunar_drake.science.thermal import Illumination, _mask_deg

    rows, cols = (int(v) for v in shape)
    strip = int(config.strip_px)
    halo = math.ceil(config.near_field_m / resolution_m)
    whole = strip >= rows
    far = []
    k = far_factor(shape, resolution_m, config)
    z_ref = 0.0
    if not whole:
        zk = coarse_dem(read_rows, (rows, cols), k)
        z_ref = float(np.mean(zk))
        far = far_fields(zk, jobs, resolution_m=resolution_m * k, z_ref=z_ref,
                         near_field_m=config.near_field_m, workers=workers)  # fmt: skip
        del zk
    set_threads(workers)
    starts = list(range(0, rows, strip))
    for si, r0 in enumerate(starts):
        r1 = min(rows, r0 + strip)
        w0, w1 = (0, rows) if whole else (max(0, r0 - halo), min(rows, r1 + halo))
        zw = np.asarray(read_rows(w0, w1))
        wshape = zw.shape
        acc = Illumination(
            np.zeros(wshape, np.uint8), np.zeros(wshape, np.float32),
            np.zeros(wshape, np.float32), np.zeros(wshape, np.float32),
            np.zeros(wshape, np.float32),
        )  # fmt: skip
        order = sorted(range(len(jobs)), key=lambda j: (
            sweep_orientation(jobs[j][0], wshape).transpose,
            sweep_orientation(jobs[j][0], wshape).flip))  # fmt: skip
        zc, key, tables = None, None, None
        for j in order:
            az, els, flux, w, epoch = jobs[j]
            o = sweep_orientation(az, wshape)
            if (o.transpose, o.flip) != key:
                key, zc, sw = (o.transpose, o.flip), None, None  # one canonical copy at once
                zc = canonical_dem(zw, o)
            sw = Sweep(zw, azimuth_deg=az, resolution_m=resolution_m, chunk=chunk, near=near,
                       canonical=zc)  # fmt: skip
            centre = _canonical(o, 0.5 * (rows - 1) - w0, 0.5 * (cols - 1), wshape)
            par = sw.sun_par(flux_w_m2=flux, mask_deg=_mask_deg(horizon_mask, az),
                             radius_deg=SUN_ANGULAR_RADIUS_DEG, w_mean=w,
                             centre=centre)  # fmt: skip
            ff, region = None, None
            if not whole:
                lo, hi = r0 - w0, r1 - w0
                if o.transpose:
                    c = (wshape[0] - hi, wshape[0] - lo) if o.flip else (lo, hi)
                    region = (0, o.shape[0], *c)
                else:
                    region = (lo, hi, 0, o.shape[1])
                # The tables depend on the window only: built once per strip.
                if tables is None:
                    tables = far_field(*far[j], k=k, z_ref=z_ref, row0=w0, shape=wshape)
                ff = tables._replace(a=far[j][0], b=far[j][1])
            a, b = ((acc.lit_now, acc.q_now_w_m2) if epoch
                    else (acc.q_max_w_m2, acc.q_mean_w_m2))  # fmt: skip
            sw.run(EPOCH if epoch else SECTOR, par, els, o.canon(a), o.canon(b),
                   o.canon(acc.ever_lit), far=ff, region=region, extent_px=(rows, cols))
        sl = slice(r0 - w0, r1 - w0)
        parts = (acc.ever_lit, acc.q_max_w_m2, acc.q_mean_w_m2, acc.q_now_w_m2, acc.lit_now)
        yield r0, Illumination(*(np.ascontiguousarray(a[sl]) for a in parts))
        del zw, zc, acc, sw
        if progress is not None:
            progress(si + 1, len(starts))


__all__ = [
    "MAX_FAR_CELLS",
    "coarse_dem",
    "far_factor",
    "far_field",
    "far_fields",
    "illumination_strips",
]
