


def run_main(main, name: str) -> None:
    """Runs a benchmark's ``main()`` as a script: bad input (a LunarDrakeError) is one
    line on stderr and exit 2, no traceback."""
    import sys

    from lunar_drake.errors import LunarDrakeError

    try:
        sys.exit(main())
    except LunarDrakeError as exc:
        print(f"{name}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        sys.exit(2)
