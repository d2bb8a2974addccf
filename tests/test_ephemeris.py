"""Tests for lunar_drake.ephemeris (kernels, Sun/Earth core, CLI) and EphemerisSource.

The kernels are built once for this module in a temporary cache (LUNAR_DRAKE_CACHE),
about 0.8 s; the environment is restored and the kernels unloaded afterwards.
"""

from __future__ import annotations

import argparse
import json
import math
import threading

import de421
import numpy as np
import pytest
import spiceypy
from jplephem.ephem import Ephemeris
from scipy.spatial.transform import Rotation
from spiceypy.utils.exceptions import NotFoundError

from lunar_drake.ephemeris import cli as eph_cli
from lunar_drake.ephemeris import kernels
from lunar_drake.ephemeris.sun_earth import (
    EphemerisRangeError,
    SiteLocation,
    enu_basis,
    meridian_convergence_deg,
    site_frame_rotation,
    sun_earth_enu,
    utc_to_tdb_s,
)
from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError

SYNODIC_MONTH_D = 29.530589  # mean synodic month (days) (Meeus 1998, ch. 49)
EPOCH = "2027-11-20T12:00:00"


@pytest.fixture(scope="module")
def spice_cache(tmp_path_factory):
    """A fresh kernel cache for this module (built on first use by ensure_kernels)."""
    mp = pytest.MonkeyPatch()
    root = tmp_path_factory.mktemp("ld_cache")
    mp.setenv("LUNAR_DRAKE_CACHE", str(root))
    kernels.unload_kernels()
    builds0 = kernels._STATE.builds
    paths = kernels.ensure_kernels()
    assert kernels._STATE.builds == builds0 + 1
    yield root / "spice", paths
    kernels.unload_kernels()
    mp.undo()


@pytest.fixture(scope="module")
def jpl():
    return Ephemeris(de421)


def _angle_deg(u, v):
    u, v = np.asarray(u), np.asarray(v)
    return np.degrees(
        np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.einsum("...i,...i->...", u, v))
    )


def _sample_ets(start_utc: str, days: float, step_h: float) -> np.ndarray:
    return utc_to_tdb_s(start_utc) + np.arange(0.0, days * 86400.0, step_h * 3600.0)


# ---------------------------------------------------------------------------------------
# Independent reference: the DE421 records through jplephem's legacy Ephemeris, the
# libration Euler angles through scipy, the PA -> ME offset from frames.req.


def _ref_j2000_to_me(jpl, et: float) -> np.ndarray:
    phi, theta, psi = np.asarray(jpl.position("librations", J2000, et / 86400.0)).ravel()
    # Body axes in J2000 are Rz(phi) Rx(theta) Rz(psi) (active, intrinsic z-x-z).
    R_JP = Rotation.from_euler("ZXZ", [phi, theta, psi]).as_matrix()
    # frames.req: TK 'ANGLES' M = [a1]_3 [a2]_2 [a3]_1 maps ME to PA, with [a]_i the
    # frame rotation, i.e. the active rotation by -a.
    a = np.radians(np.array([67.92, 78.56, 0.30]) / 3600.0)
    M_PE = Rotation.from_euler("ZYX", -a).as_matrix()
    return M_PE.T @ R_JP.T


J2000 = 2451545.0


def _ref_geometric_me(jpl, et: float, site: SiteLocation):
    """Geometric Sun and Earth from the site in MOON_ME_DE421 (km)."""
    d = et / 86400.0
    emb = np.asarray(jpl.position("earthmoon", J2000, d)).ravel()
    moon_geo = np.asarray(jpl.position("moon", J2000, d)).ravel()
    sun = np.asarray(jpl.position("sun", J2000, d)).ravel()
    earth = emb - moon_geo / (1.0 + jpl.EMRAT)
    moon = emb + moon_geo * jpl.EMRAT / (1.0 + jpl.EMRAT)
    R = _ref_j2000_to_me(jpl, et)
    lat, lon = math.radians(site.latitude_deg), math.radians(site.longitude_deg)
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    p_site = (1737.4 + site.height_m / 1000.0) * up
    return R @ (sun - moon) - p_site, R @ (earth - moon) - p_site, up


