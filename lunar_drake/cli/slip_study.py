"""``lunar-drake slip-study``: slip vs slope on planar ramps (paper Figs. 22-24)."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand, positive_float, positive_int


def command(args) -> int:
    from lunar_drake.studies.slip_study import parse_slopes, run_slip_study, summarize

    slopes = parse_slopes(args.slopes)
    rovers = [r.strip() for r in args.rover.split(",")]
    data = None
    if args.data is not None:
        from lunar_drake.studies.slip_fit import read_slip_data

        d = read_slip_data(args.data)
        data = (d.slope_deg, d.slip)
    rows = run_slip_study(
        rovers=rovers,
        slopes_deg=slopes,
        distance_m=args.distance,
        seeds=args.seeds,
        out_dir=args.out,
        soil=args.soil,
        speed_mps=args.speed,
        roughness_m=args.roughness,
        data=data,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.no_progress,
    )
    print(
        f"{'rover':<9} {'slope':>6} {'mean slip':>10} {'std':>7} {'min':>7} {'max':>7} "
        f"{'reference':>10}"
    )
    for r in summarize(rows):
        ref = "cannot climb" if r["immobilized"] else f"{100 * r['reference']:>9.2f}%"
        print(
            f"{r['rover']:<9} {r['slope_deg']:>6.1f} {100 * r['mean']:>9.2f}% "
            f"{100 * r['std']:>6.2f}% {100 * r['min']:>6.2f}% {100 * r['max']:>6.2f}% {ref:>10}"
        )
    print(f"Outputs: {Path(args.out).resolve()} (slip.csv, slip.png, params.json)")
    return 0


def add_parser(sub) -> None:
    ss = add_subcommand(sub, "slip-study", help="slip vs slope on planar ramps (paper Figs. 22-24)")
    ss.add_argument(
        "--rover", default="explicit", help="skid, explicit, or a comma list (e.g. skid,explicit)"
    )
    ss.add_argument("--slopes", default="0:20:5", help="A:B:STEP in degrees, or a comma list")
    ss.add_argument("--distance", type=positive_float, default=5.0, help="metres upslope")
    ss.add_argument("--seeds", type=positive_int, default=3)
    ss.add_argument(
        "--soil",
        default="lunar_regolith",
        help="a soil preset (lunar_regolith, grc1, jsc1a) or a soil YAML (e.g. slip-fit's)",
    )
    ss.add_argument(
        "--roughness",
        type=float,
        default=0.0,
        metavar="RMS_M",
        help="seeded fractal ramp roughness: RMS height deviation at 1 m (m; 0 = planar)",
    )
    ss.add_argument(
        "--data", default=None, help="measured slope_deg,slip CSV to draw on slip.png (optional)"
    )
    ss.add_argument("--speed", type=positive_float, default=0.1, help="commanded m/s")
    ss.add_argument("--workers", type=positive_int, default=1,
                    help="parallel processes (dask.distributed, as lunar-drake trade)")
    ss.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="an existing dask scheduler (tcp://HOST:PORT) for the cases")
    ss.add_argument("--out", required=True)
    ss.add_argument("--no-progress", action="store_true")
    ss.set_defaults(func=command)
