"""The mission-control server in its own process, so that a paced simulation and the
server never wait on each other (each has a core; they talk through two queues)."""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing as mp
import signal
import time

from lunar_drake.errors import ConfigError

#: How long a server may take to start (s): a replay may rebuild the run's site.
START_TIMEOUT_S = 900.0


def _server_main(outbox, inbox, ready, host: str, port: int, allow_remote: bool,
                 replay_dir: str | None, foxglove_port: int | None) -> None:  # fmt: skip
    """The server process: serve until terminated."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when to stop
    from lunar_drake.mission_control.server import MissionControl, start_server

    _watch_parent()

    async def main():
        if replay_dir is not None:
            from lunar_drake.errors import LunarDrakeError
            from lunar_drake.mission_control.replay import load_run

            mc = MissionControl(store=None, to_sim=None)
            try:
                load_run(mc, replay_dir)
            except (LunarDrakeError, OSError, ValueError, KeyError) as exc:
                ready.send(("error", f"cannot load {replay_dir!r}: {exc}"))
                return
        else:
            mc = MissionControl(to_sim=inbox, foxglove_port=foxglove_port, host=host)
        try:
            runner = await start_server(mc, host=host, port=port, allow_remote=allow_remote)
        except ConfigError as exc:
            ready.send(("error", str(exc)))
            return
        addr = runner.addresses[0]
        h = f"[{addr[0]}]" if ":" in addr[0] else addr[0]
        ready.send(("ok", f"http://{h}:{addr[1]}/"))
        if outbox is not None:
            mc.pump(outbox)
        await asyncio.Event().wait()

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())


def _watch_parent() -> None:
    """Exits this process when its parent has gone (killed outright), so the port is not
    held by an orphan."""
    import os
    import threading
    import time

    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


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
        deadline = time.monotonic() + START_TIMEOUT_S  # a replay may rebuild its site
        while not parent.poll(0.5):
            if not self.process.is_alive() or time.monotonic() > deadline:
                self.close()
                raise ConfigError("the mission-control server did not start (its process "
                                  + ("died)" if not self.process.is_alive() else
                                     f"took over {START_TIMEOUT_S:g} s)"))  # fmt: skip
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