def _ref_enu(v, up):
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    return np.array([v @ east, v @ north, v @ up])


# ---------------------------------------------------------------------------------------
# Kernels


def test_kernels_written_verified_and_cover_the_package_span(spice_cache, jpl):
    directory, paths = spice_cache
    assert [p.name for p in paths] == list(kernels.KERNEL_FILES)
    assert all(p.parent == directory.resolve() for p in paths)
    manifest = json.loads((directory / "manifest.json").read_text())
    assert set(manifest["files"]) == set(kernels.KERNEL_FILES)
    assert kernels.verify_kernels(directory)
    spk = str(directory / kernels.SPK_FILE)
    assert sorted(spiceypy.spkobj(spk)) == [3, 10, 301, 399]
    cov = spiceypy.spkcov(spk, 301)
    first, last = spiceypy.wnfetd(cov, 0)
    assert (first, last) == kernels.coverage_tdb_s()
    assert first == (jpl.jalpha - J2000) * 86400.0 and last == (jpl.jomega - J2000) * 86400.0
    assert spiceypy.gdpool("DELTET/DELTA_AT", 0, 100)[-2] == 37.0
    # 2017-01-01: TAI - UTC = 37 s, so TDB - UTC = 69.184 s (+ periodic terms < 2 ms).
    assert (
        abs(spiceypy.str2et("2020-01-01T00:00:00") - spiceypy.tparse("2020-01-01")[0] - 69.184)
        < 2e-3
    )


def test_spk_reproduces_the_de421_records_positions_and_rates(spice_cache, jpl):
    rng = np.random.default_rng(3)
    a, b = kernels.coverage_tdb_s()
    for et in rng.uniform(a + 1e5, b - 1e5, 12):
        d = et / 86400.0
        for target, obs, name, share in (
            ("SUN", "SOLAR SYSTEM BARYCENTER", "sun", 1.0),
            ("EARTH BARYCENTER", "SOLAR SYSTEM BARYCENTER", "earthmoon", 1.0),
            ("MOON", "EARTH", "moon", 1.0),
            ("EARTH", "EARTH BARYCENTER", "moon", -1.0 / (1.0 + jpl.EMRAT)),
        ):
            state, _ = spiceypy.spkezr(target, et, "J2000", "NONE", obs)
            p, v = jpl.position_and_velocity(name, J2000, d)
            p, v = share * np.asarray(p).ravel(), share * np.asarray(v).ravel() / 86400.0
            assert np.abs(state[:3] - p).max() < 1e-6 * max(1.0, np.linalg.norm(p) / 1e6)
            assert np.abs(state[3:] - v).max() < 1e-9


def test_pck_orientation_is_the_de421_librations(spice_cache, jpl):
    for utc in ("1905-03-01", "2000-01-01T12:00:00", EPOCH, "2049-07-04"):
        et = spiceypy.str2et(utc)
        phi, theta, psi = np.asarray(jpl.position("librations", J2000, et / 86400.0)).ravel()
        R_PJ = Rotation.from_euler("ZXZ", [phi, theta, psi]).as_matrix().T
        assert (
            np.abs(spiceypy.pxform("J2000", "MOON_PA_DE421", et) - R_PJ).max() < 1e-10
        )  # psi ~ 2e4 rad: ~4e-12 rounding
        assert (
            np.abs(spiceypy.pxform("J2000", "MOON_ME_DE421", et) - _ref_j2000_to_me(jpl, et)).max()
            < 1e-10
        )


