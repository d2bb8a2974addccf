"""The mission-control server (aiohttp): the Open MCT page, the telemetry dictionary,
history, realtime subscriptions over WebSocket, map products, the stereo preview, and
commands up the uplink.

Routes (JSON errors ``{"error": "..."}`` with 400 / 404 / 409; times in the API are UTC
milliseconds, ``site.epoch_utc`` + simulation time, as Open MCT expects):

- ``GET /`` the page; ``/web/...`` its plugins; ``/openmct/...`` Open MCT's ``dist``.
- ``GET /api/info``: the mission (name, epoch, map extent, live or replay, state).
- ``GET /api/dictionary``: every point with units and format.
- ``GET /api/history/{key}?start=&end=``: one point's samples.
- ``GET /api/realtime`` (WebSocket): send ``{"subscribe": [keys]}`` /
  ``{"unsubscribe": [keys]}``; receive ``{"datums": [{id, timestamp, value}...],
  "sim_s", "wall"}`` (the batch's simulation time and the wall time the mission
  published it) and ``{"clock": ms}``; a malformed message gets ``{"error": ...}`` and
  the socket stays.
- ``GET /api/map``: goals, plan, track, science samples, costmap version; with
  ``run --serve --instructor`` only, ``instructor``: the rover's TRUE track (an
  oracle for instructors, drawn marked as truth; null otherwise);
  ``/api/map/hillshade.png``, ``/api/map/costmap.png``; ``/api/camera/latest.png``.
- ``POST /api/command`` (:func:`~lunar_drake.mission_control.commands.parse_command`
  body), ``POST /api/preview`` (``{x_m, y_m}``: the path the ground would plan),
  ``POST /api/end``: live missions only (409 in a replay).
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import ipaddress
import itertools
import json
import math
import threading
import time
from pathlib import Path

from aiohttp import WSMsgType, web

from lunar_drake.errors import ConfigError, LunarDrakeError
from lunar_drake.mission_control.commands import CommandError, parse_command
from lunar_drake.mission_control.dictionary import HEAT_LAYERS, POINTS
from lunar_drake.mission_control.store import TelemetryStore, UnknownPointError, check_key

WEB_DIR = Path(__file__).parent / "web"
#: A request the live mission has not taken within this many seconds (wall) is dropped
#: unsent (the mission checks it), so a timed-out command never runs later.
REQUEST_TIMEOUT_S = 10.0
#: Datums a slow realtime client may have waiting before it is dropped.
CLIENT_BACKLOG = 5000


class BindError(ConfigError):
    """The server was asked to listen beyond this machine without saying so."""


def check_host(host: str, *, allow_remote: bool) -> str:
    """``host`` if it is a loopback address (or ``allow_remote``), else :class:`BindError`."""
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback and not allow_remote:
        raise BindError(f"host {host!r} is not a loopback address; mission control binds "
                        "127.0.0.1 unless --host is given explicitly")  # fmt: skip
    return host


def openmct_dir() -> Path | None:
    """Open MCT's built ``dist`` (installed by ``./lunar.sh setup`` with npm), or None."""
    d = WEB_DIR / "node_modules" / "openmct" / "dist"
    return d if (d / "openmct.js").is_file() else None


def epoch_ms(epoch_utc: str) -> float:
    """UTC milliseconds of ``site.epoch_utc`` (ISO 8601, UTC)."""
    t = _dt.datetime.fromisoformat(epoch_utc)
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    return t.timestamp() * 1000.0


class _Client:
    def __init__(self, ws):
        self.ws = ws
        self.keys: set = set()
        self.queue: asyncio.Queue = asyncio.Queue()
        self.backlog = 0
        self.dropped = False


