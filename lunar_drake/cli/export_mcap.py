"""``lunar-drake export-mcap RUN``: a run directory as ``run.mcap`` for Foxglove."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand


def command(args) -> int:
    from lunar_drake.files import check_output_file
    from lunar_drake.mission_control.recording import check_run_dir, write_run_mcap

    run_dir = check_run_dir(args.run)
    out = Path(args.out) if args.out else run_dir / "run.mcap"
    check_output_file(out, what="MCAP file")
    path = write_run_mcap(run_dir, out=out)
    print(f"Wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it in Foxglove "
          "(File > Open local file).")  # fmt: skip
    return 0


def add_parser(sub) -> None:
    r = add_subcommand(sub, "export-mcap", help="write a run directory's run.mcap for Foxglove",
                       epilog="New runs write run.mcap themselves; this converts older ones.")
    r.add_argument("run", help="a run directory (lunar-drake run --out DIR)")
    r.add_argument("--out", default=None, help="output file (default: RUN/run.mcap)")
    r.set_defaults(func=command)
