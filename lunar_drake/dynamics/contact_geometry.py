"""Wheel and belly contact geometry against a Heightfield (numpy, no Drake).

A wheel is a cylinder of radius r and width b whose axle is the wheel body's y axis.
Its footprint is sampled on a small fixed grid (``n_along`` x ``n_across`` points),
so ridges, rocks and crater rims under part of the tread matter, not one point.

For every sample point k at horizontal offset u_k along the rolling direction and w_k
across the tread, the rim's lowest point is ``z_c - sqrt(r^2 - u_k^2)`` and the
penetration is ``delta_k = z_terrain(k) - (z_c - sqrt(r^2 - u_k^2))``. The wheel's
sinkage is the largest penetration; the contact normal is that of the least-squares
plane through the terrain samples; the contact point is the rim point below the centre
along that normal (inside the soil when the wheel has sunk). All frames are the
site/world frame W (m; x east, y north, z up).
"""

from __future__ import annotations

import dataclasses as dc

import numba
import numpy as np

from lunar_drake.errors import OutOfRangeError
from lunar_drake.terrain.heightfield import heights_in_box


@dc.dataclass(frozen=True)
class FootprintSampling:
    """How a wheel's footprint is sampled.

    Attributes:
        n_along: samples along the rolling direction (odd, >= 3).
        n_across: samples across the tread (>= 1).
        along_fraction: half-length of the sampled patch as a fraction of the radius.
    """

    n_along: int = 7
    n_across: int = 3
    along_fraction: float = 0.7

    def __post_init__(self):
        if self.n_along < 3 or self.n_along % 2 == 0:
            raise OutOfRangeError(f"n_along = {self.n_along!r}; must be odd and >= 3")
        if self.n_across < 1:
            raise OutOfRangeError(f"n_across = {self.n_across!r}; must be >= 1")
        if not 0.05 <= self.along_fraction <= 0.99:
            raise OutOfRangeError(f"along_fraction = {self.along_fraction!r}; allowed [0.05, 0.99]")


@dc.dataclass
class WheelContactGeometry:
    """Per-wheel contact geometry (arrays of length n_wheels unless noted).

    Attributes:
        sinkage: largest penetration of the rim below the terrain (m); <= 0: no contact.
        n_W: contact normal (n, 3), unit, pointing out of the terrain.
        forward_W: rolling direction (n, 3): axle x normal, unit, tangent to the terrain.
        lateral_W: normal x forward (n, 3): the wheel's left in the contact plane.
        p_WC: contact point: the rim point below the centre along n_W (n, 3) (m).
        off_terrain: True where any footprint sample lay outside the raster or on nodata.
    """

    sinkage: np.ndarray
    n_W: np.ndarray
    forward_W: np.ndarray
    lateral_W: np.ndarray
    p_WC: np.ndarray
    off_terrain: np.ndarray


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n, 3) arrays (np.cross is slow for tiny arrays)."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def _safe_heights(heightfield, x: np.ndarray, y: np.ndarray):
    """Heights at points; flags points off the raster (one pixel margin) or on nodata
    (their height is -inf so they never touch)."""
    return heightfield.heights_within(x, y, margin_m=heightfield.resolution_m)


