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

import numpy as np

from lunar_drake.errors import NoDataError, OutOfBoundsError, OutOfRangeError


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


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.sqrt((v * v).sum(axis=-1, keepdims=True)), 1e-12)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
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
    b = heightfield.bounds
    m = heightfield.resolution_m
    ok = (
        (x >= b.left + m)
        & (x <= b.right - m)
        & (y >= b.bottom + m)
        & (y <= b.top - m)
        & np.isfinite(x)
        & np.isfinite(y)
    )
    z = np.full(x.shape, -np.inf)
    if ok.all():
        try:
            return heightfield.height(x, y), ok
        except NoDataError:
            pass
    for k in np.flatnonzero(ok.ravel()):
        try:
            z.ravel()[k] = heightfield.height(x.ravel()[k : k + 1], y.ravel()[k : k + 1])[0]
        except (NoDataError, OutOfBoundsError):
            ok.ravel()[k] = False
    return z, ok


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
    p = np.asarray(p_WWo, dtype=float).reshape(-1, 3)
    a = _unit(np.asarray(axle_W, dtype=float).reshape(-1, 3))
    n_w = p.shape[0]
    # Horizontal rolling direction (for sampling); robust when the axle is tilted.
    f_h = _unit(np.stack([a[:, 1], -a[:, 0], np.zeros(n_w)], axis=1))  # a x z_up
    s_h = np.stack([-f_h[:, 1], f_h[:, 0], np.zeros(n_w)], axis=1)  # z_up x f_h
    U, Wc, pinv = _pattern(sampling, radius_m, width_m)
    xs = p[:, 0:1] + U[None, :] * f_h[:, 0:1] + Wc[None, :] * s_h[:, 0:1]
    ys = p[:, 1:2] + U[None, :] * f_h[:, 1:2] + Wc[None, :] * s_h[:, 1:2]
    zt, ok = _safe_heights(heightfield, xs, ys)
    rim = p[:, 2:3] - np.sqrt(np.maximum(radius_m**2 - U[None, :] ** 2, 0.0))
    off = ~ok.all(axis=1)
    pen = np.where(ok, zt - rim, -np.inf)
    sinkage = pen.max(axis=1)
    # Plane z = c0 + cu u + cw w over the footprint (local horizontal axes f_h, s_h).
    coef = np.where(off[:, None], 0.0, np.where(ok, zt, 0.0)) @ pinv.T  # (n, 3)
    cu, cw = coef[:, 1], coef[:, 2]
    n_W = _unit(
        np.stack(
            [
                -cu * f_h[:, 0] - cw * s_h[:, 0],
                -cu * f_h[:, 1] - cw * s_h[:, 1],
                np.ones(n_w),
            ],
            axis=1,
        )
    )
    forward = _unit(_cross(a, n_W))
    lateral = _cross(n_W, forward)
    p_WC = p - radius_m * n_W
    return WheelContactGeometry(
        sinkage=sinkage,
        n_W=n_W,
        forward_W=forward,
        lateral_W=lateral,
        p_WC=p_WC,
        off_terrain=off,
    )


_PATTERNS: dict = {}


def _pattern(sampling: FootprintSampling, radius_m: float, width_m: float):
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
    zt, ok = _safe_heights(heightfield, p[:, 0], p[:, 1])
    pen = np.where(ok, zt - p[:, 2], -np.inf)
    nt = np.zeros((len(p), 3))
    nt[:, 2] = 1.0
    if (pen > 0).any():
        hit = ok & (pen > 0)
        nt[hit] = heightfield.normal(p[hit, 0], p[hit, 1])
    return pen, nt, ~ok
