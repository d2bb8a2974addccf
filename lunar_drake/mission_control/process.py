"""The mission-control server in its own process, so that a paced simulation and the
server never wait on each other (each has a core; they talk through two queues)."""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing as mp
import signal

from lunar_drake.errors import ConfigError


def _server_main(outbox, inbox, ready, host: str, port: int, allow_remote: bool,
                 replay_dir: str | None, foxglove_port: int | None) -> None:  # fmt: skip
    """The server process: serve until terminated."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when to stop
    from lunar_drake.mission_control.server import MissionControl, start_server

    async def main():
        if replay_dir is not None:
            from lunar_drake.mission_control.replay import load_run

            mc = MissionControl(store=None, to_sim=None)
            load_run(mc, replay_dir)
        else:
            mc = MissionControl(to_sim=inbox, foxglove_port=foxglove_port, host=host)
        try:
            runner = await start_server(mc, host=host, port=port, allow_remote=allow_remote)
        except ConfigError as exc:
            ready.send(("error", str(exc)))
            return
        addr = runner.addresses[0]
        ready.send(("ok", f"http://{addr[0]}:{addr[1]}/"))
        if outbox is not None:
            mc.pump(outbox)
        await asyncio.Event().wait()

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())


class ServerProcess:
    """A running mission-control server process.

    ``outbox`` (mission -> server) and ``inbox`` (server -> mission) are the live
    mission's queues (:class:`~lunar_drake.mission_control.live.LiveObserver`); ``url``
    where it listens; with ``foxglove_port`` a live mission also feeds the foxglove-sdk
    WebSocket server there (:mod:`~lunar_drake.mission_control.foxglove_live`).
    ``close()`` stops it.
    """

    def __init__(self, *, host: str = "127.0.0.1", port: int = 8080,
                 allow_remote: bool = False, replay_dir=None,
                 foxglove_port: int | None = None):  # fmt: skip
        from lunar_drake.mission_control.server import check_host

        check_host(host, allow_remote=allow_remote)
        ctx = mp.get_context("spawn")
        live = replay_dir is None
        self.outbox = ctx.Queue() if live else None
        self.inbox = ctx.Queue() if live else None
        parent, child = ctx.Pipe(duplex=False)
        self.process = ctx.Process(
            target=_server_main, name="lunar-drake-mission-control", daemon=True,
            args=(self.outbox, self.inbox, child, host, int(port), allow_remote,
                  None if replay_dir is None else str(replay_dir), foxglove_port),
        )  # fmt: skip
        self.process.start()
        child.close()
        if not parent.poll(120.0):
            self.close()
            raise ConfigError("the mission-control server did not start within 120 s")
        try:
            status, text = parent.recv()
        except EOFError:
            self.close()
            raise ConfigError("the mission-control server process died while starting") from None
        if status != "ok":
            self.close()
            raise ConfigError(text)
        self.url = text

    def close(self) -> None:
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5.0)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(5.0)
        for q in (self.outbox, self.inbox):
            if q is not None:
                q.cancel_join_thread()
                q.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