def _iau_moon_j2000_to_body(et: float) -> np.ndarray:
    """IAU 2015 lunar rotation model (Archinal et al. 2018, Table 2) (from memory)."""
    d = et / 86400.0
    T = d / 36525.0
    E = np.radians(
        np.array([125.045, 250.089, 260.008, 176.625, 357.529, 311.589, 134.963, 276.617,
                  34.226, 15.134, 119.743, 239.961, 25.053])
        + d * np.array([-0.0529921, -0.1059842, 13.0120009, 13.3407154, 0.9856003,
                        26.4057084, 13.0649930, 0.3287146, 1.7484877, -0.1589763,
                        0.0036096, 0.1643573, 12.9590088])
    )  # fmt: skip
    s, c = np.sin(E), np.cos(E)
    ra = 269.9949 + 0.0031 * T + np.dot([-3.8787, -0.1204, 0.0700, -0.0172, 0, 0.0072, 0, 0, 0,
                                         -0.0052, 0, 0, 0.0043], s)  # fmt: skip
    dec = 66.5392 + 0.0130 * T + np.dot([1.5419, 0.0239, -0.0278, 0.0068, 0, -0.0029, 0.0009,
                                         0, 0, 0.0008, 0, 0, -0.0009], c)  # fmt: skip
    w = 38.3213 + 13.17635815 * d - 1.4e-12 * d * d + np.dot(
        [3.5610, 0.1208, -0.0642, 0.0158, 0.0252, -0.0066, -0.0047, -0.0046, 0.0028, 0.0052,
         0.0040, 0.0019, -0.0044], s)  # fmt: skip
    # J2000 -> body = [W]_3 [90 - dec]_1 [90 + ra]_3 (frame rotations) = active ZXZ transposed.
    return Rotation.from_euler("ZXZ", np.radians([90.0 + ra, 90.0 - dec, w])).as_matrix().T


def _rotation_angle_deg(A, B):
    M = A @ B.T
    return math.degrees(math.acos(min(1.0, (np.trace(M) - 1.0) / 2.0)))


def test_me_frame_agrees_with_the_iau_rotation_model(spice_cache):
    # The IAU model approximates the mean-Earth frame to a few thousandths of a degree;
    # the PA frame is ~0.03 deg away and a sign error in the PA -> ME offset ~0.06 deg.
    for utc in ("1950-01-01", "2000-01-01", "2010-06-01", EPOCH, "2035-03-01", "2050-01-01"):
        et = spiceypy.str2et(utc)
        iau = _iau_moon_j2000_to_body(et)
        me = _rotation_angle_deg(iau, spiceypy.pxform("J2000", "MOON_ME_DE421", et))
        pa = _rotation_angle_deg(iau, spiceypy.pxform("J2000", "MOON_PA_DE421", et))
        assert me < 0.006
        assert pa > 0.02


