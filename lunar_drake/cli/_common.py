"""Helpers shared by the ``lunar-drake`` subcommands: scenario arguments, positive
numbers for argparse, the help formatter."""

from __future__ import annotations

import argparse


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows each option's default ("(default: 0.1)") unless it has none to show (None,
    a flag's False) or its help already says it."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS):
            return text
        if action.default == [] or isinstance(action, argparse._HelpAction):
            return text
        return super()._get_help_string(action)


def add_subcommand(sub, name: str, **kwargs) -> argparse.ArgumentParser:
    """``sub.add_parser(name, ...)`` with :class:`HelpFormatter` and the one-line help
    as the description too."""
    kwargs.setdefault("formatter_class", HelpFormatter)
    if "help" in kwargs:
        kwargs.setdefault("description", kwargs["help"][:1].upper() + kwargs["help"][1:] + ".")
    return sub.add_parser(name, **kwargs)


def split_scenario(arg: str):
    """'default' -> (None, 'default'); 'f.yaml' -> (f.yaml, 'default'); 'f.yaml:x' -> (f, x)."""
    if arg.endswith((".yaml", ".yml")):
        return arg, "default"
    if ":" in arg and arg.split(":", 1)[0].endswith((".yaml", ".yml")):
        f, name = arg.rsplit(":", 1)
        return f, name
    return None, arg


def load_named_scenario(args):
    """The scenario of ``--scenario NAME|FILE[:NAME]`` with ``--scenario-text`` applied,
    and its name."""
    from lunar_drake.scenario_files import load_scenario

    filename, name = split_scenario(args.scenario)
    scenario = load_scenario(
        filename=filename, scenario_name=name, scenario_text=args.scenario_text
    )
    return scenario, name


def plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def positive_int(s: str) -> int:
    v = int(s)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{s!r} must be a positive integer")
    return v


def positive_float(s: str) -> float:
    v = float(s)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"{s!r} must be a positive number")
    return v
