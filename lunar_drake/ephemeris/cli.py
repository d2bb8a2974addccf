"""``lunar-drake ephemeris``: where the Sun and Earth are in a site's sky at a UTC time.

Wired in by :mod:`lunar_drake.cli.ephemeris`.

Errors are raised as LunarDrakeError subclasses (``main`` turns them into exit code 2).
"""

from __future__ import annotations

import argparse
import json
import sys

from lunar_drake.ephemeris.sun_earth import ABCORRS, SiteLocation, sun_earth_enu


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Adds ``--utc --lat --lon [--height] [--abcorr] [--kernel ...] [--json]``."""
    parser.add_argument("--utc", required=True, help="UTC time, ISO 8601 (2027-11-20T12:00:00)")
    parser.add_argument("--lat", type=float, required=True, help="site latitude (deg)")
    parser.add_argument("--lon", type=float, required=True, help="site east longitude (deg)")
    parser.add_argument(
        "--height", type=float, default=0.0, help="height above the 1737.4 km sphere (m)"
    )
    parser.add_argument(
        "--abcorr",
        default="LT+S",
        choices=ABCORRS,
        help="SPICE aberration correction (default LT+S: apparent directions)",
    )
    parser.add_argument(
        "--kernel",
        action="append",
        default=[],
        metavar="PATH",
        help="extra SPICE kernel to furnish after the project's (repeatable)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def ephemeris_dict(*, utc: str, site: SiteLocation, abcorr: str = "LT+S", extra_kernels=()):
    """The JSON-ready result printed by ``lunar-drake ephemeris --json``."""
    r = sun_earth_enu(utc=utc, site=site, abcorr=abcorr, extra_kernels=extra_kernels)
    return {
        "utc": utc,
        "epoch_tdb_s": r.epoch_tdb_s,
        "site": {
            "latitude_deg": site.latitude_deg,
            "longitude_deg": site.longitude_deg,
            "height_m": site.height_m,
        },
        "abcorr": abcorr,
        "sun": {
            "azimuth_deg": r.sun_azimuth_deg,
            "elevation_deg": r.sun_elevation_deg,
            "distance_km": r.sun_distance_km,
        },
        "earth": {
            "azimuth_deg": r.earth_azimuth_deg,
            "elevation_deg": r.earth_elevation_deg,
            "distance_km": r.earth_distance_km,
            "phase": r.earth_phase,
            "phase_angle_deg": r.earth_phase_angle_deg,
        },
    }


def run_cli(args: argparse.Namespace) -> int:
    """Runs the command; returns the exit status (0)."""
    site = SiteLocation(args.lat, args.lon, args.height)
    d = ephemeris_dict(utc=args.utc, site=site, abcorr=args.abcorr, extra_kernels=args.kernel)
    if args.json:
        json.dump(d, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 0
    s, e = d["sun"], d["earth"]
    print(
        f"{args.utc} UTC at lat {site.latitude_deg:.4f} deg, lon {site.longitude_deg:.4f} deg, "
        f"height {site.height_m:g} m ({args.abcorr}; azimuth clockwise from north)"
    )
    print(f"{'':6s} {'azimuth':>9s} {'elevation':>10s} {'distance':>13s}")
    print(f"{'':6s} {'(deg)':>9s} {'(deg)':>10s} {'(km)':>13s}")
    print(f"{'Sun':6s} {s['azimuth_deg']:9.3f} {s['elevation_deg']:10.3f} {s['distance_km']:13.1f}")
    print(
        f"{'Earth':6s} {e['azimuth_deg']:9.3f} {e['elevation_deg']:10.3f} "
        f"{e['distance_km']:13.1f}  phase {e['phase']:.3f} "
        f"(Sun-Earth-site angle {e['phase_angle_deg']:.1f} deg)"
    )
    return 0
