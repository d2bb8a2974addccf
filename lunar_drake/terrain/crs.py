"""Lunar coordinate reference systems (rasterio ``CRS``) and lon/lat <-> map conversions.

The Moon is the IAU 2015 reference sphere of radius 1737.4 km (Archinal et al. 2018,
"Report of the IAU Working Group on Cartographic Coordinates and Rotational Elements:
2015", Celest. Mech. Dyn. Astr. 130:22), the sphere used by LOLA polar DEM products
and by the ``IAU_2015:30100`` family in PROJ. Longitudes are planetocentric, east
positive, degrees.

The polar CRSs are polar stereographic (variant A, true scale at the pole, i.e.
``lat_ts = lat_0 = +-90``, ``k = 1``) in metres, as used by the LOLA/LRO polar
gridded DEMs. They are written as WKT1 without an authority code so that any GDAL/PROJ
build reads them; they are equivalent to ``IAU_2015:30135`` (south) and
``IAU_2015:30130`` (north).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pyproj
from rasterio.crs import CRS

from lunar_drake.errors import CRSError

__all__ = [
    "MOON_RADIUS_M",
    "lonlat_to_xy",
    "moon_geographic",
    "moon_north_polar_stereographic",
    "moon_south_polar_stereographic",
    "require_projected_metres",
    "xy_to_lonlat",
]

MOON_RADIUS_M = 1737400.0
"""Mean lunar radius of the IAU 2015 reference sphere (m) (Archinal et al. 2018)."""

_GEOGCS = (
    'GEOGCS["Moon (2015) - Sphere / Ocentric",'
    'DATUM["Moon (2015) - Sphere",SPHEROID["Moon (2015) - Sphere",{r:.1f},0]],'
    'PRIMEM["Reference Meridian",0],'
    'UNIT["degree",0.0174532925199433]]'
)


def _polar_wkt(name: str, lat0: float) -> str:
    return (
        f'PROJCS["Moon (2015) - Sphere / Ocentric / {name}",'
        + _GEOGCS.format(r=MOON_RADIUS_M)
        + ',PROJECTION["Polar_Stereographic"],'
        f'PARAMETER["latitude_of_origin",{lat0:g}],'
        'PARAMETER["central_meridian",0],'
        'PARAMETER["scale_factor",1],'
        'PARAMETER["false_easting",0],'
        'PARAMETER["false_northing",0],'
        'UNIT["metre",1],'
        'AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
    )


def moon_geographic() -> CRS:
    """Geographic lon/lat (deg) CRS on the IAU 2015 lunar sphere (R = 1737400 m)."""
    return CRS.from_wkt(_GEOGCS.format(r=MOON_RADIUS_M))


def moon_south_polar_stereographic() -> CRS:
    """South polar stereographic on the lunar sphere, metres.

    ``+proj=stere +lat_0=-90 +lat_ts=-90 +lon_0=0 +k=1 +x_0=0 +y_0=0 +R=1737400``:
    +y points along the 0 deg meridian, +x along 90 deg E.
    """
    return CRS.from_wkt(_polar_wkt("South Polar", -90.0))


def moon_north_polar_stereographic() -> CRS:
    """North polar stereographic on the lunar sphere, metres (``lat_0 = lat_ts = +90``)."""
    return CRS.from_wkt(_polar_wkt("North Polar", 90.0))


def _as_crs(crs) -> CRS:
    if isinstance(crs, CRS):
        return crs
    if isinstance(crs, pyproj.CRS):
        return CRS.from_wkt(crs.to_wkt())
    return CRS.from_user_input(crs)


@functools.lru_cache(maxsize=32)
def _transformers(wkt: str) -> tuple[pyproj.Transformer, pyproj.Transformer]:
    proj = pyproj.CRS.from_wkt(wkt)
    geod = proj.geodetic_crs
    if geod is None:  # pragma: no cover - every projected CRS has a base geodetic CRS
        raise CRSError(f"CRS has no geodetic base CRS: {wkt!r}")
    fwd = pyproj.Transformer.from_crs(geod, proj, always_xy=True)
    inv = pyproj.Transformer.from_crs(proj, geod, always_xy=True)
    return fwd, inv


def _checked_transformers(crs) -> tuple[pyproj.Transformer, pyproj.Transformer]:
    rcrs = require_projected_metres(crs, source="lon/lat conversion")
    return _transformers(rcrs.to_wkt())


def lonlat_to_xy(lon_deg, lat_deg, *, crs) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates (m) in the projected ``crs`` of planetocentric lon/lat (deg).

    The geographic CRS is the base CRS of ``crs`` (for the lunar CRSs here, the IAU
    2015 sphere). Inputs broadcast; returns float64 arrays.
    """
    fwd, _ = _checked_transformers(crs)
    lon, lat = np.broadcast_arrays(
        np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64)
    )
    x, y = fwd.transform(lon, lat)
    return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)


def xy_to_lonlat(x, y, *, crs) -> tuple[np.ndarray, np.ndarray]:
    """Planetocentric lon/lat (deg, lon in (-180, 180]) of map coordinates (m) in ``crs``."""
    _, inv = _checked_transformers(crs)
    xx, yy = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    lon, lat = inv.transform(xx, yy)
    return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)


def require_projected_metres(crs, *, source: str) -> CRS:
    """Return ``crs`` as a rasterio ``CRS`` if it is projected with metre units.

    Args:
        crs: a rasterio/pyproj CRS, WKT, PROJ string or authority code; None is refused.
        source: what the CRS came from (usually a file path), quoted in errors.

    Raises:
        CRSError: the CRS is missing, unparsable, geographic (degrees) or not in metres.
    """
    if crs is None:
        raise CRSError(
            f"'{source}' has no coordinate reference system; a projected CRS in metres "
            "is required (e.g. lunar_drake.terrain.crs.moon_south_polar_stereographic())"
        )
    try:
        rcrs = _as_crs(crs)
    except Exception as exc:
        raise CRSError(f"'{source}' has an unreadable CRS {crs!r}: {exc}") from exc
    desc = _describe(rcrs)
    if rcrs.is_geographic or not rcrs.is_projected:
        raise CRSError(
            f"'{source}' has a geographic (angular, degree) CRS {desc}; a projected CRS "
            "in metres is required (e.g. lunar polar stereographic)"
        )
    try:
        unit, factor = rcrs.linear_units_factor
    except Exception as exc:
        raise CRSError(f"'{source}' has a CRS {desc} without linear units: {exc}") from exc
    if not math.isclose(float(factor), 1.0, rel_tol=0.0, abs_tol=1e-12):
        raise CRSError(f"'{source}' has a CRS {desc} in '{unit}' ({factor} m); metres are required")
    return rcrs


def _describe(crs: CRS) -> str:
    try:
        auth = crs.to_authority()
    except Exception:
        auth = None
    if auth:
        return f"'{auth[0]}:{auth[1]}'"
    try:
        return repr(crs.to_proj4() or crs.to_wkt())
    except Exception:
        return repr(crs.to_wkt())
