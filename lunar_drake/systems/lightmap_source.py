"""LightmapSource: baked terrain lightmaps over the mission, interpolated at sim time."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from lunar_drake.render.shading import RasterSampler


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


class LightmapSource(LeafSystem):
    """Outputs the terrain's lit fraction at the current time as a callable raster.

    .. pydrake_system::

        name: LightmapSource
        output_ports:
        - lightmap

    The lightmaps (fraction of the solar disk visible from every cell, with penumbra and
    terrain horizons; :mod:`lunar_drake.render.lightmap`) are baked at construction at
    ``interval_s`` spacing over ``[0, duration_s]`` (at least the two ends) and
    interpolated linearly in time -- the paper's hourly-lightmap plan. The output is a
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
        from lunar_drake.render.lightmap import lightmap_series

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
        lut = {float(t): (float(a), float(e)) for t, a, e in zip(times, az, el, strict=True)}
        self.series = lightmap_series(
            np.asarray(z, np.float32),
            times=times,
            sun_az_el_at=lambda t: lut[float(t)],
            resolution_m=res,
            progress=progress,
        )
        self._hf = heightfield
        self.lightmap_output = self.DeclareAbstractOutputPort(
            "lightmap",
            lambda: AbstractValue.Make(object()),
            self._calc,
            prerequisites_of_calc={self.time_ticket()},
        )

    def _calc(self, context, output):
        lm = self.series.at(context.get_time())
        output.set_value(RasterSampler.on_heightfield(lm, self._hf, outside=1.0))
