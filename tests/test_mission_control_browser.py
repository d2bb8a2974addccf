"""Mission control in a real browser: Debian's Chromium driven by Playwright against a
live mission started with ``lunar-drake run --serve`` (skipped where no Chromium or Open
MCT is installed; ``./lunar.sh test`` installs both)."""

import contextlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from lunar_drake.mission_control.server import openmct_dir

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
SCREENSHOTS = Path(__file__).resolve().parents[1] / "docs" / "img" / "mission_control"

pytestmark = [
    pytest.mark.skipif(CHROMIUM is None, reason="no Chromium (./lunar.sh test installs it)"),
    pytest.mark.skipif(openmct_dir() is None, reason="no Open MCT (./lunar.sh setup installs it)"),
]


def _get(url: str):
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


def _post(url: str, body: dict):
    req = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                 headers={"Content-Type": "application/json"})  # fmt: skip
    with urllib.request.urlopen(req, timeout=20) as r:
        return json.loads(r.read())


def _start_live(args: list[str], cache, out: Path, *, meshcat: bool = False):
    """``lunar-drake run --serve ARGS`` on a free port; (url, process) once it runs."""
    cmd = [sys.executable, "-m", "lunar_drake.cli", "run", *args, "--serve", "--port", "0",
           *([] if meshcat else ["--no-meshcat"]), "--no-progress", "--out", str(out)]  # fmt: skip
    env = {**os.environ, "LUNAR_DRAKE_CACHE": str(cache)}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env, start_new_session=True)  # fmt: skip
    url, lines = None, []
    deadline = time.monotonic() + 300
    while url is None and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"Mission control: (http://\S+)", line)
        if m:
            url = m.group(1)
    assert url, "no URL printed:\n" + "".join(lines)
    while _get(url + "api/info")["state"] != "running":
        assert proc.poll() is None, "".join(lines) + proc.stdout.read()
        time.sleep(0.5)
    return url, proc


@contextlib.contextmanager
def _live(args: list[str], cache, out: Path, *, meshcat: bool = False):
    """:func:`_start_live` as a context: (url, process), killed on the way out if it is
    still running."""
    url, proc = _start_live(args, cache, out, meshcat=meshcat)
    try:
        yield url, proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(30)


def _page(pw, errors: list | None = None, *, width: int = 1700, height: int = 860):
    """(browser, page) in Debian's Chromium; console errors and page errors go to
    ``errors``."""
    browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
    page = browser.new_page(viewport={"width": width, "height": height})
    if errors is not None:
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
    return browser, page


@pytest.fixture
def live_mission(cache, tmp_path):
    """A live goto mission without goals (the page gives them), paced to 2x real time."""
    out = tmp_path / "run"
    text = ("{simulation_duration: 400.0, ground: {goals: []}, "
            "sensors: {camera: {enabled: true, width: 320, height: 240}, "
            "nss: {enabled: true}}}")  # fmt: skip
    with _live(["--scenario", "goto", "--scenario-text", text, "--foxglove-port", "0",
                "--rate", "2"], cache, out) as (url, proc):  # fmt: skip
        yield url, proc, out


def test_the_page_loads_plots_live_and_a_clicked_goal_is_driven(live_mission):
    from playwright.sync_api import sync_playwright

    url, proc, out = live_mission
    assert _get(url + "api/info")["foxglove"].startswith("ws://127.0.0.1:")
    errors = []
    with sync_playwright() as pw:
        browser, page = _page(pw, errors)
        page.goto(url)
        page.wait_for_selector(".lunar-map canvas", timeout=60_000)
        # a plot receives live points (the plots subscribed to rover.speed)
        page.wait_for_function("() => (window.lunarRealtime.delivered['rover.speed'] || 0) >= 2",
                               timeout=60_000)  # fmt: skip
        # click the map at the site point (3, 0) m: the preview is drawn, then sent
        page.wait_for_function("() => window.lunarMap && window.lunarMap.view", timeout=30_000)
        px = page.evaluate("() => window.lunarMap.toPx(3.0, 0.0)")
        page.locator(".lunar-map canvas").click(position={"x": px[0], "y": px[1]})
        page.wait_for_selector("text=Send goal", state="visible", timeout=30_000)
        assert page.evaluate("() => window.lunarMap.preview.path.length") >= 2
        page.click("text=Send goal")
        page.wait_for_function("() => window.lunarMap.root.dataset.ack === 'acknowledged'",
                               timeout=90_000)  # fmt: skip
        # the NSS heat layer has samples to draw
        page.wait_for_function("() => (window.lunarMap.state.science.nss_weh || []).length > 0",
                               timeout=90_000)  # fmt: skip
        # the goal is driven to (the ground's judgement on the downlinked estimate)
        page.wait_for_function(
            "() => (window.lunarMap.state.goals || []).some((g) => g[2] === 'reached')",
            timeout=180_000)  # fmt: skip
        page.wait_for_timeout(1500)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOTS / "live.png"))
        browser.close()
    assert not errors, errors
    state = _get(url + "api/map")
    goal = [g for g in state["goals"] if abs(g[0] - 3.0) < 0.2 and abs(g[1]) < 0.2]
    assert goal and goal[0][2] == "reached"
    _post(url + "api/end", {})
    assert proc.wait(120) == 0
    scenario = (out / "scenario.yaml").read_text()
    assert "action: goal" in scenario
    # ended from the page: scenario.yaml runs that long (so it reproduces the session)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"] == "ended from mission control"
    duration = float(re.search(r"^simulation_duration: (\S+)", scenario, re.M).group(1))
    assert duration == pytest.approx(summary["simulated_s"]) and duration < 400.0
    events = (out / "ground_events.csv").read_text()
    assert re.search(r"goal,.*0: \(3\.\d\d, -?0\.\d\d\) m", events)


