"""``lunar-drake slip-fit``: soil phi and K fitted to measured slip vs slope."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand


def command(args) -> int:
    from lunar_drake.studies.slip_fit import describe, run_slip_fit

    print(f"Fitting phi and K to {args.data} ({args.rover} rover)...", flush=True)
    fit = run_slip_fit(
        data_path=args.data, rover=args.rover, out_dir=args.out, base_soil=args.base_soil
    )
    for line in describe(fit):
        print(line)
    print(f"Outputs: {Path(args.out).resolve()} (soil.yaml, fit.csv, fit.png)")
    return 0


def add_parser(sub) -> None:
    sf = add_subcommand(
        sub, "slip-fit", help="fit soil phi and K to measured slip vs slope (Wong-Reece reference)"
    )
    sf.add_argument("data", help="CSV with columns slope_deg,slip (slip a fraction)")
    sf.add_argument("--rover", choices=["skid", "explicit"], default="explicit")
    sf.add_argument(
        "--base-soil",
        default="lunar_regolith",
        help="soil whose other parameters are kept: lunar_regolith, grc1, jsc1a or a YAML file",
    )
    sf.add_argument("--out", required=True, help="output directory (soil.yaml, fit.csv, fit.png)")
    sf.set_defaults(func=command)
