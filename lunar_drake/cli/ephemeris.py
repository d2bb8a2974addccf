"""``lunar-drake ephemeris``: the Sun and Earth in a lunar site's sky (SPICE); the
arguments and the command are :mod:`lunar_drake.ephemeris.cli`'s."""

from __future__ import annotations

from lunar_drake.cli._common import add_subcommand


def command(args) -> int:
    from lunar_drake.ephemeris import cli as ephemeris_cli

    return ephemeris_cli.run_cli(args)


def add_parser(sub) -> None:
    from lunar_drake.ephemeris import cli as ephemeris_cli

    pe = add_subcommand(sub, "ephemeris", help="Sun and Earth in a lunar site's sky (SPICE)")
    ephemeris_cli.add_arguments(pe)
    pe.set_defaults(func=command)
