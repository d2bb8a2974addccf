"""The Sun's path over a year at a site, by azimuth sector (grid frame).

At the lunar poles the Sun circles the horizon once a lunar day and its elevation at a
given azimuth changes only with the season (the Moon's obliquity is 1.54 deg), so
whether a cell is *ever* lit, and how strongly at most, depends on the highest
elevation the Sun reaches in each direction: the *elevation envelope*. Samples of the
SPICE ephemeris (:mod:`lunar_drake.ephemeris`) every ``step_h`` over ``years`` are
binned into ``azimuth_bins`` sectors of grid azimuth; each sector keeps its highest
elevation, a few elevation quantiles (for time means) and its share of the samples.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np

from lunar_drake.science.config import SunEnvelopeConfig

#: Astronomical unit (km).
AU_KM = 149_597_870.7
#: Elevation quantiles kept per sector, for time-mean fluxes.
QUANTILES = (0.125, 0.375, 0.625, 0.875)


@dc.dataclass(frozen=True)
class SunEnvelope:
    """The Sun over the sampled span, by sector of grid azimuth.

    Attributes:
        azimuth_deg: sector centres (deg clockwise from grid north), increasing.
        width_deg: sector width (deg).
        el_max_deg: highest elevation in each sector (deg; -90 where no sample fell).
        el_levels_deg: ``(n_sectors, len(QUANTILES))`` elevation quantiles (deg).
        weight: share of all samples in each sector (sums to 1).
        distance_au: mean Sun distance of each sector's samples (au).
        samples: number of ephemeris samples.
        grid_north_deg: grid azimuth of true north at the site (deg).
    """

    azimuth_deg: np.ndarray
    width_deg: float
    el_max_deg: np.ndarray
    el_levels_deg: np.ndarray
    weight: np.ndarray
    distance_au: np.ndarray
    samples: int
    grid_north_deg: float

    @property
    def max_elevation_deg(self) -> float:
        """The highest elevation of the Sun over the span (deg)."""
        return float(self.el_max_deg.max())


def envelope_from_samples(
    az_deg, el_deg, distance_km, *, bins: int, grid_north_deg: float = 0.0
) -> SunEnvelope:
    """Bins Sun samples (ENU azimuth, elevation in deg; distance in km) into ``bins``
    sectors of grid azimuth (the ENU azimuth plus ``grid_north_deg``)."""
    az = (np.asarray(az_deg, np.float64).ravel() + grid_north_deg) % 360.0
    el = np.asarray(el_deg, np.float64).ravel()
    d = np.asarray(distance_km, np.float64).ravel() / AU_KM
    width = 360.0 / bins
    k = np.floor(az / width).astype(np.int64) % bins
    el_max = np.full(bins, -90.0)
    levels = np.full((bins, len(QUANTILES)), -90.0)
    weight = np.zeros(bins)
    dist = np.ones(bins)
    for b in range(bins):
        sel = k == b
        if not sel.any():
            continue
        e = el[sel]
        el_max[b] = e.max()
        levels[b] = np.quantile(e, QUANTILES)
        weight[b] = sel.sum() / el.size
        dist[b] = d[sel].mean()
    return SunEnvelope(
        azimuth_deg=(np.arange(bins) + 0.5) * width,
        width_deg=width,
        el_max_deg=el_max,
        el_levels_deg=levels,
        weight=weight,
        distance_au=dist,
        samples=int(el.size),
        grid_north_deg=float(grid_north_deg),
    )


def sun_envelope(hf, *, utc: str, config: SunEnvelopeConfig | None = None) -> SunEnvelope:
    """The Sun's envelope at the centre of heightfield ``hf`` over ``config.years`` from
    ``utc`` (SPICE, ``method="fast"``)."""
    from lunar_drake.ephemeris.sun_earth import (
        EphemerisRangeError,
        SiteLocation,
        enu_basis,
        sun_earth_enu,
        utc_to_tdb_s,
    )
    from lunar_drake.render.lightmap import site_and_grid_north

    cfg = config or SunEnvelopeConfig()
    cfg.validate()
    site, beta = site_and_grid_north(hf, enu_basis=enu_basis, SiteLocation=SiteLocation)
    t0 = float(utc_to_tdb_s(utc))
    span = cfg.years * 365.25 * 86400.0
    n = max(2, math.ceil(span / (cfg.step_h * 3600.0)))
    t = t0 + np.arange(n) * (cfg.step_h * 3600.0)
    try:
        se = sun_earth_enu(epoch_tdb_s=t, site=site, method="fast")
    except EphemerisRangeError as exc:
        raise EphemerisRangeError(
            f"the Sun's envelope samples {cfg.years:g} year(s) from {utc!r}, which runs past "
            f"the ephemeris: {exc}"
        ) from None
    return envelope_from_samples(
        se.sun_azimuth_deg,
        se.sun_elevation_deg,
        se.sun_distance_km,
        bins=cfg.azimuth_bins,
        grid_north_deg=beta,
    )


__all__ = ["AU_KM", "QUANTILES", "SunEnvelope", "envelope_from_samples", "sun_envelope"]
