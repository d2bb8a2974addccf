"""``lunar-drake world build``: every layer of a site's science world model."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand, positive_int
from lunar_drake.errors import ConfigError, LunarDrakeError


def command(args) -> int:
    from lunar_drake.science.config import WorldConfig
    from lunar_drake.science.world import build_world

    config = WorldConfig()
    where = "the default world configuration"
    if args.config:
        import yaml
        from pydrake.common.yaml import yaml_load_typed

        if not Path(args.config).is_file():
            raise ConfigError(f"--config {args.config!r} does not exist")
        where = f"--config {args.config!r}"
        try:
            raw = yaml.safe_load(Path(args.config).read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            what = getattr(exc, "problem", None) or type(exc).__name__
            mark = getattr(exc, "problem_mark", None)
            at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            raise ConfigError(f"{where} is not valid YAML: {what}{at}") from None
        if raw is not None and not isinstance(raw, dict):
            raise ConfigError(
                f"{where} holds a {type(raw).__name__}; it must be a mapping of sections "
                "(the shape of world.json's 'config')"
            )
        if raw:  # an empty file: the defaults
            from lunar_drake.scenario_files import check_yaml_schema

            check_yaml_schema(Path(args.config).read_text(), WorldConfig, source=where)
            try:
                config = yaml_load_typed(schema=WorldConfig, filename=args.config)
            except Exception as exc:  # Drake raises RuntimeError/TypeError on a bad value
                raise ConfigError(f"{where}: {str(exc).splitlines()[0]}") from None
    if args.workers is not None:
        config.workers = args.workers
        where = f"{where} with --workers {args.workers}" if args.config else "--workers"
    try:
        config.validate()
    except LunarDrakeError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    if args.seed is not None and not 0 <= args.seed < 2**63:
        raise ConfigError(f"--seed {args.seed} is out of range; allowed [0, 2^63 - 1]")
    if args.utc is not None and not args.utc.strip():
        raise ConfigError("--utc '' is empty; give a UTC time such as 2027-11-15T00:00:00")
    from lunar_drake.files import check_replaceable, staged_directory
    from lunar_drake.science.world import WORLD_FILES

    # Built whole under a temporary name; an earlier world there is replaced only when
    # this one is complete, and a directory holding anything else is refused.
    check_replaceable(args.out, allowed=WORLD_FILES, what="world directory")
    with staged_directory(args.out, what="world directory") as tmp:
        doc = build_world(site_dir=args.site_dir, out_dir=tmp, utc=args.utc, config=config,
                          seed=args.seed, progress=not args.no_progress)  # fmt: skip
    layers = doc["layers"]
    print(
        f"World model of {args.site_dir} at {doc['utc']} ({doc['shape'][0]} x {doc['shape'][1]} "
        f"px, {doc['seconds']:.1f} s): permanent shadow {100 * doc['psr_fraction']:.2f} % "
        f"(Sun up to {doc['sun_envelope']['max_elevation_deg']:.2f} deg over the year); "
        f"temperature {layers['temperature_K']['min']:.0f}-{layers['temperature_K']['max']:.0f}"
        f" K; ice up to {layers['ice_wt_pct']['max']:.2f} wt%"
    )
    print(f"Outputs: {Path(args.out).resolve()} (<layer>.tif, <layer>.png, world.json)")
    return 0


def add_parser(sub) -> None:
    w = add_subcommand(sub, "world", help="the science world model of a site: build")
    wsub = w.add_subparsers(dest="world_command", required=True)
    wb = add_subcommand(wsub, "build", help="build every layer of a site's world model")
    wb.add_argument("site_dir", help="a site directory (from 'terrain synth')")
    wb.add_argument("--out", required=True, help="output directory")
    wb.add_argument("--utc", default=None,
                    help="epoch of the temperature and OH layers (default: the default "
                         "scenario's)")  # fmt: skip
    wb.add_argument("--config", default=None,
                    help="a WorldConfig YAML file (shaped as world.json's 'config')")  # fmt: skip
    wb.add_argument(
        "--seed",
        type=int,
        default=None,
        help="noise seed (default: the site.json's; 0 without one)",
    )
    wb.add_argument("--workers", type=positive_int, default=None,
                    help="threads (default: the config's, 2)")  # fmt: skip
    wb.add_argument("--no-progress", action="store_true")
    wb.set_defaults(func=command)