def test_cache_rebuilds_a_corrupt_or_missing_file(spice_cache):
    directory, _ = spice_cache
    spk = directory / kernels.SPK_FILE
    before = sun_earth_enu(utc=EPOCH, site=SiteLocation(-89.9, 0.0))
    good = spk.read_bytes()
    data = bytearray(good)
    data[len(data) // 2] ^= 0xFF
    spk.write_bytes(bytes(data))
    assert not kernels.verify_kernels(directory)
    kernels.unload_kernels()
    builds = kernels._STATE.builds
    kernels.ensure_kernels()
    assert kernels._STATE.builds == builds + 1
    assert spk.read_bytes() == good  # the build is deterministic
    (directory / kernels.PCK_FILE).unlink()
    kernels.unload_kernels()
    kernels.ensure_kernels()
    assert kernels._STATE.builds == builds + 2 and kernels.verify_kernels(directory)
    after = sun_earth_enu(utc=EPOCH, site=SiteLocation(-89.9, 0.0))
    assert np.array_equal(before.sun_dir_enu, after.sun_dir_enu)
    assert not list(directory.glob(".*.tmp-*"))


def test_extra_kernels_are_furnished_and_survive_kclear(spice_cache, tmp_path):
    extra = tmp_path / "site_topo.tf"
    extra.write_text(
        "KPL/FK\n\\begindata\n"
        "FRAME_TEST_TOPO = 1399999\nFRAME_1399999_NAME = 'TEST_TOPO'\n"
        "FRAME_1399999_CLASS = 4\nFRAME_1399999_CLASS_ID = 1399999\n"
        "FRAME_1399999_CENTER = 301\nTKFRAME_1399999_RELATIVE = 'MOON_ME_DE421'\n"
        "TKFRAME_1399999_SPEC = 'ANGLES'\nTKFRAME_1399999_UNITS = 'DEGREES'\n"
        "TKFRAME_1399999_AXES = ( 3, 2, 3 )\nTKFRAME_1399999_ANGLES = ( -30.0, -120.0, 0.0 )\n"
        "LUNAR_DRAKE_TEST_VALUE = 42\n\\begintext\n"
    )
    paths = kernels.ensure_kernels([extra])
    assert paths[-1] == extra.resolve() and paths[:4] == list(kernels._STATE.ours)
    assert spiceypy.gdpool("LUNAR_DRAKE_TEST_VALUE", 0, 1)[0] == 42.0
    et = spiceypy.str2et(EPOCH)
    R = spiceypy.pxform("MOON_ME_DE421", "TEST_TOPO", et)
    # frames.req: [a1]_ax1 [a2]_ax2 [a3]_ax3 maps TK-frame vectors to the RELATIVE frame.
    M = spiceypy.eul2m(math.radians(-30.0), math.radians(-120.0), 0.0, 3, 2, 3)
    assert np.allclose(R, np.asarray(M).T, atol=1e-14)
    assert kernels.ensure_kernels([extra]) == paths  # idempotent
    spiceypy.kclear()
    assert kernels.ensure_kernels() == paths  # ours and the extra, furnished again
    assert spiceypy.gdpool("LUNAR_DRAKE_TEST_VALUE", 0, 1)[0] == 42.0
    r = sun_earth_enu(utc=EPOCH, site=SiteLocation(-45.0, 10.0))
    assert r.sun_distance_km > 1e8
    with pytest.raises(kernels.KernelNotFoundError, match=r"nope\.bsp"):
        kernels.ensure_kernels([tmp_path / "nope.bsp"])
    kernels.unload_kernels(extras_only=True)
    assert kernels.ensure_kernels() == paths[:4]
    with pytest.raises(NotFoundError):
        spiceypy.gdpool("LUNAR_DRAKE_TEST_VALUE", 0, 1)


def test_ensure_kernels_is_thread_safe(spice_cache):
    site = SiteLocation(-89.5, 120.0)
    ets = _sample_ets(EPOCH, 2.0, 1.0)
    expected = sun_earth_enu(epoch_tdb_s=ets, site=site)
    results, errors = [], []

    def work():
        try:
            kernels.ensure_kernels()
            results.append(sun_earth_enu(epoch_tdb_s=ets, site=site).sun_dir_enu)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert all(np.array_equal(r, expected.sun_dir_enu) for r in results)


# ---------------------------------------------------------------------------------------
# Sun and Earth


@pytest.mark.parametrize(
    "site",
    [SiteLocation(-45.0, 30.0, 1000.0), SiteLocation(20.0, -100.0), SiteLocation(-85.0, 200.0)],
)
def test_geometric_directions_match_an_independent_evaluation(spice_cache, jpl, site):
    ets = _sample_ets("2010-01-01", 60.0, 97.0)
    r = sun_earth_enu(epoch_tdb_s=ets, site=site, abcorr="NONE")
    for i, et in enumerate(ets):
        sun, earth, up = _ref_geometric_me(jpl, et, site)
        s, e = _ref_enu(sun, up), _ref_enu(earth, up)
        assert _angle_deg(r.sun_dir_enu[i], s / np.linalg.norm(s)) < 1e-6
        assert _angle_deg(r.earth_dir_enu[i], e / np.linalg.norm(e)) < 1e-6
        assert abs(r.sun_distance_km[i] - np.linalg.norm(s)) < 1e-3
        assert abs(r.earth_distance_km[i] - np.linalg.norm(e)) < 1e-3


@pytest.mark.parametrize("abcorr", ["NONE", "LT", "LT+S"])
def test_fast_path_matches_spice(spice_cache, abcorr):
    site = SiteLocation(-89.7, 77.0, 300.0)
    ets = _sample_ets(EPOCH, 30.0, 5.0)
    a = sun_earth_enu(epoch_tdb_s=ets, site=site, abcorr=abcorr)
    b = sun_earth_enu(epoch_tdb_s=ets, site=site, abcorr=abcorr, method="fast")
    assert _angle_deg(a.sun_dir_enu, b.sun_dir_enu).max() < 1e-7
    assert _angle_deg(a.earth_dir_enu, b.earth_dir_enu).max() < 1e-7
    assert np.abs(a.sun_distance_km - b.sun_distance_km).max() < 1e-3
    assert np.abs(a.earth_distance_km - b.earth_distance_km).max() < 1e-3
    assert np.abs(a.earth_phase - b.earth_phase).max() < 1e-9


def test_aberration_correction_is_applied(spice_cache):
    # Stellar aberration by the Moon's ~30 km/s heliocentric motion: v/c = 20.6 arcsec.
    site = SiteLocation(-89.9, 0.0)
    ets = _sample_ets(EPOCH, 30.0, 24.0)
    geo = sun_earth_enu(epoch_tdb_s=ets, site=site, abcorr="NONE")
    app = sun_earth_enu(epoch_tdb_s=ets, site=site, abcorr="LT+S")
    d = _angle_deg(geo.sun_dir_enu, app.sun_dir_enu)
    assert 0.004 < d.min() and d.max() < 0.0075


@pytest.mark.parametrize("lat", [-90.0, -89.9])
def test_polar_sun_over_a_lunation(spice_cache, lat):
    site = SiteLocation(lat, 0.0)
    ets = _sample_ets(EPOCH, SYNODIC_MONTH_D, 6.0)
    ets = np.append(ets, ets[0] + SYNODIC_MONTH_D * 86400.0)
    r = sun_earth_enu(epoch_tdb_s=ets, site=site)
    # The lunar equator is inclined 1.54 deg to the ecliptic: the Sun grazes the horizon.
    assert np.abs(r.sun_elevation_deg).max() < 1.6 + (90.0 + lat)
    assert np.ptp(r.sun_elevation_deg) < 1.0
    az = np.degrees(np.unwrap(np.radians(r.sun_azimuth_deg)))
    # One turn per synodic month; from the south pole the Sun's azimuth decreases
    # (the subsolar longitude drifts west as the Moon turns east).
    assert abs((az[-1] - az[0]) + 360.0) < 5.0
    assert np.all(np.diff(az) < 0.0)
    rate = np.diff(az[:-1]) / 6.0  # deg/h; paper: "the sun moves slowly (~0.5 deg/hour)"
    assert np.all((-0.56 < rate) & (rate < -0.45))
    assert np.all((1.45e8 < r.sun_distance_km) & (r.sun_distance_km < 1.53e8))
    assert np.all(np.abs(r.sun_angular_radius_deg - 0.2665) < 0.006)


def test_earth_is_nearly_fixed_in_the_sky_of_a_near_side_site(spice_cache):
    site = SiteLocation(0.0, 0.0)
    r = sun_earth_enu(epoch_tdb_s=_sample_ets(EPOCH, SYNODIC_MONTH_D, 6.0), site=site)
    mean = r.earth_dir_enu.mean(axis=0)
    mean /= np.linalg.norm(mean)
    # Optical libration: <= ~7.9 deg in longitude and ~6.7 deg in latitude.
    wander = _angle_deg(r.earth_dir_enu, mean)
    assert wander.max() < 11.0 and wander.max() > 2.0
    assert r.earth_elevation_deg.min() > 78.0
    assert _angle_deg(r.sun_dir_enu[0], r.sun_dir_enu).max() > 170.0  # the Sun goes round
    assert np.all((350e3 < r.earth_distance_km) & (r.earth_distance_km < 410e3))


def test_earth_phase_is_the_complement_of_the_moon_phase(spice_cache, jpl):
    site = SiteLocation(-89.9, 0.0)
    ets = _sample_ets(EPOCH, SYNODIC_MONTH_D, 12.0)
    r = sun_earth_enu(epoch_tdb_s=ets, site=site)
    for i, et in enumerate(ets):
        d = et / 86400.0
        moon = np.asarray(jpl.position("moon", J2000, d)).ravel()
        emb = np.asarray(jpl.position("earthmoon", J2000, d)).ravel()
        sun = np.asarray(jpl.position("sun", J2000, d)).ravel() - (emb - moon / (1 + jpl.EMRAT))
        cos_m = np.dot(sun - moon, -moon) / (np.linalg.norm(sun - moon) * np.linalg.norm(moon))
        moon_phase = 0.5 * (1.0 + cos_m)
        assert abs(r.earth_phase[i] + moon_phase - 1.0) < 0.01
    assert np.ptp(r.earth_phase) > 0.95
    # New Moon 2024-01-11 11:57 UTC -> full Earth; full Moon 2024-01-25 17:54 -> new Earth.
    new = sun_earth_enu(utc="2024-01-11T11:57:00", site=site)
    full = sun_earth_enu(utc="2024-01-25T17:54:00", site=site)
    assert new.earth_phase > 0.99 and full.earth_phase < 0.01
    assert new.earth_phase_angle_deg < 12.0 and full.earth_phase_angle_deg > 168.0


def test_scalar_and_array_inputs(spice_cache):
    site = SiteLocation(-89.9, 0.0)
    one = sun_earth_enu(utc=EPOCH, site=site)
    assert one.sun_dir_enu.shape == (3,) and isinstance(one.sun_elevation_deg, float)
    et = utc_to_tdb_s(EPOCH)
    many = sun_earth_enu(epoch_tdb_s=[et, et + 3600.0], site=site)
    assert many.sun_dir_enu.shape == (2, 3) and many.sun_elevation_deg.shape == (2,)
    assert np.array_equal(many.sun_dir_enu[0], one.sun_dir_enu)
    assert np.isclose(np.linalg.norm(one.sun_dir_enu), 1.0)
    el = math.degrees(math.asin(one.sun_dir_enu[2]))
    az = math.degrees(math.atan2(one.sun_dir_enu[0], one.sun_dir_enu[1])) % 360.0
    assert math.isclose(el, one.sun_elevation_deg) and math.isclose(az, one.sun_azimuth_deg)
    # Same inputs, same bytes.
    again = sun_earth_enu(utc=EPOCH, site=site)
    assert np.array_equal(again.earth_dir_enu, one.earth_dir_enu)
    # 2100 is inside the package's span (its records run to 2200-02-01).
    assert sun_earth_enu(utc="2100-01-01", site=site).sun_distance_km > 1e8


def test_errors(spice_cache):
    site = SiteLocation(-89.9, 0.0)
    with pytest.raises(
        EphemerisRangeError, match=r"2300-01-01.*1899-12-04T00:00:00 TDB to 2200-02-01T00:00:00 TDB"
    ):
        sun_earth_enu(utc="2300-01-01", site=site)
    with pytest.raises(EphemerisRangeError, match="epoch_tdb_s"):
        sun_earth_enu(epoch_tdb_s=[0.0, -4e9], site=site)
    with pytest.raises(EphemerisRangeError):
        sun_earth_enu(epoch_tdb_s=float("nan"), site=site, method="fast")
    assert issubclass(EphemerisRangeError, LunarDrakeError) and issubclass(
        EphemerisRangeError, ValueError
    )
    for lat, lon, h in ((91.0, 0.0, 0.0), (float("nan"), 0.0, 0.0), (0.0, float("inf"), 0.0),
                        (-90.5, 0.0, 0.0), (0.0, 0.0, 1e6)):  # fmt: skip
        with pytest.raises(OutOfRangeError):
            SiteLocation(lat, lon, h)
    with pytest.raises(OutOfRangeError, match="latitude_deg = 'x'"):
        SiteLocation("x", 0.0)
    with pytest.raises(ConfigError, match="not a time"):
        sun_earth_enu(utc="yesterday-ish", site=site)
    with pytest.raises(ConfigError, match="exactly one"):
        sun_earth_enu(utc=EPOCH, epoch_tdb_s=0.0, site=site)
    with pytest.raises(ConfigError, match="abcorr"):
        sun_earth_enu(utc=EPOCH, site=site, abcorr="XLT")
    with pytest.raises(ConfigError, match=r"method=.fast."):
        sun_earth_enu(utc=EPOCH, site=site, abcorr="CN+S", method="fast")


# ---------------------------------------------------------------------------------------
# Grid frame


@pytest.mark.parametrize("lat", [-89.9, -85.0, 88.0])
@pytest.mark.parametrize("lon", [0.0, 37.0, 90.0, -135.0, 200.0])
def test_site_frame_rotation_matches_the_polar_stereographic_grid(lat, lon):
    from lunar_drake.terrain.crs import (
        lonlat_to_xy,
        moon_north_polar_stereographic,
        moon_south_polar_stereographic,
    )

    crs = moon_south_polar_stereographic() if lat < 0 else moon_north_polar_stereographic()
    site = SiteLocation(lat, lon)
    R_EG = site_frame_rotation(site)
    assert np.allclose(R_EG @ R_EG.T, np.eye(3)) and np.isclose(np.linalg.det(R_EG), 1.0)
    h = 1e-6  # deg; central differences along the meridian and the parallel
    xn, yn = lonlat_to_xy(lon, [lat + h, lat - h], crs=crs)  # true north
    xe, ye = lonlat_to_xy([lon + h, lon - h], lat, crs=crs)  # true east
    north_G = np.array([xn[0] - xn[1], yn[0] - yn[1], 0.0])
    east_G = np.array([xe[0] - xe[1], ye[0] - ye[1], 0.0])
    assert _angle_deg(R_EG @ (north_G / np.linalg.norm(north_G)), [0.0, 1.0, 0.0]) < 1e-4
    assert _angle_deg(R_EG @ (east_G / np.linalg.norm(east_G)), [1.0, 0.0, 0.0]) < 1e-4
    gamma = meridian_convergence_deg(site)
    assert math.isclose(math.cos(math.radians(gamma)), R_EG[1, 1], abs_tol=1e-12)
    assert -180.0 < gamma <= 180.0


def test_enu_basis_is_right_handed_and_defined_at_the_pole():
    for site in (SiteLocation(-90.0, 0.0), SiteLocation(-90.0, 45.0), SiteLocation(33.0, -70.0)):
        R = enu_basis(site)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    # At the south pole "north" runs along the site's meridian.
    assert np.allclose(enu_basis(SiteLocation(-90.0, 90.0))[1], [0.0, 1.0, 0.0], atol=1e-15)
    with pytest.raises(OutOfRangeError, match="latitude 0"):
        meridian_convergence_deg(SiteLocation(0.0, 10.0))


# ---------------------------------------------------------------------------------------
# Drake system and CLI


def test_ephemeris_source_holds_spice_values(spice_cache):
    from pydrake.systems.analysis import Simulator

    from lunar_drake.systems.ephemeris_source import EphemerisSource

    site = SiteLocation(-89.8, 60.0, 150.0)
    sys_enu = EphemerisSource(site=site, epoch_utc=EPOCH, update_period_s=1.0)
    names = [sys_enu.get_output_port(i).get_name() for i in range(sys_enu.num_output_ports())]
    assert names[:7] == [
        "sun_direction_W",
        "sun_distance_km",
        "earth_direction_W",
        "earth_distance_km",
        "earth_phase",
        "sun_elevation_deg",
        "sun_azimuth_deg",
    ]
    ctx = sys_enu.CreateDefaultContext()
    et0 = utc_to_tdb_s(EPOCH)
    ref0 = sun_earth_enu(epoch_tdb_s=et0, site=site)
    assert np.array_equal(sys_enu.sun_direction_output.Eval(ctx), ref0.sun_dir_enu)
    assert sys_enu.earth_phase_output.Eval(ctx)[0] == ref0.earth_phase

    sim = Simulator(sys_enu)
    sim.Initialize()
    sim.AdvanceTo(10.5)
    c = sim.get_context()
    ref10 = sun_earth_enu(epoch_tdb_s=et0 + 10.0, site=site)  # zero-order hold of t = 10
    assert np.array_equal(sys_enu.sun_direction_output.Eval(c), ref10.sun_dir_enu)
    assert np.array_equal(sys_enu.earth_direction_output.Eval(c), ref10.earth_dir_enu)
    assert sys_enu.sun_azimuth_output.Eval(c)[0] == ref10.sun_azimuth_deg
    assert sys_enu.sun_elevation_output.Eval(c)[0] == ref10.sun_elevation_deg
    assert sys_enu.sun_distance_output.Eval(c)[0] == ref10.sun_distance_km
    assert sys_enu.earth_distance_output.Eval(c)[0] == ref10.earth_distance_km
    assert not np.array_equal(ref10.sun_dir_enu, ref0.sun_dir_enu)

    sys_grid = EphemerisSource(site=site, epoch_utc=EPOCH, world_frame="polar_grid")
    g = sys_grid.sun_direction_output.Eval(sys_grid.CreateDefaultContext())
    assert np.allclose(g, site_frame_rotation(site).T @ ref0.sun_dir_enu, atol=1e-15)
    assert not np.allclose(g, ref0.sun_dir_enu, atol=1e-3)  # lon 60: they differ by 60 deg

    # Parameters move the site and epoch per context.
    ctx2 = sys_enu.CreateDefaultContext()
    sys_enu.set_site(ctx2, SiteLocation(10.0, 10.0))
    sys_enu.set_epoch_utc(ctx2, "2030-01-01T00:00:00")
    sim2 = Simulator(sys_enu, ctx2)
    sim2.Initialize()
    ref = sun_earth_enu(utc="2030-01-01T00:00:00", site=SiteLocation(10.0, 10.0))
    assert np.array_equal(
        sys_enu.earth_direction_output.Eval(sim2.get_context()), ref.earth_dir_enu
    )

    with pytest.raises(OutOfRangeError):
        EphemerisSource(site=site, epoch_utc=EPOCH, update_period_s=0.0)
    with pytest.raises(ConfigError):
        EphemerisSource(site=site, epoch_utc=EPOCH, world_frame="ned")


def test_cli_json_and_table(spice_cache, capsys):
    parser = argparse.ArgumentParser()
    eph_cli.add_arguments(parser)
    args = parser.parse_args(["--utc", EPOCH, "--lat", "-89.9", "--lon", "0", "--json"])
    assert eph_cli.run_cli(args) == 0
    out = json.loads(capsys.readouterr().out)
    ref = sun_earth_enu(utc=EPOCH, site=SiteLocation(-89.9, 0.0))
    assert set(out["sun"]) == {"azimuth_deg", "elevation_deg", "distance_km"}
    assert {"azimuth_deg", "elevation_deg", "distance_km", "phase"} <= set(out["earth"])
    assert out["sun"]["elevation_deg"] == ref.sun_elevation_deg
    assert out["earth"]["phase"] == ref.earth_phase
    args = parser.parse_args(["--utc", EPOCH, "--lat", "-89.9", "--lon", "0", "--height", "50"])
    assert eph_cli.run_cli(args) == 0
    text = capsys.readouterr().out
    assert "Sun" in text and "Earth" in text and "phase" in text
    with pytest.raises(OutOfRangeError):
        eph_cli.run_cli(parser.parse_args(["--utc", EPOCH, "--lat", "95", "--lon", "0"]))
