"""Mission control in a real browser: Debian's Chromium driven by Playwright against a
live mission started with ``lunar-drake run --serve`` (skipped where no Chromium or Open
MCT is installed; ``./lunar.sh test`` installs both)."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

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


@pytest.fixture
def live_mission(cache, tmp_path):
    """A live goto mission without goals (the page gives them), paced to 2x real time."""
    out = tmp_path / "run"
    text = ("{simulation_duration: 400.0, ground: {goals: []}, "
            "sensors: {camera: {enabled: true, width: 320, height: 240}, "
            "nss: {enabled: true}}}")  # fmt: skip
    cmd = [sys.executable, "-m", "lunar_drake.cli", "run", "--scenario", "goto",
           "--scenario-text", text, "--serve", "--port", "0", "--foxglove-port", "0",
           "--rate", "2", "--no-meshcat",
           "--no-progress", "--out", str(out)]  # fmt: skip
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
    yield url, proc, out
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(30)


def test_the_page_loads_plots_live_and_a_clicked_goal_is_driven(live_mission):
    from playwright.sync_api import sync_playwright

    url, proc, out = live_mission
    assert _get(url + "api/info")["foxglove"].startswith("ws://127.0.0.1:")
    errors = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1700, "height": 860})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
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