def test_the_default_mission_is_driven_from_the_page(cache, tmp_path):
    """``./lunar.sh run --serve``'s mission: the default scenario (orbital map, the mast's
    stereo pair, VO), as fast as it runs, its goals left out so the page gives the only
    one: a click on the map, 3 m from the rover where the ground's preview finds a path,
    is driven to (the ground's judgement), and the true rover moved."""
    from playwright.sync_api import sync_playwright

    out = tmp_path / "run"
    with _live(["--scenario-text", "{ground: {goals: []}}", "--foxglove-port", "-1",
                "--rate", "0"], cache, out) as (url, proc):  # fmt: skip
        info = _get(url + "api/info")
        assert info["map_source"] == "orbital"
        sx, sy = info["spawn_xy"]
        errors = []
        with sync_playwright() as pw:
            browser, page = _page(pw, errors)
            page.goto(url)
            page.wait_for_function("() => window.lunarMap && window.lunarMap.view",
                                   timeout=60_000)  # fmt: skip
            page.wait_for_function(
                "() => (window.lunarRealtime.delivered['rover.speed'] || 0) >= 2", timeout=300_000)
            goal = None
            for ang in range(0, 360, 45):  # a goal the ground can plan to
                gx = sx + 3.0 * math.cos(math.radians(ang))
                gy = sy + 3.0 * math.sin(math.radians(ang))
                r = page.evaluate(
                    "async ([x, y]) => { const r = await fetch('/api/preview', {method: 'POST',"
                    " headers: {'Content-Type': 'application/json'}, body: JSON.stringify("
                    "{x_m: x, y_m: y})}); return [r.status, await r.json()]; }", [gx, gy])
                if r[0] == 200:
                    goal = (gx, gy)
                    break
            assert goal is not None, "no plannable goal 3 m from the spawn"
            px = page.evaluate(f"() => window.lunarMap.toPx({goal[0]}, {goal[1]})")
            page.locator(".lunar-map canvas").click(position={"x": px[0], "y": px[1]})
            page.wait_for_selector("text=Send goal", state="visible", timeout=60_000)
            page.click("text=Send goal")
            page.wait_for_function(
                "() => window.lunarMap.root.dataset.ack === 'acknowledged'", timeout=300_000)
            page.wait_for_function(
                "() => (window.lunarMap.state.goals || []).some((g) => g[2] === 'reached')",
                timeout=600_000)  # fmt: skip
            page.wait_for_timeout(1500)
            SCREENSHOTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(SCREENSHOTS / "default.png"))
            browser.close()
        assert not errors, errors
        _post(url + "api/end", {})
        assert proc.wait(300) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"] == "ended from mission control"
    assert summary["ground"]["map_source"] == "orbital"
    truth = np.loadtxt(out / "truth.csv", delimiter=",", skiprows=1, usecols=(1, 2))
    assert math.hypot(*(truth[-1] - goal)) < 1.5  # the true rover got there


def test_a_meshcat_button_clicked_in_the_browser_drives_the_rover(cache, tmp_path):
    """Drake's Meshcat page in Chromium: *Drive arc (2 m)* (the arc sliders at their
    defaults: 0.2 m/s, straight) goes through the operator API like the page's commands,
    the rover drives, and the click is in the run's ``scenario.yaml``."""
    from playwright.sync_api import sync_playwright

    out = tmp_path / "run"
    text = ("{simulation_duration: 300.0, ground: {goals: []}, "
            "sensors: {camera: {enabled: false}}}")  # fmt: skip
    with _live(["--scenario", "goto", "--scenario-text", text, "--foxglove-port", "-1",
                "--rate", "2"], cache, out, meshcat=True) as (url, proc):  # fmt: skip
        meshcat_url, lines = None, []
        while meshcat_url is None:
            line = proc.stdout.readline()
            assert line, "no Meshcat URL:\n" + "".join(lines)
            lines.append(line)
            m = re.search(r"^Meshcat: (http://\S+)", line)
            meshcat_url = m.group(1) if m else None
        x0 = _get(url + "api/history/rover.x?strategy=latest")
        with sync_playwright() as pw:
            browser, page = _page(pw, width=1280, height=800)
            page.goto(meshcat_url)
            page.get_by_text("Open Controls").click(timeout=60_000)  # dat.GUI's panel
            page.locator("li.cr.function", has_text="Drive arc (2 m)").click(timeout=60_000)
            browser.close()
        x_start = x0[-1]["value"] if x0 else 0.0
        deadline = time.monotonic() + 240
        moved = 0.0
        while moved < 1.5 and time.monotonic() < deadline:
            time.sleep(1.0)
            got = _get(url + "api/history/rover.x?strategy=latest")
            moved = abs(got[-1]["value"] - x_start) if got else 0.0
        assert moved >= 1.5, f"the rover moved {moved:.2f} m after the click"
        _post(url + "api/end", {})
        assert proc.wait(300) == 0
    scenario = (out / "scenario.yaml").read_text()
    assert "action: drive_arc" in scenario and "speed_mps: 0.2" in scenario
