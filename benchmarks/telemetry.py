"""Benchmark: mission control's telemetry path (issue 31).

    .venv/bin/python benchmarks/telemetry.py --out bench_telemetry.json

1. **Live latency and pacing.** ``lunar-drake run --serve --rate 1`` on the ``goto``
   site without cameras, telemetry at 10 Hz, for ``--duration`` simulated seconds
   (default 600: ten minutes); ``--clients`` (10) WebSocket clients each subscribe to
   every point of the dictionary. Latency of a telemetry datum (``PACKET_KEYS``:
   those stamped with a packet's delivery) = its arrival at a client minus the
   wall time at which the paced mission's ground software took the packet in (its
   receiver's tick after the link delivered it: the batch's publish time less the
   simulated time from that tick to the publish, over the rate). Also: from the link's
   delivery (which adds the wait for the ground's 10 Hz tick, a property of the modelled
   ground software), and the transfer alone (arrival minus publish).
   ``rate_error_pct`` = |simulated s / wall s of the run - rate| / rate x 100, from the
   run's ``timing.json``.
2. **History.** A ``--history-duration`` (3600) s run of the same mission, as fast as it
   can, served for replay (``lunar-drake serve``); ``history_load_s`` = the median time
   of ``GET /api/history/rover.x`` over its whole span (5 requests).

JSON keys: ``latency_ms: {median, p99}``, ``from_delivery_ms``, ``transfer_ms``, ``clients``,
``points``, ``datums``, ``rate_error_pct``, ``history_load_s``, ``history_points``,
with the machine's speed index. Aims: p99 under 100 ms, the rate within 2 %, history
under 1 s.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_write_text, check_output_file
from lunar_drake.mission_control.dictionary import PACKET_KEYS

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line

SCENARIO_TEXT = ("{{simulation_duration: {d}, flight: {{telemetry_rate_hz: 10.0}}, "
                 "sensors: {{camera: {{enabled: false}}}}}}")  # fmt: skip


def _start(args: list[str]) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-m", "lunar_drake.cli", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)  # fmt: skip
    lines = []
    while True:
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError("no mission-control URL:\n" + "".join(lines))
        lines.append(line)
        m = re.search(r"Mission control: (http://\S+)", line)
        if m:
            return proc, m.group(1)


def _get(url: str):
    with urllib.request.urlopen(url, timeout=30) as r:
        return json.loads(r.read())


async def _clients(url: str, n: int, keys: list[str], rate: float, done) -> list:
    from aiohttp import ClientSession

    lat, transfer, delivery = [], [], []

    async def one():
        async with ClientSession() as s, s.ws_connect(url.replace("http", "ws") +
                                                      "api/realtime", heartbeat=20) as ws:
            await ws.send_str(json.dumps({"subscribe": keys}))
            while not done.is_set():
                try:
                    msg = await ws.receive(timeout=1.0)
                except asyncio.TimeoutError:
                    continue
                if msg.type.name != "TEXT":
                    return
                now = time.time()
                data = json.loads(msg.data)
                if "datums" not in data or data.get("wall") is None:
                    continue
                wall, sim = data["wall"], data["sim_s"]
                transfer.append(now - wall)
                for d in data["datums"]:
                    if d["id"] not in PACKET_KEYS:
                        continue  # stamped at the ground's tick, not a packet's delivery
                    t = (d["timestamp"] - epoch) / 1000.0  # the link's delivery (sim s)
                    t_in = math.ceil(t * tick_hz - 1e-6) / tick_hz  # the ground's intake
                    lat.append(now - (wall - (sim - t_in) / rate))
                    delivery.append(now - (wall - (sim - t) / rate))

    info = _get(url + "api/info")
    epoch, tick_hz = info["epoch_ms"], info["ground_rate_hz"]
    await asyncio.gather(*(one() for _ in range(n)))
    return lat, transfer, delivery


def live(*, duration: float, clients: int, rate: float, out: Path) -> dict:
    proc, url = _start(["run", "--scenario", "goto", "--scenario-text",
                        SCENARIO_TEXT.format(d=duration), "--serve", "--port", "0",
                        "--foxglove-port", "-1", "--rate", str(rate), "--no-meshcat",
                        "--no-progress", "--out", str(out)])  # fmt: skip
    try:
        while _get(url + "api/info")["state"] != "running":
            time.sleep(0.5)
        keys = [p["key"] for p in _get(url + "api/dictionary")["points"]]

        async def main():
            done = asyncio.Event()
            task = asyncio.create_task(_clients(url, clients, keys, rate, done))
            while proc.poll() is None:
                try:
                    if _get(url + "api/info")["state"] == "done":
                        break
                except OSError:
                    break
                await asyncio.sleep(1.0)
            done.set()
            return await task

        lat, transfer, delivery = asyncio.run(main())
        rc = proc.wait(300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    if rc != 0:
        raise RuntimeError(f"the live run failed ({rc}): {proc.stdout.read()}")
    timing = json.loads((out / "timing.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    achieved = summary["simulated_s"] / timing["simulate_s"]
    return {"lat": np.array(lat), "transfer": np.array(transfer),
            "delivery": np.array(delivery), "points": len(keys),
            "rate_achieved": achieved, "simulated_s": summary["simulated_s"],
            "rate_error_pct": abs(achieved - rate) / rate * 100.0}


def history(*, duration: float, out: Path) -> dict:
    r = subprocess.run([sys.executable, "-m", "lunar_drake.cli", "run", "--scenario", "goto",
                        "--scenario-text", SCENARIO_TEXT.format(d=duration), "--no-meshcat",
                        "--no-progress", "--out", str(out)], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"the {duration:g} s run failed: {r.stdout}{r.stderr}")
    proc, url = _start(["serve", str(out), "--port", "0"])
    try:
        times, n = [], 0
        for _ in range(5):
            t0 = time.perf_counter()
            rows = _get(url + "api/history/rover.x")
            times.append(time.perf_counter() - t0)
            n = len(rows)
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)
    return {"history_load_s": float(np.median(times)), "history_points": n}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=None, help="JSON results")
    p.add_argument("--duration", type=float, default=600.0, help="live run, simulated s")
    p.add_argument("--history-duration", type=float, default=3600.0)
    p.add_argument("--clients", type=int, default=10)
    p.add_argument("--rate", type=float, default=1.0)
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")
    with tempfile.TemporaryDirectory(prefix="bench_telemetry_") as tmp:
        lv = live(duration=a.duration, clients=a.clients, rate=a.rate, out=Path(tmp) / "live")
        hi = history(duration=a.history_duration, out=Path(tmp) / "long")
    speed = measure_speed_index()
    ms = lambda v, q: round(float(np.percentile(v, q)) * 1000.0, 2)  # noqa: E731
    result = {
        "benchmark": "telemetry",
        "clients": a.clients,
        "points": lv["points"],
        "telemetry_rate_hz": 10.0,
        "datums": int(lv["lat"].size),
        "latency_ms": {"median": ms(lv["lat"], 50), "p99": ms(lv["lat"], 99)},
        "transfer_ms": {"median": ms(lv["transfer"], 50), "p99": ms(lv["transfer"], 99)},
        "from_delivery_ms": {"median": ms(lv["delivery"], 50), "p99": ms(lv["delivery"], 99)},
        "rate": a.rate,
        "rate_achieved": round(lv["rate_achieved"], 4),
        "rate_error_pct": round(lv["rate_error_pct"], 3),
        "live_simulated_s": lv["simulated_s"],
        "history_run_s": a.history_duration,
        "history_load_s": round(hi["history_load_s"], 4),
        "history_points": hi["history_points"],
        "cpu_count": os.cpu_count(),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    print(f"{'clients':>7} {'points':>6} {'datums':>8} {'lat med ms':>10} {'lat p99 ms':>10} "
          f"{'xfer p99 ms':>11} {'rate err %':>10} {'history s':>9} {'hist pts':>8}")
    print(f"{a.clients:>7} {lv['points']:>6} {result['datums']:>8} "
          f"{result['latency_ms']['median']:>10.1f} {result['latency_ms']['p99']:>10.1f} "
          f"{result['transfer_ms']['p99']:>11.1f} {result['rate_error_pct']:>10.2f} "
          f"{result['history_load_s']:>9.3f} {result['history_points']:>8}")
    print(speed_index_line(speed))
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    sys.exit(main())
