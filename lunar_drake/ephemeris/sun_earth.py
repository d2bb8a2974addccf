"""Sun and Earth in the local sky of a lunar site (paper section 5: "We used ephemeris data
to accurately place the Sun and Earth in the sky for proposed mission landing dates").

Frames and units:

* ME: MOON_ME_DE421, the mean-Earth/polar-axis lunar frame of DE421 (the frame of LOLA
  maps). A site is a point of the IAU reference sphere R = 1737.4 km (Archinal et al.
  2018, Celest. Mech. Dyn. Astr. 130:22) at planetocentric latitude/longitude (east
  positive) and height above that sphere.
* ENU: the site's local East-North-Up frame. Azimuth is measured clockwise from north
  (north = 0 deg, east = 90 deg), elevation up from the local horizontal plane of the
  sphere (no terrain, no refraction: the Moon has no atmosphere).
  At a pole "north" is along the site's longitude meridian: at the south pole it points
  along meridian ``longitude_deg`` (away from the pole), at the north pole along meridian
  ``longitude_deg + 180``.
* Times: ``utc`` strings are parsed by SPICE (ISO 8601 such as ``2027-11-20T12:00:00``,
  UTC unless a zone or ``TDB`` is given); ``epoch_tdb_s`` is TDB seconds past J2000
  (SPICE "ET").

Two evaluation methods give the same numbers to about 1e-9 deg:

``method="spice"`` (default)
    ``spiceypy.spkcpo`` per epoch: observer fixed in MOON_ME_DE421 at the site, target
    SUN or EARTH, output frame MOON_ME_DE421 evaluated at the observer epoch, with the
    requested aberration correction (default ``LT+S``: one-way light time plus stellar
    aberration, reception). About 0.1 ms per epoch.
``method="fast"``
    The same DE421 Chebyshev records evaluated with numpy for all epochs at once, with
    SPICE's own ``LT`` (one Newtonian light-time iteration) and ``STELAB`` (first-order
    stellar aberration by the observer's barycentric velocity, including the site's
    rotation) algorithms reproduced. For many epochs (hourly lightmaps over a lunation,
    ...), about 5 us per epoch; abcorr ``NONE``, ``LT`` or ``LT+S``.

Earth's phase is the illuminated fraction of Earth's disk seen from the site,
``k = (1 + cos a)/2``, with ``a`` the Sun-Earth-site phase angle computed from the
(corrected) Sun and Earth vectors (the aberration it neglects is below 0.01 deg).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lunar_drake.ephemeris.kernels import (
    J2000_JD,
    MOON_ME_FRAME,
    SECONDS_PER_DAY,
    SPICE_LOCK,
    coverage_tdb_s,
    ensure_kernels,
    load_de421,
)
from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError

__all__ = [
    "ABCORRS",
    "EARTH_EQUATORIAL_RADIUS_KM",
    "MOON_RADIUS_KM",
    "SUN_RADIUS_KM",
    "EphemerisRangeError",
    "SiteLocation",
    "SunEarth",
    "enu_basis",
    "meridian_convergence_deg",
    "site_frame_rotation",
    "sun_earth_enu",
    "tdb_s_to_utc",
    "utc_to_tdb_s",
]

MOON_RADIUS_KM = 1737.4
"""IAU 2015 lunar reference sphere (km) (Archinal et al. 2018); = terrain.crs.MOON_RADIUS_M."""
SUN_RADIUS_KM = 695700.0
"""IAU 2015 nominal solar radius (km) (IAU 2015 Resolution B3; Prsa et al. 2016, AJ 152:41)."""
EARTH_EQUATORIAL_RADIUS_KM = 6378.1366
"""Earth equatorial radius (km) (IAU 2015 / IERS Conventions 2010; Archinal et al. 2018)."""
CLIGHT_KM_S = 299792.458
"""Speed of light (km/s), the value of CSPICE ``clight``."""
HEIGHT_RANGE_M = (-20000.0, 20000.0)
"""Allowed site heights above the 1737.4 km sphere (m): lunar topography spans about
-9.1 km to +10.8 km (LOLA; Smith et al. 2010, GRL 37:L18204) (from memory)."""
ABCORRS = ("NONE", "LT", "LT+S", "CN", "CN+S")
"""Aberration corrections accepted (reception only)."""
_FAST_ABCORRS = ("NONE", "LT", "LT+S")
_COVERAGE_MARGIN_S = 3600.0
"""Kept clear of the ends of the DE421 span, for light time (Sun: ~500 s) and rates."""


class EphemerisRangeError(LunarDrakeError, ValueError):
    """An epoch lies outside the span covered by the DE421 kernels."""


# ------------------------------------------------------------------------------------------
# Site


@dataclass(frozen=True)
class SiteLocation:
    """A point on the Moon.

    Attributes:
        latitude_deg: planetocentric latitude (deg), [-90, 90].
        longitude_deg: east longitude (deg), [-360, 360].
        height_m: height above the 1737.4 km reference sphere (m), [-20 km, 20 km].
    """

    latitude_deg: float
    longitude_deg: float
    height_m: float = 0.0

    def __post_init__(self):
        for name, lo, hi in (
            ("latitude_deg", -90.0, 90.0),
            ("longitude_deg", -360.0, 360.0),
            ("height_m", *HEIGHT_RANGE_M),
        ):
            v = getattr(self, name)
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise OutOfRangeError(
                    f"SiteLocation.{name} = {v!r} is not a number; allowed [{lo:g}, {hi:g}]"
                ) from None
            if not (math.isfinite(f) and lo <= f <= hi):
                raise OutOfRangeError(
                    f"SiteLocation.{name} = {v!r}; allowed a finite value in [{lo:g}, {hi:g}]"
                )
            object.__setattr__(self, name, f)

    @property
    def radius_km(self) -> float:
        """Distance of the site from the Moon's centre (km)."""
        return MOON_RADIUS_KM + self.height_m / 1000.0

    def position_me_km(self) -> np.ndarray:
        """p_MS: the site in MOON_ME_DE421 (km), shape (3,)."""
        return self.radius_km * enu_basis(self)[2]


