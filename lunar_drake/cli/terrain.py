"""``lunar-drake terrain synth``: synthesize a site (paper section 4)."""

from __future__ import annotations

import time
from pathlib import Path

from lunar_drake.cli._common import add_subcommand, positive_float, positive_int
from lunar_drake.errors import ConfigError


def command(args) -> int:
    from lunar_drake.terrain.sfd import CraterSFD
    from lunar_drake.terrain.synth import SynthConfig, synthesize_site

    if args.from_dem and not Path(args.from_dem).exists():
        from lunar_drake.errors import RasterNotFoundError

        raise RasterNotFoundError(f"--from-dem {args.from_dem!r} does not exist")
    if args.sfd == "powerlaw":
        sfd = CraterSFD(
            law="powerlaw", coefficient=args.powerlaw_coefficient, exponent=args.powerlaw_exponent
        )
    else:
        sfd = CraterSFD(law=args.sfd)
    if args.from_dem is None and args.size % args.factor:
        raise ConfigError(f"--size {args.size} must be a multiple of --factor {args.factor}")
    config = SynthConfig(
        size_px=args.size,
        resolution_m=args.resolution,
        factor=args.factor,
        seed=args.seed,
        crater_sfd=sfd,
        min_crater_m=args.min_crater_m,
        max_crater_m=args.max_crater_m,
        rock_abundance=args.rock_abundance,
        ejecta_rock_abundance=args.ejecta_rock_abundance,
        min_rock_m=args.min_rock_m,
        from_dem=args.from_dem,
        center_lat_deg=args.lat,
        center_lon_deg=args.lon,
        tile_px=args.tile,
        workers=args.workers,
    )
    t0 = time.perf_counter()
    products = synthesize_site(config=config, out_dir=args.out, progress=not args.no_progress)
    st = products.stats
    print(
        f"Site {st['size_px'][0]}x{st['size_px'][1]} px at {st['resolution_m']:g} m: "
        f"{st['craters']} craters, {st['rocks']} rocks ({st['ejecta_rocks']} ejecta), "
        f"z {st['z_min_m']:.2f}..{st['z_max_m']:.2f} m, {time.perf_counter() - t0:.1f} s"
    )
    print(f"Outputs: {Path(args.out).resolve()}")
    return 0


def add_parser(sub) -> None:
    t = add_subcommand(sub, "terrain", help="terrain tools: synth (synthesize a site)")
    tsub = t.add_subparsers(dest="terrain_command", required=True)
    s = add_subcommand(tsub, "synth", help="synthesize a site (paper section 4)")
    s.add_argument("--size", type=positive_int, default=1024, help="pixels a side")
    s.add_argument("--resolution", type=positive_float, default=0.1, help="metres per pixel")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--tile", type=positive_int, default=1024, help="tile side (px)")
    s.add_argument("--workers", type=positive_int, default=2, help="worker threads")
    s.add_argument(
        "--factor", type=positive_int, default=32, help="fractal upscaling factor (power of two)"
    )
    s.add_argument("--min-crater-m", type=positive_float, default=0.5)
    s.add_argument("--max-crater-m", type=positive_float, default=None)
    s.add_argument("--sfd", choices=["trask", "viper", "powerlaw"], default="trask")
    s.add_argument(
        "--powerlaw-coefficient",
        type=positive_float,
        default=0.08,
        help="c in N(>=D) = c D^e per m^2 (with --sfd powerlaw)",
    )
    s.add_argument(
        "--powerlaw-exponent",
        type=float,
        default=-2.0,
        help="e in N(>=D) = c D^e per m^2 (with --sfd powerlaw)",
    )
    s.add_argument(
        "--rock-abundance",
        type=float,
        default=0.005,
        help="Golombek-Rapp cumulative fractional area k, in [0, 1)",
    )
    s.add_argument(
        "--ejecta-rock-abundance",
        type=float,
        default=0.05,
        help="Golombek-Rapp k of ejecta rocks on a fresh crater rim, in [0, 1)",
    )
    s.add_argument("--min-rock-m", type=positive_float, default=0.1)
    s.add_argument("--lat", type=float, default=-90.0, help="site centre latitude (deg)")
    s.add_argument("--lon", type=float, default=0.0, help="site centre longitude (deg east)")
    s.add_argument("--from-dem", default=None, help="upscale this GeoTIFF DEM by --factor")
    s.add_argument("--no-progress", action="store_true")
    s.set_defaults(func=command)
