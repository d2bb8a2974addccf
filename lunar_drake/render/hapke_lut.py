"""A tabulated bidirectional reflectance ``r(cos_i, cos_e, g)`` for the fast camera
engine: the exact function (e.g. :func:`lunar_drake.render.hapke.blended_reflectance`)
sampled once on a grid and read back by trilinear interpolation in compiled code.

Grid axes (all uniform on [0, 1], none needs an inverse trigonometric function at
lookup): ``sqrt(1 - cos_i)`` and ``sqrt(1 - cos_e)`` (about ``angle / sqrt(2)`` near
normal incidence, where cosines are flat, and ``1 - cos / 2`` near grazing); the phase
angle through ``sqrt(sin(g / 2))`` with ``sin(g / 2) = sqrt((1 - cos g) / 2)`` (about
``sqrt(g / 2)`` near zero phase, so the narrow opposition surge gets fine steps).
Accuracy against the exact function is measured by
:meth:`ReflectanceLUT.max_relative_error` (tests pin it; see docs/lighting.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from lunar_drake.errors import OutOfRangeError

__all__ = [
    "ReflectanceLUT",
    "lut_axis",
    "lut_axis_f32",
    "lut_cell_f32",
    "lut_corner_f32",
    "lut_reflectance",
    "lut_reflectance_at",
    "lut_reflectance_at_f32",
    "trilerp",
]


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_axis(c, n):
    """Grid coordinate in [0, n] of a cosine on the ``sqrt(1 - cos)`` axes."""
    return math.sqrt(1.0 - min(max(c, 0.0), 1.0)) * n


@numba.njit(cache=True, inline="always", error_model="numpy")
def trilerp(t000, t001, t010, t011, t100, t101, t110, t111, fx, fy, fz):
    """Trilinear blend of a cell's corners ``t[di][dj][dk]`` with fractions fx, fy, fz
    (k first, then j, then i; the arithmetic is in the fractions' float type)."""
    c00 = t000 + fz * (t001 - t000)
    c01 = t010 + fz * (t011 - t010)
    c10 = t100 + fz * (t101 - t100)
    c11 = t110 + fz * (t111 - t110)
    c0 = c00 + fy * (c01 - c00)
    c1 = c10 + fy * (c11 - c10)
    return c0 + fx * (c1 - c0)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _trilinear(table, i0, j0, k0, fx, fy, fz):
    """Trilinear blend of the cell at (i0, j0, k0) with fractions fx, fy, fz (the
    arithmetic is in the fractions' float type)."""
    return trilerp(
        table[i0, j0, k0], table[i0, j0, k0 + 1],
        table[i0, j0 + 1, k0], table[i0, j0 + 1, k0 + 1],
        table[i0 + 1, j0, k0], table[i0 + 1, j0, k0 + 1],
        table[i0 + 1, j0 + 1, k0], table[i0 + 1, j0 + 1, k0 + 1],
        fx, fy, fz,
    )  # fmt: skip


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_reflectance_at(table, x, y, cg):
    """Trilinear ``r`` at grid coordinates x (cos_i axis), y (cos_e axis) and cos_g."""
    ni = table.shape[0] - 1
    ne = table.shape[1] - 1
    ng = table.shape[2] - 1
    h = 0.5 * (1.0 - cg)
    z = math.sqrt(math.sqrt(min(max(h, 0.0), 1.0))) * ng
    i0 = min(int(x), ni - 1)
    j0 = min(int(y), ne - 1)
    k0 = min(int(z), ng - 1)
    fx = x - i0
    fy = y - j0
    fz = z - k0
    return _trilinear(table, i0, j0, k0, fx, fy, fz)


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_axis_f32(c, n):
    """:func:`lut_axis` in float32 (``c`` float32, ``n`` the float32 grid size)."""
    one = np.float32(1.0)
    return np.float32(math.sqrt(one - min(max(c, np.float32(0.0)), one))) * n


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_corner_f32(x, y, cg, ni, ne, ng):
    """The table cell of float32 axes ``x`` (incidence), ``y`` (emission) and phase
    cosine ``cg`` for a table of ``ni + 1`` x ``ne + 1`` x ``ng + 1`` nodes, whatever its
    memory layout: the int32 corner ``(i0, j0, k0)`` and the float32 fractions ``(fx,
    fy, fz)``."""
    one = np.float32(1.0)
    h = np.float32(0.5) * (one - cg)
    h = min(max(h, np.float32(0.0)), one)
    z = np.float32(math.sqrt(np.float32(math.sqrt(h)))) * np.float32(ng)
    # x, y, z >= 0: int32 truncation is int() (and vectorizes)
    i0 = min(np.int32(x), np.int32(ni - 1))
    j0 = min(np.int32(y), np.int32(ne - 1))
    k0 = min(np.int32(z), np.int32(ng - 1))
    return i0, j0, k0, x - np.float32(i0), y - np.float32(j0), z - np.float32(k0)


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_cell_f32(table, x, y, cg):
    """The cell of :func:`lut_reflectance_at_f32` without reading the table: ``(k, fx,
    fy, fz)``, the flat int32 index of its (i0, j0, k0) corner in the C-contiguous table
    and the float32 fractions (vector code; the caller reads the eight corners at ``k``,
    ``k + 1``, ``k + n_g``, ... and blends them with :func:`trilerp`)."""
    ne = table.shape[1] - 1
    ng = table.shape[2] - 1
    i0, j0, k0, fx, fy, fz = lut_corner_f32(x, y, cg, table.shape[0] - 1, ne, ng)
    k = (i0 * np.int32(ne + 1) + j0) * np.int32(ng + 1) + k0
    return k, fx, fy, fz


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_reflectance_at_f32(table, x, y, cg):
    """:func:`lut_reflectance_at` in float32 arithmetic (``x``, ``y``, ``cg`` float32):
    the form a compiled loop vectorizes eight pixels wide where the CPU has fast
    gathers, table reads included (results within ~1e-6 relative of the float64 form);
    :func:`lut_cell_f32` and :func:`trilerp` are the same arithmetic in two halves."""
    ni = table.shape[0] - 1
    ne = table.shape[1] - 1
    ng = table.shape[2] - 1
    one = np.float32(1.0)
    h = np.float32(0.5) * (one - cg)
    h = min(max(h, np.float32(0.0)), one)
    z = np.float32(math.sqrt(np.float32(math.sqrt(h)))) * np.float32(ng)
    i0 = min(int(x), ni - 1)
    j0 = min(int(y), ne - 1)
    k0 = min(int(z), ng - 1)
    fx = x - np.float32(i0)
    fy = y - np.float32(j0)
    fz = z - np.float32(k0)
    return _trilinear(table, i0, j0, k0, fx, fy, fz)


@numba.njit(cache=True, inline="always", error_model="numpy")
def lut_reflectance(table, ci, ce, cg):
    """Trilinear ``r`` from ``table[i, e, g]`` at cos_i, cos_e, cos_g (clamped to the
    grid; the caller skips ``cos_i <= 0``)."""
    return lut_reflectance_at(
        table, lut_axis(ci, table.shape[0] - 1), lut_axis(ce, table.shape[1] - 1), cg
    )


@numba.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def _lookup_many(table, ci, ce, cg, out):
    for i in numba.prange(out.size):
        out[i] = lut_reflectance(table, ci[i], ce[i], cg[i]) if ci[i] > 0.0 else 0.0


@dataclass(frozen=True)
class ReflectanceLUT:
    """Tabulated ``r(cos_i, cos_e, g)`` (1/sr).

    Attributes:
        table: ``(n_i, n_e, n_g)`` float32 values on the grid (module docstring).
    """

    table: np.ndarray

    @classmethod
    def build(
        cls,
        reflectance: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
        *,
        n_i: int = 129,
        n_e: int = 129,
        n_g: int = 129,
    ) -> ReflectanceLUT:
        """Sample ``reflectance(cos_i, cos_e, phase_rad)`` (vectorized) on the grid.

        Grid points whose phase is impossible for their (i, e) (outside ``|i - e| <=
        g <= i + e``) are set to the value at the nearest possible phase, so that
        interpolation near the boundary stays smooth.
        """
        for name, n in (("n_i", n_i), ("n_e", n_e), ("n_g", n_g)):
            if not 8 <= int(n) <= 1024:
                raise OutOfRangeError(f"{name} = {n!r}; allowed 8..1024")
        ci = 1.0 - np.linspace(0.0, 1.0, int(n_i)) ** 2
        ce = 1.0 - np.linspace(0.0, 1.0, int(n_e)) ** 2
        u = np.linspace(0.0, 1.0, int(n_g))
        g = 2.0 * np.arcsin(np.minimum(u**2, 1.0))
        inc = np.arccos(ci)[:, None, None]
        emi = np.arccos(ce)[None, :, None]
        gg = np.clip(g[None, None, :], np.abs(inc - emi), inc + emi)
        CI, CE, G = np.broadcast_arrays(ci[:, None, None], ce[None, :, None], gg)
        r = np.asarray(
            reflectance(CI.ravel().copy(), CE.ravel().copy(), G.ravel().copy()), np.float64
        ).reshape(CI.shape)
        r = np.where(np.isfinite(r), r, 0.0)
        r[-1] = 0.0  # cos_i = 0: no light
        return cls(table=np.ascontiguousarray(r, dtype=np.float32))

    def __call__(self, cos_i, cos_e, phase) -> np.ndarray:
        """Vectorized lookup at ``phase`` (rad); 0 where ``cos_i <= 0``. float32."""
        ci, ce, g = np.broadcast_arrays(
            np.asarray(cos_i, np.float64), np.asarray(cos_e, np.float64), np.asarray(phase)
        )
        cg = np.cos(np.asarray(g, np.float64))
        out = np.empty(ci.size, np.float32)
        _lookup_many(self.table, ci.ravel(), ce.ravel(), cg.ravel(), out)
        return out.reshape(ci.shape)

    def max_relative_error(
        self,
        reflectance: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
        *,
        samples: int = 20000,
        seed: int = 0,
        min_cos: float = 0.02,
    ) -> tuple[float, float]:
        """``(p99, max)`` of ``|lut - exact| / exact`` at random feasible geometries with
        cos_i, cos_e >= ``min_cos``."""
        rng = np.random.default_rng(seed)
        ci = rng.uniform(min_cos, 1.0, samples)
        ce = rng.uniform(min_cos, 1.0, samples)
        i, e = np.arccos(ci), np.arccos(ce)
        g = rng.uniform(np.abs(i - e), np.minimum(i + e, math.pi))
        exact = np.asarray(reflectance(ci, ce, g), np.float64)
        approx = self(ci, ce, g).astype(np.float64)
        ok = exact > 1e-6
        rel = np.abs(approx[ok] - exact[ok]) / exact[ok]
        return float(np.quantile(rel, 0.99)), float(rel.max())
