"""The ``lunar-drake`` command: one module per subcommand (``run``, ``serve``,
``export-mcap``, ``scenarios``,
``terrain synth``, ``plan``, ``world build``, ``render``, ``trade``, ``slip-study``,
``vo-study``,
``slip-fit``, ``ephemeris``, ``lightmap``), each with ``add_parser(sub)`` and
``command(args) -> int``; :func:`main` runs one and turns a
:class:`~lunar_drake.errors.LunarDrakeError` into one line and exit status 2.
"""

from __future__ import annotations

import argparse
import os
import sys

from lunar_drake.errors import LunarDrakeError

#: The subcommand modules, in the order ``lunar-drake --help`` lists them.
COMMANDS = ("run", "serve", "export_mcap", "scenarios", "plan", "render", "terrain", "world",
            "trade", "slip_study", "vo_study", "slip_fit", "ephemeris", "lightmap")  # fmt: skip

DESCRIPTION = """\
lunar_drake: a Lunar rover mission simulator on Drake (synthetic polar terrain, a
Hapke-lit stereo camera, a slip-aware rover, flight and ground software split by a
delayed link, science instruments on a world model).

Start with:
  lunar-drake scenarios                  the shipped missions, one line each
  lunar-drake run --scenario goto        a first look: one goal on a small site, a minute
                                         or two on 2 cores
  lunar-drake run                        the default mission (minutes; ~240 MB with
                                         its frames and Meshcat replay)
  lunar-drake run --scenario goto --serve
                                         a live mission: open the printed URL (Open
                                         MCT) and drive the rover from the map
  lunar-drake <command> --help           the options of one command
"""


def build_parser() -> argparse.ArgumentParser:
    import importlib

    p = argparse.ArgumentParser(
        prog="lunar-drake",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", title="commands")
    for name in COMMANDS:
        importlib.import_module(f"lunar_drake.cli.{name}").add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    """Runs one command; returns the exit status (0, 2 for bad input, 130 interrupted,
    143 terminated: under :func:`run`, SIGTERM is taken as Ctrl-C is, partial outputs
    removed)."""
    from lunar_drake import interrupts

    parser = build_parser()
    args = parser.parse_args(argv)
    sigint = interrupts.LatchedSigint()
    hook = sys.unraisablehook
    sys.unraisablehook = _quiet_interrupts(hook)
    try:
        return args.func(args)
    except LunarDrakeError as exc:
        if interrupts.requested():  # Ctrl-C that a library turned into another error
            return _interrupted(interrupts.terminated())
        print(f"lunar-drake: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return _interrupted(interrupts.terminated())
    except Exception:
        # Ctrl-C during an import (pydrake's, Open3D's) surfaces as another error
        # ("ImportError: initialization failed"): it was the interrupt all the same.
        if interrupts.requested():
            return _interrupted(interrupts.terminated())
        raise
    finally:
        sigint.restore()
        sys.unraisablehook = hook


def _quiet_interrupts(hook):
    """An unraisable hook that stays silent for a Ctrl-C or SIGTERM that landed in a
    finalizer (numba's llvmlite objects are collected mid-build): the interrupt is
    latched and reported once; anything else goes to ``hook``."""

    def quiet(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            return
        hook(unraisable)

    return quiet


def _interrupted(terminated: bool = False) -> int:
    """Reports an interrupt: 130 after Ctrl-C, 143 after SIGTERM (128 + the signal)."""
    what = "terminated" if terminated else "interrupted"
    print(f"lunar-drake: {what}; partial outputs removed", file=sys.stderr)
    return 143 if terminated else 130


def run() -> None:
    """The ``lunar-drake`` program: :func:`main`, then exit with its status. After Ctrl-C
    or SIGTERM it exits at once (streams flushed) instead of finalizing the interpreter: an
    extension interrupted mid-import (Open3D) can otherwise fail at exit and turn 130
    into 1, or re-raise the interrupt. It first starts itself again, once, with glibc's
    malloc cache raised (:mod:`lunar_drake.allocator`)."""
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("lunar-drake")
    from lunar_drake import interrupts

    sigterm = interrupts.TermAsInterrupt()  # the program's only: main() from Python keeps
    try:  # the default SIGTERM
        code = main()
        if interrupts.terminated() and code not in (130, 143):  # the interrupt was lost
            print("lunar-drake: terminated", file=sys.stderr)
            code = 143
        sys.stdout.flush()
    except KeyboardInterrupt:  # one that came just after main() returned
        code = _interrupted(interrupts.terminated())
    except BrokenPipeError:  # the reader went away (``| head``): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 141  # 128 + SIGPIPE, as a shell reports it
    finally:
        sigterm.restore()
    if code in (130, 143):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    run()