class MissionControl:
    """The server's state: the store, the live mission's queues (or none: a replay), the
    realtime clients and the requests waiting for the mission's reply."""

    def __init__(self, *, store: TelemetryStore | None = None, to_sim=None,
                 foxglove_port: int | None = None, host: str = "127.0.0.1"):  # fmt: skip
        self.store = store or TelemetryStore()
        self.foxglove_port, self.host = foxglove_port, host
        self.foxglove = None
        self.to_sim = to_sim
        self.info: dict = {"name": "", "epoch_utc": "2000-01-01T00:00:00", "live": to_sim is
                           not None, "state": "waiting" if to_sim is not None else "replay"}
        self.hillshade_png: bytes | None = None
        self.costmap: dict | None = None
        self.frame: dict | None = None
        self.clients: set = set()
        self.pending: dict = {}
        self._ids = itertools.count(1)
        self._batch = (None, None)  # (simulation s, publish wall s) of the batch in hand
        self.loop: asyncio.AbstractEventLoop | None = None
        self.epoch_ms = epoch_ms(self.info["epoch_utc"])
        self.store.listeners.append(self._fan_out)

    # ------------------------------------------------------------------- mission news

    def set_site(self, msg: dict) -> None:
        """The ``site`` message: the mission's name, epoch, map extent and hillshade."""
        self.info.update({k: v for k, v in msg.items() if k not in ("kind", "hillshade_png")})
        self.hillshade_png = msg.get("hillshade_png")
        self.epoch_ms = epoch_ms(self.info["epoch_utc"])
        if self.info.get("live"):
            self.info["state"] = "running"
        if self.foxglove_port is not None and self.foxglove is None:
            from lunar_drake.mission_control.foxglove_live import FoxgloveLive

            try:
                self.foxglove = FoxgloveLive(host=self.host, port=self.foxglove_port,
                                             epoch_utc=self.info["epoch_utc"])  # fmt: skip
                self.info["foxglove"] = f"ws://{self.host}:{self.foxglove.server.port}"
            except Exception as exc:  # a busy port: the page still works
                self.info["foxglove_error"] = f"Foxglove live server not started: {exc}"

    def ingest(self, msg: dict) -> None:
        """One message from the mission (:mod:`~lunar_drake.mission_control.live`)."""
        kind = msg.get("kind")
        if kind == "site":
            self.set_site(msg)
        elif kind == "batch":
            m = self.store.map
            if "goals" in msg:
                m.goals = msg["goals"]
            if "plan" in msg:
                m.path = msg["plan"]["path"]
                m.plan_seq = msg["plan"]["seq"]
            for layer, samples in msg.get("science", {}).items():
                m.science.setdefault(layer, []).extend(samples)
            if "truth_pose" in msg and self.info.get("instructor"):
                m.truth.append(msg["truth_pose"])
            if "costmap" in msg:
                self.costmap = msg["costmap"]
            if "frame" in msg:
                self.frame = msg["frame"]
            self._batch = (msg["t_s"], msg.get("wall"))
            self.store.add(msg["datums"])
            if self.foxglove is not None:
                self.foxglove.batch(msg)
            self._broadcast({"clock": self.ms(msg["t_s"]), "sim_s": msg["t_s"],
                             "wall": msg.get("wall")})  # fmt: skip
        elif kind == "reply":
            fut = self.pending.pop(msg.get("id"), None)
            if fut is not None and not fut.done():
                fut.set_result(msg)
        elif kind == "done":
            self.info["state"] = "done"
            self.info["stop_reason"] = msg.get("stop_reason", "")
            for fut in self.pending.values():
                if not fut.done():
                    fut.set_result({"ok": False, "error": "the mission has ended"})
            self.pending.clear()
            self._broadcast({"state": "done", "stop_reason": self.info["stop_reason"]})

    def ms(self, t_s: float) -> float:
        return self.epoch_ms + 1000.0 * float(t_s)

    def _fan_out(self, datums: list) -> None:
        if not self.clients or not datums:
            return
        sim_s, wall = self._batch
        for c in list(self.clients):
            mine = [d for d in datums if d[0] in c.keys]
            if mine:
                self._send(c, {"datums": [{"id": k, "timestamp": self.ms(t), "value": v}
                                          for k, t, v in mine],
                               "sim_s": sim_s, "wall": wall})  # fmt: skip

    def _broadcast(self, payload: dict) -> None:
        for c in list(self.clients):
            self._send(c, payload)

    def _send(self, c: _Client, payload: dict) -> None:
        if c.dropped:
            return
        if c.queue.qsize() > CLIENT_BACKLOG:  # a client that stopped reading: let it go
            c.dropped = True
            self.clients.discard(c)
            c.queue.put_nowait(None)
            return
        c.queue.put_nowait(payload)

    # ----------------------------------------------------------------- the live link

    def pump(self, outbox) -> threading.Thread:
        """Starts a thread that hands every message from the mission's ``outbox`` to
        :meth:`ingest` on the event loop (until a ``done``)."""

        def run():
            while True:
                try:
                    msg = outbox.get()
                except (EOFError, OSError):
                    msg = {"kind": "done", "stop_reason": "the mission process vanished"}
                self.loop.call_soon_threadsafe(self.ingest, msg)
                if msg.get("kind") == "done":
                    return

        t = threading.Thread(target=run, name="mission-pump", daemon=True)
        t.start()
        return t

    async def request(self, op: str, **kw) -> dict:
        """Sends a request to the live mission and waits for its reply (10 s)."""
        if self.to_sim is None:
            raise _HttpError(409, "this is a replay of a finished run: commands need a live "
                                  "mission (lunar-drake run --serve)")  # fmt: skip
        if self.info.get("state") == "done":
            raise _HttpError(409, "the mission has ended")
        if self.info.get("state") == "waiting":
            raise _HttpError(409, "the mission is still being built (site, world model); "
                                  "try again when /api/info says running")  # fmt: skip
        rid = next(self._ids)
        fut = self.loop.create_future()
        self.pending[rid] = fut
        self.to_sim.put({"id": rid, "op": op, "expires": time.time() + REQUEST_TIMEOUT_S, **kw})
        try:
            return await asyncio.wait_for(fut, REQUEST_TIMEOUT_S + 5.0)
        except asyncio.TimeoutError:
            self.pending.pop(rid, None)
            raise _HttpError(504, f"the mission did not answer {op!r} in time; it was not "
                                  "sent") from None  # fmt: skip


