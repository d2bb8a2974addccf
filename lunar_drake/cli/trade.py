"""``lunar-drake trade``: a design trade study on dask.distributed (lunar_drake.trade)."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand, plural, positive_int


def _list() -> int:
    from lunar_drake.trade.study import load_study, shipped_studies

    for name, path in shipped_studies().items():
        s = load_study(path)
        first = " ".join(s.description.split()).split(". ")[0]
        first = first if len(first) <= 72 else first[:69].rsplit(" ", 1)[0] + "..."
        print(f"{name:<12} {first}  [{len(s.factors)} factors, {len(s.replicates)} replicates]")
    return 0


def command(args) -> int:
    from lunar_drake.errors import ConfigError
    from lunar_drake.trade.engine import run_study
    from lunar_drake.trade.study import load_study

    if args.list:
        return _list()
    if not args.study:
        raise ConfigError("trade needs a STUDY.yaml (or a shipped study's name: "
                          "lunar-drake trade --list)")  # fmt: skip
    if not args.out:
        raise ConfigError("trade needs --out DIR (where results.csv and report.md go)")
    study = load_study(args.study)
    try:
        run = run_study(study=study, out=Path(args.out), workers=args.workers,
                        scheduler=args.scheduler, resume=args.resume, quick=args.quick,
                        progress=not args.no_progress)  # fmt: skip
    except KeyboardInterrupt:
        print(f"Interrupted: the finished runs are kept in {Path(args.out).resolve()}; "
              "--resume runs the rest.", flush=True)  # fmt: skip
        raise
    ok = len(run.rows) - run.failed
    print(f"Study {study.name!r}: {ok} of {plural(len(run.jobs), 'run')} ok"
          + (f", {run.failed} failed (see report.md)" if run.failed else "")
          + f"; {run.ran} run now in {run.wall_s:.0f} s")  # fmt: skip
    names = ", ".join(p.name for p in run.files if p.parent == run.out)
    print(f"Outputs: {run.out.resolve()} ({names}, plots/, cases/)")
    return 0


def add_parser(sub) -> None:
    t = add_subcommand(
        sub, "trade", help="run a design trade study (factors x replicates) on dask.distributed",
        epilog="A study is a YAML file (see docs/trades.md) or a shipped study's name "
               "(--list). Every case runs simulate() and metrics.summarize; results.csv "
               "is the same bytes whatever the worker count.",
    )  # fmt: skip
    t.add_argument("study", nargs="?", help="STUDY.yaml or a shipped study's name")
    t.add_argument("--out", help="study directory (results.csv, report.md, plots/, cases/)")
    t.add_argument("--workers", type=positive_int, default=2,
                   help="local single-threaded worker processes")  # fmt: skip
    t.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing dask scheduler (tcp://HOST:PORT) instead of local "
                        "workers")  # fmt: skip
    t.add_argument("--resume", action="store_true",
                   help="continue a study in --out: run only the cases without a row")
    t.add_argument("--quick", action="store_true",
                   help="the study's reduced form (short traverses, one replicate)")
    t.add_argument("--list", action="store_true", help="list the shipped studies")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.set_defaults(func=command)