def wheel_contact_geometry(
    *,
    heightfield,
    p_WWo: np.ndarray,
    axle_W: np.ndarray,
    radius_m: float,
    width_m: float,
    sampling: FootprintSampling,
) -> WheelContactGeometry:
    """Contact geometry of n wheels.

    The contact normal is that of the least-squares plane through the terrain heights
    over the footprint samples (one height gather per step for all wheels; a rock or
    rim under part of the tread tilts it).

    Args:
        heightfield: the site Heightfield.
        p_WWo: wheel centres (n, 3) in W (m).
        axle_W: axle directions (n, 3) in W (unit; the wheel body's +y).
        radius_m, width_m: wheel radius and width (m).
        sampling: footprint sampling pattern.
    """
    p = np.ascontiguousarray(p_WWo, dtype=np.float64).reshape(-1, 3)
    a = np.ascontiguousarray(axle_W, dtype=np.float64).reshape(-1, 3)
    U, Wc, pinv = footprint_pattern(sampling, radius_m, width_m)
    raster = heightfield.within_kernel_args(margin_m=heightfield.resolution_m)
    if raster is not None:  # one compiled call: the same operations as below
        sinkage, n_W, forward, lateral, p_WC, off = geometry_in_memory(
            *raster, p, a, U, Wc, pinv, float(radius_m)
        )
    else:
        f_h, s_h, xs, ys = _footprint_points(p, a, U, Wc)
        zt, ok = _safe_heights(heightfield, xs, ys)
        sinkage, n_W, forward, lateral, p_WC, off = _footprint_plane(
            p, a, f_h, s_h, U, zt, ok, pinv, float(radius_m)
        )
    return WheelContactGeometry(
        sinkage=sinkage,
        n_W=n_W,
        forward_W=forward,
        lateral_W=lateral,
        p_WC=p_WC,
        off_terrain=off,
    )


@numba.njit(cache=True)
def _unit3(x, y, z):  # pragma: no cover - numba
    n = max(np.sqrt(x * x + y * y + z * z), 1e-12)
    return x / n, y / n, z / n


@numba.njit(cache=True)
def _footprint_points(p, a, U, Wc):  # pragma: no cover - numba
    """Horizontal rolling (``f_h = a x z_up``) and side (``s_h = z_up x f_h``) directions
    (n, 3) of wheels with axles ``a`` (n, 3), and their footprint sample points
    ``xs, ys`` (n, k) (m) at offsets ``U`` along and ``Wc`` across the tread (k,)."""
    n = p.shape[0]
    k = U.size
    f_h = np.zeros((n, 3))
    s_h = np.zeros((n, 3))
    xs = np.empty((n, k))
    ys = np.empty((n, k))
    for i in range(n):
        ax, ay, _ = _unit3(a[i, 0], a[i, 1], a[i, 2])
        fx, fy, _ = _unit3(ay, -ax, 0.0)  # robust when the axle is tilted
        f_h[i, 0], f_h[i, 1] = fx, fy
        s_h[i, 0], s_h[i, 1] = -fy, fx
        for j in range(k):
            xs[i, j] = p[i, 0] + U[j] * fx - Wc[j] * fy
            ys[i, j] = p[i, 1] + U[j] * fy + Wc[j] * fx
    return f_h, s_h, xs, ys


@numba.njit(cache=True)
def _footprint_plane(p, a, f_h, s_h, U, zt, ok, pinv, radius):  # pragma: no cover - numba
    """Sinkage, the least-squares plane's normal, the rolling and lateral directions, the
    contact point and the off-terrain flag of each wheel from its footprint heights
    ``zt`` (n, k) (m; ``ok`` False where off the raster or on nodata)."""
    n, k = zt.shape
    sinkage = np.empty(n)
    n_W = np.empty((n, 3))
    forward = np.empty((n, 3))
    lateral = np.empty((n, 3))
    p_WC = np.empty((n, 3))
    off = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        deepest = -np.inf
        c1 = 0.0
        c2 = 0.0
        for j in range(k):
            if not ok[i, j]:
                off[i] = True
        for j in range(k):
            if ok[i, j]:
                rim = p[i, 2] - np.sqrt(max(radius * radius - U[j] * U[j], 0.0))
                deepest = max(deepest, zt[i, j] - rim)
                if not off[i]:
                    # Plane z = c0 + cu u + cw w over the footprint (axes f_h, s_h).
                    c1 += pinv[1, j] * zt[i, j]
                    c2 += pinv[2, j] * zt[i, j]
        sinkage[i] = deepest
        nx, ny, nz = _unit3(-c1 * f_h[i, 0] - c2 * s_h[i, 0], -c1 * f_h[i, 1] - c2 * s_h[i, 1], 1.0)
        ax, ay, az = a[i, 0], a[i, 1], a[i, 2]
        fx, fy, fz = _unit3(ay * nz - az * ny, az * nx - ax * nz, ax * ny - ay * nx)
        n_W[i, 0], n_W[i, 1], n_W[i, 2] = nx, ny, nz
        forward[i, 0], forward[i, 1], forward[i, 2] = fx, fy, fz
        lateral[i, 0] = ny * fz - nz * fy
        lateral[i, 1] = nz * fx - nx * fz
        lateral[i, 2] = nx * fy - ny * fx
        p_WC[i, 0] = p[i, 0] - radius * nx
        p_WC[i, 1] = p[i, 1] - radius * ny
        p_WC[i, 2] = p[i, 2] - radius * nz
    return sinkage, n_W, forward, lateral, p_WC, off


