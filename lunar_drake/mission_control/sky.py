"""The ground's prediction of the Sun and the Earth in the rover's sky: SPICE at the
site (the kernels are a pre-flight product) and the terrain horizon of the ground's own
a-priori map, at the ground's pose estimate. Nothing here reads the plant.

The ``sky.*`` points and the ``cw.earth_below_horizon`` caution come from it. It is a
prediction: the horizon is marched over the ground's map window only (a ridge beyond
it is not seen) on the orbital heights (smoothed, noisy), so it can disagree with the
plant's line of sight, which uses the true site raster; ``cw.loss_of_signal`` says what
actually happened.
"""

from __future__ import annotations

import dataclasses as dc
import math
import types

import numpy as np

from lunar_drake.errors import LunarDrakeError


@dc.dataclass(frozen=True)
class MapHeights:
    """The ground's a-priori map as the horizon march reads it (``bounds``,
    ``resolution_m``, ``heights_within``): bilinear heights inside the map, ``ok``
    False outside."""

    z: np.ndarray
    resolution_m: float
    x0_m: float
    y1_m: float

    @classmethod
    def of(cls, map_product) -> MapHeights:
        return cls(np.asarray(map_product.z, np.float64), float(map_product.resolution_m),
                   float(map_product.x0_m), float(map_product.y1_m))  # fmt: skip

    @property
    def bounds(self):
        rows, cols = self.z.shape
        return types.SimpleNamespace(left=self.x0_m, right=self.x0_m + cols * self.resolution_m,
                                     bottom=self.y1_m - rows * self.resolution_m, top=self.y1_m)

    def heights_within(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        from lunar_drake.perception.elevation_map import PriorDem

        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        b = self.bounds
        ok = (x >= b.left) & (x <= b.right) & (y >= b.bottom) & (y <= b.top)
        z = PriorDem(self.z, self.resolution_m, self.x0_m, self.y1_m).sample(x, y)
        return np.where(ok, z, -np.inf), ok


class SkyPrediction:
    """Sun and Earth elevation and azimuth (deg) at the site, and the Earth's margin over
    the map's horizon (deg) at a pose, predicted every ``period_s`` of simulation time.

    Args:
        scenario: the mission's scenario (site, epoch, kernels, the antenna's height and
            the line-of-sight margin). map_product: the ground's a-priori map.
        period_s: how often a new prediction is made (s; the sky moves ~0.5 deg an hour).
    """

    def __init__(self, *, scenario, map_product, period_s: float = 10.0):
        from lunar_drake.ephemeris.sun_earth import SiteLocation, site_frame_rotation, utc_to_tdb_s

        s = scenario.site
        self._site = SiteLocation(s.latitude_deg, s.longitude_deg)
        self._R_EG = site_frame_rotation(self._site)
        self._epoch = float(utc_to_tdb_s(s.epoch_utc))
        self._kernels = tuple(scenario.lighting.extra_kernels)
        los = scenario.comms.line_of_sight
        self._antenna_m = float(los.antenna_height_m)
        self._min_margin = float(los.min_margin_deg)
        self._heights = MapHeights.of(map_product)
        self.period_s = float(period_s)
        self._next = -math.inf

    def due(self, t_s: float) -> bool:
        """Whether a prediction is due at ``t_s`` (s)."""
        return t_s >= self._next - 1e-9

    def datums(self, t_s: float, pose) -> list:
        """The ``sky.*`` and ``cw.earth_below_horizon`` datums at ``t_s`` (s) for the
        ground's pose (x, y, ...; site m); the margin is left out off the map."""
        from lunar_drake.comms.line_of_sight import earth_margin_deg
        from lunar_drake.ephemeris.sun_earth import sun_earth_enu

        self._next = t_s + self.period_s
        t = float(t_s)
        se = sun_earth_enu(epoch_tdb_s=self._epoch + t, site=self._site,
                           extra_kernels=self._kernels)  # fmt: skip
        out = [("sky.sun_elevation", t, float(se.sun_elevation_deg)),
               ("sky.sun_azimuth", t, float(se.sun_azimuth_deg)),
               ("sky.earth_elevation", t, float(se.earth_elevation_deg)),
               ("sky.earth_azimuth", t, float(se.earth_azimuth_deg))]  # fmt: skip
        x, y = float(pose[0]), float(pose[1])
        h = self._heights
        z, ok = h.heights_within([x], [y])
        if not ok[0]:
            return out
        earth_G = self._R_EG.T @ np.asarray(se.earth_dir_enu, np.float64)
        try:
            margin = earth_margin_deg(heightfield=h, p_W=(x, y, float(z[0]) + self._antenna_m),
                                      earth_direction_W=earth_G)  # fmt: skip
        except LunarDrakeError:
            return out
        out.append(("sky.earth_margin", t, float(margin)))
        out.append(("cw.earth_below_horizon", t, int(margin <= self._min_margin)))
        return out
