"""``lunar-drake serve RUN``: a finished run in the mission-control page (replay)."""

from __future__ import annotations

import time

from lunar_drake.cli._common import add_subcommand


def command(args) -> int:
    from lunar_drake.cli.run import check_port
    from lunar_drake.mission_control.process import ServerProcess
    from lunar_drake.mission_control.recording import check_run_dir

    run_dir = check_run_dir(args.run)
    check_port(args.port)
    host = args.host or "127.0.0.1"
    with ServerProcess(host=host, port=args.port, allow_remote=args.host is not None,
                       replay_dir=run_dir) as server:  # fmt: skip
        print(f"Mission control: {server.url} (replay of {run_dir}); press Ctrl-C to stop.",
              flush=True)  # fmt: skip
        try:
            while server.process.is_alive():
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass
    return 0


def add_parser(sub) -> None:
    r = add_subcommand(sub, "serve", help="serve a finished run in the mission-control page",
                       epilog="A live mission: lunar-drake run --serve.")  # fmt: skip
    r.add_argument("run", help="a run directory (lunar-drake run --out DIR)")
    r.add_argument("--port", type=int, default=8080, help="port (default 8080; 0: any free)")
    r.add_argument("--host", default=None,
                   help="interface to listen on (default 127.0.0.1; giving another opens it "
                        "to the network)")  # fmt: skip
    r.set_defaults(func=command)