def enu_basis(site: SiteLocation) -> np.ndarray:
    """R_EM (3, 3): rows are the site's East, North, Up unit vectors in MOON_ME_DE421.

    ``v_ENU = R_EM @ v_ME``. At a pole, North is along meridian ``site.longitude_deg``
    (see the module docstring).
    """
    lat, lon = math.radians(site.latitude_deg), math.radians(site.longitude_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array(
        [
            [-so, co, 0.0],
            [-sl * co, -sl * so, cl],
            [cl * co, cl * so, sl],
        ]
    )


def meridian_convergence_deg(
    site: SiteLocation, *, pole: str | None = None, central_meridian_deg: float = 0.0
) -> float:
    """Azimuth of grid north at ``site`` (deg, clockwise from true north).

    For a polar stereographic projection with central meridian ``lon0`` the map
    coordinates are ``x = rho sin(lon - lon0)``, ``y = rho cos(lon - lon0)`` (south pole;
    ``rho`` grows away from the pole) or ``y = -rho cos(lon - lon0)`` (north pole). True
    north is the direction of increasing latitude (+rho in the south, -rho in the north),
    true east the direction of increasing longitude, which gives

        south polar: gamma = -(lon - lon0)        north polar: gamma = +(lon - lon0)

    e.g. at lon 90 E on a south-polar map grid north (+y) points true west. The
    projection is conformal, so grid and true axes differ by this rotation only (scale
    aside). Returned in (-180, 180].

    Args:
        site: where (the site centre); only its longitude (and latitude sign) matter.
        pole: "south" or "north"; by default the hemisphere of ``site.latitude_deg``
            (latitude 0 is refused: polar grids only).
        central_meridian_deg: the projection's central meridian (deg); lunar_drake's polar
            CRSs use 0.
    """
    if pole is None:
        if site.latitude_deg == 0.0:
            raise OutOfRangeError(
                "meridian_convergence_deg: site latitude 0 is on neither polar grid; "
                "pass pole='south' or pole='north'"
            )
        pole = "south" if site.latitude_deg < 0.0 else "north"
    if pole not in ("south", "north"):
        raise ConfigError(f"pole = {pole!r}; allowed 'south' or 'north'")
    d = site.longitude_deg - float(central_meridian_deg)
    gamma = -d if pole == "south" else d
    gamma = (gamma + 180.0) % 360.0 - 180.0
    return 180.0 if gamma == -180.0 else gamma


def site_frame_rotation(
    site: SiteLocation, *, pole: str | None = None, central_meridian_deg: float = 0.0
) -> np.ndarray:
    """R_EG (3, 3): from the polar-stereographic grid frame G to true ENU E at ``site``.

    G is the frame lunar_drake's terrain calls "x east, y north, z up": x along the map's
    +x (grid east), y along +y (grid north), z the local vertical. ``v_E = R_EG @ v_G``;
    its columns are G's axes in ENU. With ``gamma`` = :func:`meridian_convergence_deg`:
    grid north = (sin gamma, cos gamma, 0), grid east = (cos gamma, -sin gamma, 0) in ENU.

    Exact at the site point; across a raster the convergence changes with longitude,
    which matters close to a pole (100 m sideways at 3 km from the pole turns true north
    by about 1.9 deg), so sky directions should be expressed in G, which is fixed.
    """
    g = math.radians(
        meridian_convergence_deg(site, pole=pole, central_meridian_deg=central_meridian_deg)
    )
    c, s = math.cos(g), math.sin(g)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------------------------------
# Time


def utc_to_tdb_s(utc: str | Sequence[str]) -> float | np.ndarray:
    """TDB seconds past J2000 of UTC string(s) (parsed by SPICE ``str2et``)."""
    import spiceypy
    from spiceypy.utils.exceptions import SpiceyError

    ensure_kernels()
    scalar = isinstance(utc, str)
    items = [utc] if scalar else list(utc)
    out = np.empty(len(items))
    with SPICE_LOCK:
        for i, s in enumerate(items):
            if not isinstance(s, str):
                raise ConfigError(
                    f"utc = {s!r} is not a string; use ISO 8601 like '2027-11-20T12:00:00'"
                )
            try:
                out[i] = spiceypy.str2et(s)
            except SpiceyError as exc:
                raise ConfigError(
                    f"utc = {s!r} is not a time SPICE can parse; use ISO 8601 like "
                    f"'2027-11-20T12:00:00' ({exc.short if hasattr(exc, 'short') else exc})"
                ) from None
    return float(out[0]) if scalar else out


def tdb_s_to_utc(epoch_tdb_s: float, *, precision: int = 3) -> str:
    """ISO 8601 UTC (``YYYY-MM-DDTHH:MM:SS.sss``) of TDB seconds past J2000."""
    import spiceypy

    ensure_kernels()
    with SPICE_LOCK:
        return spiceypy.et2utc(float(epoch_tdb_s), "ISOC", int(precision))


def _tdb_calendar(epoch_tdb_s: float) -> str:
    """``YYYY-MM-DDTHH:MM:SS TDB`` of TDB seconds past J2000."""
    import spiceypy

    with SPICE_LOCK:
        return spiceypy.timout(float(epoch_tdb_s), "YYYY-MM-DDTHR:MN:SC ::TDB") + " TDB"


def _coverage_text() -> str:
    a, b = coverage_tdb_s()
    return f"{_tdb_calendar(a)} to {_tdb_calendar(b)}"


def _check_coverage(et: np.ndarray, labels) -> None:
    a, b = coverage_tdb_s()
    lo, hi = a + _COVERAGE_MARGIN_S, b - _COVERAGE_MARGIN_S
    bad = ~((et >= lo) & (et <= hi))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        t = et[i]
        what = labels[i] if labels is not None else f"epoch_tdb_s = {float(t)!r}"
        if math.isfinite(t) and labels is None:
            what += f" ({_tdb_calendar(t)})"
        raise EphemerisRangeError(
            f"time {what} is outside the DE421 kernel coverage ({_coverage_text()}, "
            f"less {_COVERAGE_MARGIN_S:g} s at each end for light time)"
        )


# ------------------------------------------------------------------------------------------
# Results


@dataclass(frozen=True)
class SunEarth:
    """Sun and Earth seen from a site; arrays carry a leading time axis for array input.

    Attributes:
        epoch_tdb_s: observation epoch(s), TDB s past J2000.
        sun_dir_enu, earth_dir_enu: unit vectors from the site, site ENU, shape (..., 3).
        sun_distance_km, earth_distance_km: site-to-centre distances (km) (light-time
            corrected when abcorr includes LT).
        sun_azimuth_deg, earth_azimuth_deg: clockwise from north, [0, 360).
        sun_elevation_deg, earth_elevation_deg: above the local horizontal plane.
        earth_phase: illuminated fraction of Earth's disk seen from the site, [0, 1].
        earth_phase_angle_deg: Sun-Earth-site angle (deg): 0 = full Earth.
        sun_angular_radius_deg, earth_angular_radius_deg: apparent radii (deg).
    """

    epoch_tdb_s: np.ndarray | float
    sun_dir_enu: np.ndarray
    sun_distance_km: np.ndarray | float
    earth_dir_enu: np.ndarray
    earth_distance_km: np.ndarray | float
    sun_azimuth_deg: np.ndarray | float
    sun_elevation_deg: np.ndarray | float
    earth_azimuth_deg: np.ndarray | float
    earth_elevation_deg: np.ndarray | float
    earth_phase: np.ndarray | float
    earth_phase_angle_deg: np.ndarray | float
    sun_angular_radius_deg: np.ndarray | float
    earth_angular_radius_deg: np.ndarray | float


def _az_el(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    az = np.degrees(np.arctan2(v[..., 0], v[..., 1])) % 360.0
    el = np.degrees(np.arcsin(np.clip(v[..., 2], -1.0, 1.0)))
    return az, el


def _finish(et, sun_me, earth_me, site: SiteLocation, scalar: bool) -> SunEarth:
    R_EM = enu_basis(site)
    sun = sun_me @ R_EM.T
    earth = earth_me @ R_EM.T
    ds = np.linalg.norm(sun, axis=-1)
    de = np.linalg.norm(earth, axis=-1)
    su = sun / ds[..., None]
    eu = earth / de[..., None]
    sun_from_earth = sun - earth
    cos_a = np.einsum("...i,...i->...", sun_from_earth, -earth) / (
        np.linalg.norm(sun_from_earth, axis=-1) * de
    )
    cos_a = np.clip(cos_a, -1.0, 1.0)
    s_az, s_el = _az_el(su)
    e_az, e_el = _az_el(eu)
    fields = dict(
        epoch_tdb_s=et,
        sun_dir_enu=su,
        sun_distance_km=ds,
        earth_dir_enu=eu,
        earth_distance_km=de,
        sun_azimuth_deg=s_az,
        sun_elevation_deg=s_el,
        earth_azimuth_deg=e_az,
        earth_elevation_deg=e_el,
        earth_phase=0.5 * (1.0 + cos_a),
        earth_phase_angle_deg=np.degrees(np.arccos(cos_a)),
        sun_angular_radius_deg=np.degrees(np.arcsin(np.minimum(SUN_RADIUS_KM / ds, 1.0))),
        earth_angular_radius_deg=np.degrees(
            np.arcsin(np.minimum(EARTH_EQUATORIAL_RADIUS_KM / de, 1.0))
        ),
    )
    if scalar:
        fields = {k: (v[0] if v.ndim > 1 else float(v[0])) for k, v in fields.items()}
    return SunEarth(**fields)


# ------------------------------------------------------------------------------------------
# SPICE path


def _vectors_spice(et: np.ndarray, site: SiteLocation, abcorr: str):
    import spiceypy

    obs = site.position_me_km()
    sun = np.empty((et.size, 3))
    earth = np.empty((et.size, 3))
    with SPICE_LOCK:
        for i, t in enumerate(et):
            s, _ = spiceypy.spkcpo(
                "SUN", float(t), MOON_ME_FRAME, "OBSERVER", abcorr, obs, "MOON", MOON_ME_FRAME
            )
            e, _ = spiceypy.spkcpo(
                "EARTH", float(t), MOON_ME_FRAME, "OBSERVER", abcorr, obs, "MOON", MOON_ME_FRAME
            )
            sun[i] = s[:3]
            earth[i] = e[:3]
    return sun, earth


# ------------------------------------------------------------------------------------------
# numpy ("fast") path: the DE421 records evaluated directly


def _cheb(records: np.ndarray, days: float, jalpha: float, et: np.ndarray):
    """Positions and rates (per second) of Chebyshev records at TDB seconds ``et``."""
    n, _, k = records.shape
    offset = (J2000_JD - jalpha) + et / SECONDS_PER_DAY
    idx = np.clip(np.floor(offset / days).astype(np.int64), 0, n - 1)
    tau = 2.0 * (offset - idx * days) / days - 1.0
    T = np.empty((k, et.size))
    dT = np.empty((k, et.size))
    T[0], dT[0] = 1.0, 0.0
    T[1], dT[1] = tau, 1.0
    for j in range(2, k):
        T[j] = 2.0 * tau * T[j - 1] - T[j - 2]
        dT[j] = 2.0 * T[j - 1] + 2.0 * tau * dT[j - 1] - dT[j - 2]
    c = records[idx]  # (m, 3, k)
    pos = np.einsum("mck,km->mc", c, T)
    rate = np.einsum("mck,km->mc", c, dT) * (2.0 / (days * SECONDS_PER_DAY))
    return pos, rate


def _frame_rot(axis: int, a: np.ndarray) -> np.ndarray:
    """SPICE ``[a]_axis`` frame rotation matrices, shape (m, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    if axis == 1:
        rows = ((o, z, z), (z, c, s), (z, -s, c))
    elif axis == 2:
        rows = ((c, z, -s), (z, o, z), (s, z, c))
    else:
        rows = ((c, s, z), (-s, c, z), (z, z, o))
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def _frame_rot_dot(axis: int, a: np.ndarray) -> np.ndarray:
    """d[a]_axis / da, shape (m, 3, 3)."""
    c, s = np.cos(a), np.sin(a)
    z = np.zeros_like(a)
    if axis == 1:
        rows = ((z, z, z), (z, -s, c), (z, -c, -s))
    elif axis == 2:
        rows = ((-s, z, -c), (z, z, z), (c, z, -s))
    else:
        rows = ((-s, c, z), (-c, -s, z), (z, z, z))
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


_TK_ANGLES_ARCSEC = (67.92, 78.56, 0.30)
_TK_AXES = (3, 2, 1)


def _pa_to_me() -> np.ndarray:
    """R (3, 3) taking MOON_PA_DE421 vectors to MOON_ME_DE421 (frames.req TK 'ANGLES':
    ME -> PA is [a1]_ax1 [a2]_ax2 [a3]_ax3; this is its transpose)."""
    m = np.eye(3)
    for ang, ax in zip(_TK_ANGLES_ARCSEC, _TK_AXES, strict=True):
        m = m @ _frame_rot(ax, np.array([math.radians(ang / 3600.0)]))[0]
    return m.T


def _j2000_to_me(et: np.ndarray):
    """R_MJ(t) (m, 3, 3) and its time derivative (1/s)."""
    r = load_de421()
    ang, rate = _cheb(r.librations, r.days_per_record("librations"), r.jalpha, et)
    phi, theta, psi = ang.T
    dphi, dtheta, dpsi = rate.T
    A, B, C = _frame_rot(3, psi), _frame_rot(1, theta), _frame_rot(3, phi)
    dA, dB, dC = _frame_rot_dot(3, psi), _frame_rot_dot(1, theta), _frame_rot_dot(3, phi)
    R_PJ = A @ B @ C
    dR_PJ = (
        dA * dpsi[:, None, None] @ B @ C
        + A @ (dB * dtheta[:, None, None]) @ C
        + A @ B @ (dC * dphi[:, None, None])
    )
    M = _pa_to_me()
    return M @ R_PJ, M @ dR_PJ


def _ssb_states(et: np.ndarray):
    """Sun, Earth and Moon positions (km) and velocities (km/s) rel. SSB, J2000."""
    r = load_de421()
    sun = _cheb(r.sun, r.days_per_record("sun"), r.jalpha, et)
    emb = _cheb(r.earthmoon, r.days_per_record("earthmoon"), r.jalpha, et)
    moon = _cheb(r.moon, r.days_per_record("moon"), r.jalpha, et)
    fe = 1.0 / (1.0 + r.emrat)
    fm = r.emrat / (1.0 + r.emrat)
    earth = (emb[0] - fe * moon[0], emb[1] - fe * moon[1])
    luna = (emb[0] + fm * moon[0], emb[1] + fm * moon[1])
    return sun, earth, luna


def _ssb_position(target: str, et: np.ndarray) -> np.ndarray:
    """Position (km) of SUN or EARTH rel. SSB, J2000."""
    r = load_de421()
    if target == "SUN":
        return _cheb(r.sun, r.days_per_record("sun"), r.jalpha, et)[0]
    emb = _cheb(r.earthmoon, r.days_per_record("earthmoon"), r.jalpha, et)[0]
    moon = _cheb(r.moon, r.days_per_record("moon"), r.jalpha, et)[0]
    return emb - moon / (1.0 + r.emrat)


def _stelab(p: np.ndarray, v_obs: np.ndarray) -> np.ndarray:
    """SPICE STELAB, vectorized: rotate ``p`` toward ``v_obs`` by asin(|u x v/c|)."""
    u = p / np.linalg.norm(p, axis=-1, keepdims=True)
    h = np.cross(u, v_obs / CLIGHT_KM_S)
    sinphi = np.linalg.norm(h, axis=-1, keepdims=True)
    phi = np.arcsin(sinphi)
    k = np.divide(h, sinphi, out=np.zeros_like(h), where=sinphi > 0.0)
    cos, sin = np.cos(phi), np.sin(phi)
    return (
        p * cos
        + np.cross(k, p) * sin
        + k * np.einsum("...i,...i->...", k, p)[..., None] * (1 - cos)
    )


def _vectors_fast(et: np.ndarray, site: SiteLocation, abcorr: str, chunk: int = 65536):
    sun_out = np.empty((et.size, 3))
    earth_out = np.empty((et.size, 3))
    p_site = site.position_me_km()
    for s0 in range(0, et.size, chunk):
        t = et[s0 : s0 + chunk]
        sun, earth, moon = _ssb_states(t)
        R_MJ, dR_MJ = _j2000_to_me(t)
        p_obs = moon[0] + np.einsum("mji,j->mi", R_MJ, p_site)  # R_MJ^T p_site
        v_obs = moon[1] + np.einsum("mji,j->mi", dR_MJ, p_site)
        for name, geo, out in (("SUN", sun[0], sun_out), ("EARTH", earth[0], earth_out)):
            rel = geo - p_obs
            if abcorr != "NONE":
                lt = np.linalg.norm(rel, axis=-1) / CLIGHT_KM_S
                rel = _ssb_position(name, t - lt) - p_obs
                if abcorr == "LT+S":
                    rel = _stelab(rel, v_obs)
            out[s0 : s0 + chunk] = np.einsum("mij,mj->mi", R_MJ, rel)
    return sun_out, earth_out


# ------------------------------------------------------------------------------------------
# Public entry point


def sun_earth_enu(
    *,
    utc: str | Sequence[str] | None = None,
    epoch_tdb_s: float | Sequence[float] | np.ndarray | None = None,
    site: SiteLocation,
    abcorr: str = "LT+S",
    method: str = "spice",
    extra_kernels: Sequence[str] = (),
) -> SunEarth:
    """Sun and Earth seen from ``site`` at the given epoch(s).

    Give exactly one of ``utc`` (string or sequence of strings) and ``epoch_tdb_s`` (TDB
    seconds past J2000, scalar or array, flattened). Scalar input gives scalar fields and
    (3,) vectors; array input gives a leading time axis.

    Args:
        utc: UTC epoch(s), ISO 8601.
        epoch_tdb_s: TDB epoch(s), s past J2000.
        site: where the observer stands.
        abcorr: SPICE aberration correction, one of :data:`ABCORRS` ("LT+S": apparent
            directions, as an observer at the site would see them; "NONE": geometric).
        method: "spice" (per-epoch ``spkcpo``) or "fast" (vectorized numpy over the same
            DE421 records; abcorr NONE, LT or LT+S). They agree to ~1e-9 deg.
        extra_kernels: extra SPICE kernels to furnish (see ``ensure_kernels``).

    Raises:
        EphemerisRangeError: an epoch outside the kernels' coverage (it names both).
        OutOfRangeError / ConfigError: a bad site, time string, abcorr or method.
    """
    if not isinstance(site, SiteLocation):
        raise ConfigError(f"site must be a SiteLocation, got {type(site).__name__}")
    if (utc is None) == (epoch_tdb_s is None):
        raise ConfigError("give exactly one of utc= or epoch_tdb_s=")
    ab = str(abcorr).upper().replace(" ", "")
    if ab not in ABCORRS:
        raise ConfigError(f"abcorr = {abcorr!r}; allowed {', '.join(ABCORRS)}")
    if method not in ("spice", "fast"):
        raise ConfigError(f"method = {method!r}; allowed 'spice' or 'fast'")
    if method == "fast" and ab not in _FAST_ABCORRS:
        raise ConfigError(
            f"abcorr = {abcorr!r} is not available with method='fast'; allowed "
            f"{', '.join(_FAST_ABCORRS)} (or use method='spice')"
        )
    ensure_kernels(extra_kernels)
    labels = None
    if utc is not None:
        scalar = isinstance(utc, str)
        utcs = [utc] if scalar else list(utc)
        et = np.atleast_1d(np.asarray(utc_to_tdb_s(utcs), dtype=np.float64))
        labels = [f"utc = {u!r}" for u in utcs]
    else:
        arr = np.asarray(epoch_tdb_s, dtype=np.float64)
        scalar = arr.ndim == 0
        et = np.atleast_1d(arr).ravel()
    if et.size == 0:
        raise ConfigError("no epochs given (an empty sequence)")
    _check_coverage(et, labels)
    if method == "spice":
        sun_me, earth_me = _vectors_spice(et, site, ab)
    else:
        sun_me, earth_me = _vectors_fast(et, site, ab)
    return _finish(et, sun_me, earth_me, site, scalar)