class _HttpError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def _finite(v):
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


def _finite_json(data) -> web.Response:
    """JSON with NaN and infinities as null (browsers cannot parse them)."""
    return web.json_response(_finite(data))


def _error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


@web.middleware
async def _errors(request, handler):
    try:
        return await handler(request)
    except _HttpError as exc:
        return _error(exc.status, str(exc))
    except UnknownPointError as exc:
        return _error(404, str(exc))
    except LunarDrakeError as exc:
        return _error(400, str(exc))


def _time_arg(request, name: str, default: float) -> float:
    raw = request.query.get(name)
    if raw is None or raw == "":
        return default
    try:
        v = float(raw)
    except ValueError:
        raise _HttpError(400, f"{name} = {raw!r} must be a number (UTC ms)") from None
    if math.isnan(v):
        raise _HttpError(400, f"{name} = {raw!r} must be a number (UTC ms)")
    return v


def _check_origin(request) -> None:
    """Refuses a request made by another site's page (a browser sends its Origin): only
    the page this server serves may command the rover."""
    origin = request.headers.get("Origin")
    if origin is None:  # not from a browser page (curl, Python, tests)
        return
    host = request.headers.get("Host", "")
    if origin.split("://", 1)[-1] != host:
        raise _HttpError(403, f"requests from {origin} are refused; use the page at "
                              f"http://{host}/")  # fmt: skip


async def _json_body(request) -> dict:
    _check_origin(request)
    if request.content_type != "application/json":
        raise _HttpError(415, f"the body must be JSON (Content-Type: application/json), not "
                              f"{request.content_type!r}")  # fmt: skip
    try:
        body = await request.json()
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise _HttpError(400, "the request body is not valid JSON") from None
    return body


