"""`lunar-drake run`: runs that reproduce from their scenario.yaml, flags as scenario
overrides, outputs that are never half-written or lost, one-line errors, Meshcat on
127.0.0.1, the progress bar, and the parked rover holding still."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lunar_drake.cli import build_parser, main
from lunar_drake.cli.run import run_estimate
from lunar_drake.outputs import LOG_FILES
from lunar_drake.scenario_files import apply_overrides, load_scenario

RUN = ["run", "--no-meshcat", "--no-progress"]
LOGS = [*LOG_FILES.values(), "telemetry.csv", "link.csv"]


def _tree(path: Path) -> dict:
    return {
        str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()
    }


def _assert_same_run(a: Path, b: Path):
    assert (a / "summary.json").read_bytes() == (b / "summary.json").read_bytes()
    for name in LOGS:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert (a / "scenario.yaml").read_bytes() == (b / "scenario.yaml").read_bytes()


def _siblings(path: Path) -> list[str]:
    return sorted(p.name for p in path.parent.iterdir() if p.name.startswith("."))


@pytest.mark.slow
def test_default_run_with_flags_reproduces_from_its_scenario_yaml(cache, tmp_path, capsys):
    """The issue's check: --duration 20 --no-cameras become scenario fields, and
    `run --scenario RUN/scenario.yaml --out OTHER` writes the same bytes."""
    a, b = tmp_path / "a", tmp_path / "b"
    assert main([*RUN, "--duration", "20", "--no-cameras", "--out", str(a)]) == 0
    text = (a / "scenario.yaml").read_text()
    assert "simulation_duration: 20.0" in text and "enabled: false" in text
    summary = json.loads((a / "summary.json").read_text())
    assert summary["scenario"] == "default" and summary["simulated_s"] == 20.0
    assert summary["camera_frames"] == 0 and not (a / "frames").exists()
    assert main([*RUN, "--scenario", str(a / "scenario.yaml"), "--out", str(b)]) == 0
    _assert_same_run(a, b)
    capsys.readouterr()


def test_scenario_text_run_reproduces_and_frames_match(cache, tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    override = "{random_seed: 3, sensors: {imu: {delay_s: 0.02}, camera: {rate_hz: 2.0}}}"
    args = [*RUN, "--scenario", "small", "--duration", "0.6", "--scenario-text", override]
    assert main([*args, "--out", str(a)]) == 0
    out = capsys.readouterr().out
    assert "Outputs:" in out and "(2 stereo frames)" in out
    assert "random_seed: 3" in (a / "scenario.yaml").read_text()
    assert main([*RUN, "--scenario", str(a / "scenario.yaml"), "--out", str(b)]) == 0
    _assert_same_run(a, b)
    frames = sorted((a / "frames").iterdir())
    # The frame bytes announced before the run are the right order (an estimate).
    s = load_scenario(filename=str(a / "scenario.yaml"))
    estimate = run_estimate(s, meshcat=False)["frames_bytes"]
    assert 0.5 < estimate / sum(f.stat().st_size for f in frames) < 2.0
    assert [f.name for f in frames][:2] == ["left_000000.png", "left_000000_preview.png"]
    for f in frames:
        assert f.read_bytes() == (b / "frames" / f.name).read_bytes(), f.name
    assert main([*RUN, "--scenario", "small", "--duration", "0.2", "--out", str(b)]) == 0
    assert "(1 stereo frame)" in capsys.readouterr().out


def test_a_failed_run_leaves_the_previous_run_untouched(cache, tmp_path, capsys):
    out = tmp_path / "run"
    assert main([*RUN, "--scenario", "small", "--duration", "0.2", "--out", str(out)]) == 0
    before = _tree(out)
    # The spawn is off the site: the run fails while building, after the site loaded.
    bad = "{rover: {spawn_x_m: 500.0}}"
    args = [*RUN, "--scenario", "small", "--scenario-text", bad, "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "OutOfBoundsError" in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert _tree(out) == before
    assert _siblings(out) == []


def test_a_failed_run_into_a_new_directory_leaves_nothing(cache, tmp_path, capsys):
    out = tmp_path / "new" / "nested" / "run"
    args = [*RUN, "--scenario", "small", "--scenario-text", "{rover: {spawn_x_m: 500.0}}"]
    assert main([*args, "--out", str(out)]) == 2
    assert not (tmp_path / "new").exists()
    capsys.readouterr()


@pytest.mark.parametrize(("sig", "code", "word"), [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated")])  # fmt: skip
def test_an_interrupted_run_leaves_the_previous_run_untouched(cache, tmp_path, sig, code, word):
    """Ctrl-C, or SIGTERM (a job scheduler's stop, ``timeout``), mid-run: one line, no
    traceback, the previous run untouched and no staging directory left."""
    out = tmp_path / "run"
    env = {**os.environ, "LUNAR_DRAKE_CACHE": str(cache)}
    exe = [sys.executable, "-m", "lunar_drake.cli", *RUN, "--scenario", "small"]
    subprocess.run([*exe, "--duration", "0.2", "--out", str(out)], env=env, check=True)
    before = _tree(out)
    proc = subprocess.Popen(
        [*exe, "--duration", "300", "--out", str(out)],
        env=env,
        stderr=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    # Wait until it is simulating (its staging directory exists), then interrupt.
    deadline = time.time() + 120
    while time.time() < deadline and not any(".run.tmp-" in n for n in _siblings(out)):
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err
    assert "Traceback" not in err and word in err
    assert _tree(out) == before
    assert _siblings(out) == []


@pytest.mark.parametrize("command", ["run", "render", "slip-study"])
def test_unwritable_out_is_one_line_naming_the_path(cache, tmp_path, capsys, command):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    out = blocker / "out"
    args = {
        "run": [*RUN, "--scenario", "small", "--duration", "0.1"],
        "render": ["render", "--scenario", "small", "--no-progress"],
        "slip-study": ["slip-study", "--slopes", "0", "--seeds", "1", "--no-progress"],
    }[command]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "OutputError" in err and str(out) in err and "not a directory" in err.lower()


def test_a_folder_of_other_files_is_never_replaced(cache, tmp_path, capsys):
    keep = tmp_path / "data"
    keep.mkdir()
    (keep / "precious.txt").write_text("keep me")
    args = [*RUN, "--scenario", "small", "--duration", "0.1", "--out", str(keep)]
    assert main(args) == 2
    assert "precious.txt" in capsys.readouterr().err
    assert (keep / "precious.txt").read_text() == "keep me"


@pytest.mark.parametrize(
    ("extra", "ip"), [([], "127.0.0.1"), (["--meshcat-host", "127.0.0.2"], "127.0.0.2")]
)
def test_meshcat_listens_on_localhost_by_default(cache, tmp_path, capsys, extra, ip):
    """Meshcat binds 127.0.0.1 unless --meshcat-host says otherwise (here another
    loopback address, so the test never opens a port to the network)."""
    import psutil

    assert build_parser().parse_args(["run"]).meshcat_host == "127.0.0.1"
    out = tmp_path / "run"
    args = ["run", "--scenario", "small", "--duration", "0.1", "--no-progress", "--out", str(out)]
    before = {c.laddr for c in psutil.Process().net_connections(kind="tcp")}
    assert main([*args, *extra]) == 0
    printed = capsys.readouterr().out
    assert f"Meshcat: http://{ip}:" in printed
    listening = [
        c
        for c in psutil.Process().net_connections(kind="tcp")
        if c.status == psutil.CONN_LISTEN and c.laddr not in before
    ]
    assert listening and all(c.laddr.ip == ip for c in listening)
    size = (out / "meshcat.html").stat().st_size
    assert size > 10_000
    # The size announced before the run is the right order (an estimate).
    s = load_scenario(scenario_name="small", scenario_text="{simulation_duration: 0.1}")
    assert 0.5 < run_estimate(s, meshcat=True)["meshcat_bytes"] / size < 2.0


def test_progress_bar_counts_simulated_seconds_and_real_time_factor(cache, tmp_path, capsys):
    args = ["run", "--no-meshcat", "--scenario", "small", "--duration", "2"]
    assert main([*args, "--no-cameras", "--out", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    assert "simulating" in err and "/2.0 sim s" in err and "x real time" in err
    assert main([*args, "--no-progress", "--no-cameras", "--out", str(tmp_path / "q")]) == 0
    assert "simulating" not in capsys.readouterr().err


def test_parked_rover_holds_on_a_side_slope(cache):
    """After its route the rover parks across an 8 degree slope: the flight software
    brakes the wheels and the rover holds within 1 cm (it slid 1.9 m and yawed 29 deg
    before the brakes and the soil's static shear)."""
    from lunar_drake import metrics
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import SiteData
    from lunar_drake.terrain.heightfield import Heightfield

    n, res = 400, 0.05
    yy = np.mgrid[0:n, 0:n][0]
    y = (n / 2 - yy - 0.5) * res
    z = (y * math.tan(math.radians(8.0))).astype(np.float32)  # uphill to the north
    site = SiteData.from_heightfield(Heightfield.from_array(z, resolution_m=res))
    for rover in ("default", "skid"):
        scenario = load_scenario(
            scenario_name=rover,
            scenario_text="{simulation_duration: 30.0, rover: {spawn_x_m: -3.0},"
            " sensors: {camera: {enabled: false}},"
            " ground: {goals: [], route: [{duration_s: 1.0}, {duration_s: 5.0, vx_mps: 0.2}]}}",
        )
        logs = simulate(scenario=scenario, site=site)
        parked = metrics.parked_drift(logs)
        assert parked is not None and parked["duration_s"] > 15.0
        assert parked["drift_m"] < 0.01, (rover, parked)
        assert abs(parked["yaw_change_deg"]) < 0.5, (rover, parked)


def test_a_run_that_hits_nodata_leaves_no_directory(cache, tmp_path, capsys):
    """A DEM with a nodata hole under the spawn point: NoDataError, one line, exit 2, and
    neither the run directory nor the parents the run would have made are left."""
    from lunar_drake.terrain.heightfield import Heightfield

    z = np.zeros((200, 200), np.float32)
    z[80:120, 80:120] = np.nan
    dem = tmp_path / "holes.tif"
    Heightfield.from_array(z, resolution_m=0.1).to_geotiff(dem)
    out = tmp_path / "new" / "run"
    text = "{terrain: {dem: " + str(dem) + "}, sensors: {camera: {enabled: false}}}"
    args = [*RUN, "--scenario", "small", "--duration", "0.1", "--scenario-text", text]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "NoDataError" in err and "nodata" in err
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["holes.tif"]


def test_ctrl_c_inside_a_system_callback_is_an_interrupt(small_site):
    """SIGINT that lands while a library runs inside a system's callback can come back as
    another error (seen in CI: numba compiling during the first step, reported by Drake
    as "initialization failed"); simulate() still reports it as KeyboardInterrupt (exit
    130 in the CLI), not as a failed simulation, and restores the SIGINT handler."""
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    scenario = apply_overrides(scenario, "{sensors: {camera: {enabled: false}}}")
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when started in the background

    def interrupt(t, pose):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)  # the handler runs here, inside the callback
        except KeyboardInterrupt:
            raise RuntimeError("initialization failed") from None

    with pytest.raises(KeyboardInterrupt):
        simulate(
            scenario=scenario,
            site=site,
            progress=False,
            stop_when=interrupt,
            stop_check_period_s=0.05,
        )
    assert signal.getsignal(signal.SIGINT) is before


def test_ctrl_c_swallowed_before_the_simulation_still_stops_it(small_site):
    """A KeyboardInterrupt can be swallowed outright (seen: in an importlib callback,
    "Exception ignored"); the CLI latches SIGINT, and simulate() under it stops at once.
    Library use (no latch owner) starts clean and leaves no latch behind."""
    from lunar_drake import interrupts
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    scenario = apply_overrides(scenario, "{sensors: {camera: {enabled: false}}}")
    before = signal.getsignal(signal.SIGINT)
    owner = interrupts.LatchedSigint()  # what cli.main installs
    try:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        except KeyboardInterrupt:
            pass  # swallowed, as an import callback would
        assert interrupts.requested()
        with pytest.raises(KeyboardInterrupt):
            simulate(scenario=scenario, site=site, progress=False)
        assert interrupts.requested()  # simulate() is nested: the latch is the owner's
    finally:
        owner.restore()
    assert not interrupts.requested()
    assert signal.getsignal(signal.SIGINT) is before
    # A later library run is not affected.
    logs = simulate(scenario=apply_overrides(scenario, "{simulation_duration: 0.1}"), site=site,
                    progress=False)  # fmt: skip
    assert logs.stop_reason == "duration reached"


def test_ctrl_c_during_an_import_is_an_interrupt_not_a_traceback(monkeypatch, capsys, tmp_path):
    # Ctrl-C while pydrake or Open3D initialises surfaces as "ImportError: initialization
    # failed"; the latch says it was the interrupt.
    from lunar_drake import interrupts
    from lunar_drake.cli import world as world_command

    def interrupted_import(args):
        try:
            interrupts.raise_and_latch(signal.SIGINT, None)
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None

    monkeypatch.setattr(world_command, "command", interrupted_import)
    assert main(["world", "build", str(tmp_path), "--out", str(tmp_path / "w")]) == 130
    assert capsys.readouterr().err.strip() == "lunar-drake: interrupted; partial outputs removed"

    def failing_import(args):
        raise ImportError("no module named nothing")

    monkeypatch.setattr(world_command, "command", failing_import)  # no Ctrl-C: a real error
    with pytest.raises(ImportError):
        main(["world", "build", str(tmp_path), "--out", str(tmp_path / "w")])


def test_an_output_path_that_is_a_file_and_a_negative_seed_are_refused(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("keep me")
    for argv in (["run", "--scenario", "small", "--no-meshcat", "--out", str(f)],
                 ["world", "build", str(tmp_path), "--out", str(f)]):  # fmt: skip
        assert main(argv) == 2
        assert "it is a file, not a directory" in capsys.readouterr().err
    assert f.read_text() == "keep me"
    out = str(tmp_path / "w")
    assert main(["world", "build", str(tmp_path), "--out", out, "--seed", "-1"]) == 2
    assert "--seed -1 is out of range" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
