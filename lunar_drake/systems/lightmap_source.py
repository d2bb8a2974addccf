"""LightmapSource: baked terrain lightmaps over the mission, interpolated at sim time."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue

from lunar_drake.render.shading import RasterSampler
from lunar_drake.systems.leaf import Leaf


def sun_grid_az_el(*, site, epoch_utc: str, times_s, extra_kernels=()):
    """Sun azimuth (deg, clockwise from grid north) and elevation (deg) in the site's
    grid frame at sim times ``times_s`` after ``epoch_utc``."""
    from lunar_drake.ephemeris.sun_earth import site_frame_rotation, sun_earth_enu, utc_to_tdb_s

    t0 = float(utc_to_tdb_s(epoch_utc))
    se = sun_earth_enu(
        epoch_tdb_s=t0 + np.asarray(times_s, float), site=site, extra_kernels=tuple(extra_kernels)
    )
    R_EG = site_frame_rotation(site)
    d = np.atleast_2d(se.sun_dir_enu) @ R_EG  # rows: grid-frame vectors (R_GE = R_EG^T)
    az = np.degrees(np.arctan2(d[:, 0], d[:, 1])) % 360.0
    el = np.degrees(np.arcsin(np.clip(d[:, 2], -1.0, 1.0)))
    return az, el


class LightmapSource(Leaf):
    """Outputs the terrain's lit fraction at the current time as a callable raster.

    .. pydrake_system::

        name: LightmapSource
        output_ports:
        - lightmap

    The lightmaps (fraction of the solar disk visible from every cell, with penumbra and
    terrain horizons; :mod:`lunar_drake.render.lightmap`) are tabulated at
    ``interval_s`` spacing over ``[0, duration_s]`` (at least the two ends), baked on
    first use (a few kept in memory) and interpolated linearly in time -- the paper's
    hourly-lightmap plan. The output is a
    :class:`~lunar_drake.render.shading.RasterSampler` over the site ``(x, y) -> [0, 1]``.

    Args:
        heightfield: the site terrain (baked on a copy decimated to ``max_px`` a side).
        site: SiteLocation; epoch_utc: sim time 0. duration_s, interval_s: bake times.
    """

    def __init__(
        self,
        *,
        heightfield,
        site,
        epoch_utc: str,
        duration_s: float,
        interval_s: float = 3600.0,
        max_px: int = 2048,
        extra_kernels=(),
        progress: bool = False,
    ):
        super().__init__()
        z, res = heightfield.decimated(max_size=max_px)
        n = max(2, math.ceil(duration_s / interval_s) + 1)
        times = (
            np.linspace(0.0, max(duration_s, 1.0), n)
            if n == 2
            else np.arange(n) * float(interval_s)
        )
        az, el = sun_grid_az_el(
            site=site, epoch_utc=epoch_utc, times_s=times, extra_kernels=extra_kernels
        )
        self.times_s = tuple(float(t) for t in times)
        self.sun_az_el_deg = tuple((float(a), float(e)) for a, e in zip(az, el, strict=True))
        self._z = np.asarray(z, np.float32)
        self._res = float(res)
        self._hf = heightfield
        self._progress = progress
        self._maps: dict[int, np.ndarray] = {}  # a bounded cache of baked maps
        self._bake(0)  # bake the first map now, so a bad DEM fails at build time
        self.lightmap_output = self.DeclareAbstractOutputPort(
            "lightmap",
            lambda: AbstractValue.Make(object()),
            self._calc,
            prerequisites_of_calc={self.time_ticket()},
        )

    def _bake(self, k: int) -> np.ndarray:
        """Map k, baked on first use; only the most recent few are kept (memory stays
        bounded over a lunar-day run). Baking is deterministic, so a re-bake is
        bit-identical."""
        if k not in self._maps:
            from lunar_drake.render.lightmap import lightmap

            a, e = self.sun_az_el_deg[k]
            self._maps[k] = lightmap(
                self._z,
                sun_azimuth_deg=a,
                sun_elevation_deg=e,
                resolution_m=self._res,
                progress=self._progress,
            )
            while len(self._maps) > 3:
                self._maps.pop(max(self._maps, key=lambda j: abs(j - k)))
        return self._maps[k]

    def lightmap_at(self, t: float) -> np.ndarray:
        """Lit fraction at sim time ``t`` (s): linear between the bracketing baked maps."""
        ts = self.times_s
        if not ts[0] <= t <= ts[-1]:
            from lunar_drake.errors import OutOfRangeError

            raise OutOfRangeError(
                f"t = {t:g} s is outside the baked lightmaps' times [{ts[0]:g}, {ts[-1]:g}] s; "
                "they cover the scenario's simulation_duration (simulate no further, or "
                "set it longer)"
            )
        k = min(int(np.searchsorted(ts, t, side="right")) - 1, len(ts) - 2)
        f = (t - ts[k]) / (ts[k + 1] - ts[k])
        a, b = self._bake(k), self._bake(k + 1)
        out = np.subtract(b, a, dtype=np.float32)  # a + f (b - a), float32, in place
        out *= np.float32(f)
        out += a
        return out

    def _calc(self, context, output):
        lm = self.lightmap_at(context.get_time())
        output.set_value(RasterSampler.on_heightfield(lm, self._hf, outside=1.0))
