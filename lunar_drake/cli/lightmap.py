"""``lunar-drake lightmap``: bake a terrain lightmap (the visible solar disk fraction);
the arguments and the command are :mod:`lunar_drake.render.lightmap`'s."""

from __future__ import annotations

from lunar_drake.cli._common import add_subcommand


def command(args) -> int:
    from lunar_drake.render import lightmap

    return lightmap.run_cli(args)


def add_parser(sub) -> None:
    from lunar_drake.render import lightmap

    pl = add_subcommand(sub, "lightmap",
                        help="bake a terrain lightmap (visible solar disk fraction)")  # fmt: skip
    lightmap.add_arguments(pl)
    pl.set_defaults(func=command)