@numba.njit(cache=True)
def geometry_in_memory(
    z, res, left, right, bottom, top, p, a, U, Wc, pinv, radius
):  # pragma: no cover - numba
    """:func:`_footprint_points`, the heights of an in-memory raster
    (:func:`~lunar_drake.terrain.heightfield.heights_in_box`, the box already shrunk by
    the margin) and :func:`_footprint_plane` in one call."""
    f_h, s_h, xs, ys = _footprint_points(p, a, U, Wc)
    n, k = xs.shape
    zt, ok = heights_in_box(z, xs.ravel(), ys.ravel(), res, left, right, bottom, top)
    return _footprint_plane(p, a, f_h, s_h, U, zt.reshape(n, k), ok.reshape(n, k), pinv, radius)


_PATTERNS: dict = {}


def footprint_pattern(sampling: FootprintSampling, radius_m: float, width_m: float):
    """Sample offsets along (u) and across (w) the tread and the plane-fit pseudo-inverse."""
    key = (sampling, float(radius_m), float(width_m))
    if key not in _PATTERNS:
        L = sampling.along_fraction * radius_m
        u = np.linspace(-L, L, sampling.n_along)
        if sampling.n_across == 1:
            w = np.zeros(1)
        else:
            w = (
                np.linspace(-0.5, 0.5, sampling.n_across)
                * width_m
                * ((sampling.n_across - 1) / sampling.n_across)
            )
        U, Wc = np.meshgrid(u, w, indexing="ij")
        U, Wc = U.ravel(), Wc.ravel()
        A = np.c_[np.ones_like(U), U, Wc]
        pinv = np.linalg.pinv(A) if sampling.n_across > 1 else np.linalg.pinv(A[:, :2])
        if sampling.n_across == 1:
            pinv = np.vstack([pinv, np.zeros((1, U.size))])
        _PATTERNS[key] = (U, Wc, pinv)
    return _PATTERNS[key]


def belly_penetration(*, heightfield, p_WP: np.ndarray):
    """Penetration (m, > 0 when the point is below the terrain), terrain normals and an
    off-terrain flag for chassis belly points ``p_WP`` (k, 3)."""
    p = np.asarray(p_WP, dtype=float).reshape(-1, 3)
    raster = heightfield.within_kernel_args(margin_m=heightfield.resolution_m)
    if raster is not None:  # compiled: the same lookups as _safe_heights
        zt, ok = heights_in_box(raster[0], np.ascontiguousarray(p[:, 0]),
                                 np.ascontiguousarray(p[:, 1]), *raster[1:])  # fmt: skip
    else:
        zt, ok = _safe_heights(heightfield, p[:, 0], p[:, 1])
    pen = np.where(ok, zt - p[:, 2], -np.inf)
    nt = np.zeros((len(p), 3))
    nt[:, 2] = 1.0
    if (pen > 0).any():
        hit = ok & (pen > 0)
        nt[hit] = heightfield.normal(p[hit, 0], p[hit, 1])
    return pen, nt, ~ok