def make_app(mc: MissionControl) -> web.Application:
    """The aiohttp application of ``mc``."""
    app = web.Application(middlewares=[_errors], client_max_size=64 * 1024)

    async def on_startup(app):
        mc.loop = asyncio.get_running_loop()

    app.on_startup.append(on_startup)

    async def index(request):
        return web.FileResponse(WEB_DIR / "index.html")

    async def info(request):
        return web.json_response({**mc.info, "now_ms": mc.ms(mc.store.now_s),
                                  "epoch_ms": mc.epoch_ms, "now_s": mc.store.now_s,
                                  "openmct": openmct_dir() is not None})  # fmt: skip

    async def dictionary(request):
        return web.json_response({"name": mc.info.get("name") or "rover",
                                  "points": [p.to_json() for p in POINTS]})  # fmt: skip

    async def history(request):
        key = check_key(request.match_info["key"])
        start = _time_arg(request, "start", -math.inf)
        end = _time_arg(request, "end", math.inf)
        if start > end:
            raise _HttpError(400, f"start = {start:g} is after end = {end:g}")
        rows = mc.store.history(key, start_s=(start - mc.epoch_ms) / 1000.0,
                                end_s=(end - mc.epoch_ms) / 1000.0)  # fmt: skip
        if request.query.get("strategy") == "latest":
            rows = rows[-1:]
        # the store holds finite values only
        return web.json_response([{"id": key, "timestamp": mc.ms(t), "value": v} for t, v in rows])

    async def map_state(request):
        m = mc.store.map
        xs, ys = mc.store.history("ground.x"), mc.store.history("ground.y")
        track = [[x[1], y[1]] for x, y in zip(xs, ys, strict=False)]
        cm = None
        if mc.costmap is not None:
            cm = {k: v for k, v in mc.costmap.items() if k != "png"}
        return _finite_json({
            "extent_m": mc.info.get("extent_m"), "goals": m.goals, "plan": m.path,
            "plan_seq": m.plan_seq, "heat_layers": {k: v[1] for k, v in HEAT_LAYERS.items()},
            "track": track, "science": m.science, "costmap": cm,
            "rover": track[-1] if track else mc.info.get("spawn_xy"),
            "frame": None if mc.frame is None else {k: v for k, v in mc.frame.items()
                                                    if k != "png"},
            "instructor": ({"track": [[x, y] for _, x, y, _ in m.truth],
                            "rover": m.truth[-1][1:] if m.truth else None}
                           if mc.info.get("instructor") else None),
        })  # fmt: skip

    def png(data: bytes | None, what: str) -> web.Response:
        if data is None:
            raise _HttpError(404, f"no {what} yet")
        return web.Response(body=data, content_type="image/png",
                            headers={"Cache-Control": "no-store"})  # fmt: skip

    async def hillshade(request):
        return png(mc.hillshade_png, "hillshade")

    async def costmap(request):
        return png(None if mc.costmap is None else mc.costmap["png"], "costmap")

    async def camera(request):
        return png(None if mc.frame is None else mc.frame["png"], "stereo frame")

    async def command(request):
        cmd = parse_command(await _json_body(request))
        reply = await mc.request("command", command=cmd)
        if not reply.get("ok"):
            raise _HttpError(400, reply.get("error", "refused"))
        return web.json_response({"ok": True, "command": reply["command"],
                                  "queued_at_ms": mc.ms(reply["t_s"]), "t_s": reply["t_s"],
                                  "warning": reply.get("warning", "")})  # fmt: skip

    async def preview(request):
        body = await _json_body(request)
        goal = parse_command({**(body if isinstance(body, dict) else {}), "action": "goal"})
        reply = await mc.request("preview", x_m=goal["x_m"], y_m=goal["y_m"])
        if not reply.get("ok"):
            raise _HttpError(400, reply.get("error", "refused"))
        return web.json_response({"ok": True, "path": reply["path"]})

    async def end(request):
        _check_origin(request)
        await mc.request("end")
        return web.json_response({"ok": True})

    async def realtime(request):
        _check_origin(request)
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=64 * 1024)
        await ws.prepare(request)
        client = _Client(ws)
        mc.clients.add(client)

        async def writer():
            while True:
                payload = await client.queue.get()
                if payload is None:
                    await ws.close()
                    return
                await ws.send_str(json.dumps(payload))

        task = asyncio.create_task(writer())
        task.add_done_callback(lambda t: t.cancelled() or t.exception())
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    data = json.loads(msg.data)
                    if not isinstance(data, dict):
                        raise CommandError("a message is a JSON object")
                    for key in data.get("subscribe", []):
                        client.keys.add(check_key(key))
                    for key in data.get("unsubscribe", []):
                        client.keys.discard(key)
                except (json.JSONDecodeError, LunarDrakeError, TypeError) as exc:
                    mc._send(client, {"error": str(exc) or "malformed message"})
        finally:
            mc.clients.discard(client)
            task.cancel()
        return ws

    app.router.add_get("/", index)
    app.router.add_get("/api/info", info)
    app.router.add_get("/api/dictionary", dictionary)
    app.router.add_get("/api/history/{key}", history)
    app.router.add_get("/api/map", map_state)
    app.router.add_get("/api/map/hillshade.png", hillshade)
    app.router.add_get("/api/map/costmap.png", costmap)
    app.router.add_get("/api/camera/latest.png", camera)
    app.router.add_get("/api/realtime", realtime)
    app.router.add_post("/api/command", command)
    app.router.add_post("/api/preview", preview)
    app.router.add_post("/api/end", end)
    app.router.add_static("/web", WEB_DIR / "static")
    if (dist := openmct_dir()) is not None:
        app.router.add_static("/openmct", dist)
    return app


async def start_server(mc: MissionControl, *, host: str = "127.0.0.1", port: int = 8080,
                       allow_remote: bool = False) -> web.AppRunner:  # fmt: skip
    """Starts serving ``mc`` on host:port (``port`` 0: any free one); returns the runner
    (``runner.addresses`` has the bound address)."""
    check_host(host, allow_remote=allow_remote)
    runner = web.AppRunner(make_app(mc), access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, host, port)
    try:
        await site.start()
    except OSError as exc:
        await runner.cleanup()
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    mc.loop = asyncio.get_running_loop()
    return runner
