"""Surface normals, slope and hillshade from a DEM tile.

Frames: site frame, x east (column index increases east), y north (row index increases
*south*), z up. Gradients are central differences over two pixels,
``dz/dx = (z[r, c+1] - z[r, c-1]) / 2h`` and ``dz/dy = (z[r-1, c] - z[r+1, c]) / 2h``;
the unit normal is ``(-dz/dx, -dz/dy, 1) / |.|``. A slope facing north (ground falling
towards the north, i.e. ``z`` growing with the row index) therefore has ``n_y > 0``.

Functions taking ``z_halo`` expect a tile with one extra pixel on every side (the
neighbouring tiles' pixels, or edge-replicated at the site boundary) and return the
interior, so tiled results equal whole-grid results exactly.
"""

from __future__ import annotations

import math

import numpy as np

from lunar_drake.errors import ConfigError, NoDataError, OutOfRangeError


def _check(z, name: str, min_size: int) -> np.ndarray:
    z = np.asarray(z)
    if z.ndim != 2 or z.shape[0] < min_size or z.shape[1] < min_size:
        raise ConfigError(
            f"{name} has shape {z.shape!r}; expected a 2-D array at least {min_size} x {min_size}"
        )
    if not np.issubdtype(z.dtype, np.floating) and not np.issubdtype(z.dtype, np.integer):
        raise ConfigError(f"{name} has dtype {z.dtype}; expected a real numeric array")
    bad = ~np.isfinite(z)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise NoDataError(
            f"{name} holds {int(bad.sum())} non-finite cells (first {float(z[r, c])!r} at row {r}, "
            f"col {c}); all heights must be finite"
        )
    return z


def _check_res(resolution_m) -> float:
    if isinstance(resolution_m, bool) or not isinstance(resolution_m, (int, float, np.number)):
        raise ConfigError(f"resolution_m = {resolution_m!r} must be a number > 0 m")
    if not (math.isfinite(resolution_m) and resolution_m > 0):
        raise OutOfRangeError(f"resolution_m = {resolution_m!r} must be finite and > 0 m")
    return float(resolution_m)


def _gradients(z_halo: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """dz/dx (east) and dz/dy (north) of the interior: float32 for float32 input (the
    pipeline's tiles), float64 otherwise."""
    dt = np.float32 if z_halo.dtype == np.float32 else np.float64
    z = z_halo.astype(dt, copy=False)
    inv = dt(1.0 / (2.0 * res))
    dzdx = (z[1:-1, 2:] - z[1:-1, :-2]) * inv
    dzdy = (z[:-2, 1:-1] - z[2:, 1:-1]) * inv
    return dzdx, dzdy


def normals_from_dem(z_halo, *, resolution_m: float) -> np.ndarray:
    """Unit surface normals of a tile's interior, float32 ``(3, h, w)`` = (n_x, n_y, n_z).

    Args:
        z_halo: heights (m), ``(h + 2, w + 2)``: the tile plus a 1-pixel halo.
        resolution_m: pixel size (m).
    """
    z = _check(z_halo, "z_halo", 3)
    res = _check_res(resolution_m)
    p, q = _gradients(z, res)
    one = p.dtype.type(1.0)
    inv_norm = p * p
    inv_norm += q * q
    inv_norm += one
    np.sqrt(inv_norm, out=inv_norm)
    np.divide(one, inv_norm, out=inv_norm)
    out = np.empty((3, *p.shape), dtype=np.float32)
    np.multiply(p, -inv_norm, out=out[0], casting="same_kind")
    np.multiply(q, -inv_norm, out=out[1], casting="same_kind")
    out[2] = inv_norm
    return out


def slope_deg(z_halo, *, resolution_m: float) -> np.ndarray:
    """Slope angle (degrees from horizontal) of a tile's interior, float32 ``(h, w)``.

    Args:
        z_halo: heights (m), ``(h + 2, w + 2)``: the tile plus a 1-pixel halo.
        resolution_m: pixel size (m).
    """
    z = _check(z_halo, "z_halo", 3)
    res = _check_res(resolution_m)
    p, q = _gradients(z, res)
    return np.degrees(np.arctan(np.sqrt(p * p + q * q))).astype(np.float32)


def hillshade(
    z, *, resolution_m: float, azimuth_deg: float = 315.0, altitude_deg: float = 30.0
) -> np.ndarray:
    """Lambertian hillshade in [0, 1] (float32, same shape as ``z``) for overview images.

    Args:
        z: heights (m), 2-D, at least 2 x 2; edges are replicated for the gradients.
        resolution_m: pixel size (m).
        azimuth_deg: direction the light comes from, degrees clockwise from north
            (315 = north-west, the cartographic convention).
        altitude_deg: Sun elevation above the horizon (degrees, in [0, 90]).
    """
    z = _check(z, "z", 2)
    res = _check_res(resolution_m)
    if not (math.isfinite(azimuth_deg)):
        raise OutOfRangeError(f"azimuth_deg = {azimuth_deg!r} must be finite")
    if not 0.0 <= altitude_deg <= 90.0:
        raise OutOfRangeError(f"altitude_deg = {altitude_deg!r}; allowed [0, 90]")
    n = normals_from_dem(np.pad(z.astype(np.float64), 1, mode="edge"), resolution_m=res)
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    light = (math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt))
    shade = light[0] * n[0] + light[1] * n[1] + light[2] * n[2]
    return np.clip(shade, 0.0, 1.0).astype(np.float32)
