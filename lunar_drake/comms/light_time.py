"""The one-way Earth-rover light time at a scenario's epoch, from the ephemeris."""

from __future__ import annotations

SPEED_OF_LIGHT_MPS = 299_792_458.0


def light_time_s(*, site, epoch_utc: str, extra_kernels=()) -> float:
    """Light time (s) from the site to the Earth's centre at ``epoch_utc``: the
    light-time-corrected distance (SPICE, ``sun_earth_enu``) over c. It changes by
    about 0.1 s over a month (lunar perigee to apogee) and by microseconds over a
    run, so a run uses the value at its epoch. ``site`` is a
    :class:`~lunar_drake.ephemeris.sun_earth.SiteLocation`."""
    from lunar_drake.ephemeris.sun_earth import sun_earth_enu

    e = sun_earth_enu(utc=epoch_utc, site=site, extra_kernels=tuple(extra_kernels))
    return float(e.earth_distance_km) * 1000.0 / SPEED_OF_LIGHT_MPS
