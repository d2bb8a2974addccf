"""Is the Earth above the local terrain horizon at the rover's antenna? Pure (no Drake).

The terrain horizon toward an azimuth is the largest elevation angle of the terrain seen
from the antenna, ``atan((z(d) - z_a - d^2 / (2 R)) / d)`` over distances ``d`` along the
ray to the raster's edge (heights bilinear, the Moon's curvature through ``d^2/(2R)``),
sampled every ``step_m`` (default: the raster resolution). Terrain beyond the site
raster is not seen (a far ridge can hide the Earth where this says it is visible).
"""

from __future__ import annotations

import math

import numpy as np

from lunar_drake.errors import OutOfRangeError
from lunar_drake.terrain.crs import MOON_RADIUS_M


def ray_length_m(*, bounds, p_xy, direction_xy) -> float:
    """Distance (m) from ``p_xy`` (inside ``bounds``) to the raster edge along the unit
    ``direction_xy``."""
    x, y = float(p_xy[0]), float(p_xy[1])
    dx, dy = float(direction_xy[0]), float(direction_xy[1])
    t = math.inf
    if dx > 0:
        t = min(t, (bounds.right - x) / dx)
    elif dx < 0:
        t = min(t, (bounds.left - x) / dx)
    if dy > 0:
        t = min(t, (bounds.top - y) / dy)
    elif dy < 0:
        t = min(t, (bounds.bottom - y) / dy)
    return max(t, 0.0)


def terrain_horizon_deg(
    *, heightfield, p_W, azimuth_rad: float, step_m: float | None = None
) -> float:
    """Elevation (deg) of the terrain horizon seen from the point ``p_W`` (site frame, m)
    toward ``azimuth_rad`` (clockwise from the site's +y, grid north); -90 when the ray
    leaves the raster at once."""
    b = heightfield.bounds
    p = np.asarray(p_W, dtype=float)
    if not (b.left <= p[0] <= b.right and b.bottom <= p[1] <= b.top):
        raise OutOfRangeError(
            f"antenna at ({p[0]:.2f}, {p[1]:.2f}) m is off the site raster "
            f"x [{b.left:g}, {b.right:g}], y [{b.bottom:g}, {b.top:g}] m"
        )
    u = np.array([math.sin(azimuth_rad), math.cos(azimuth_rad)])
    step = float(step_m or heightfield.resolution_m)
    length = ray_length_m(bounds=b, p_xy=p[:2], direction_xy=u) * (1.0 - 1e-9)
    if length < step:
        return -90.0
    d = np.arange(step, length, step)
    z, ok = heightfield.heights_within(p[0] + d * u[0], p[1] + d * u[1])
    if not ok.any():
        return -90.0
    d = d[ok]
    rise = z[ok] - p[2] - d * d / (2.0 * MOON_RADIUS_M)
    return float(np.degrees(np.max(np.arctan2(rise, d))))


def earth_margin_deg(*, heightfield, p_W, earth_direction_W) -> float:
    """Elevation of the Earth's centre above the terrain horizon in its azimuth (deg),
    seen from the antenna at ``p_W`` (site frame, m); ``earth_direction_W`` is the unit
    vector to the Earth in the site frame (x grid east, y grid north, z up). Positive:
    in view."""
    e = np.asarray(earth_direction_W, dtype=float)
    n = float(np.linalg.norm(e))
    if not n > 0.0:
        raise OutOfRangeError(f"earth_direction_W = {e.tolist()!r} must be a non-zero vector")
    e = e / n
    elevation = math.degrees(math.asin(max(-1.0, min(1.0, e[2]))))
    azimuth = math.atan2(e[0], e[1])
    return elevation - terrain_horizon_deg(heightfield=heightfield, p_W=p_W, azimuth_rad=azimuth)
