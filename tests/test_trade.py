"""The trade-study runner: study files, the design, errors, and runs on dask.distributed
(a LocalCluster and a real ``dask scheduler`` with two ``dask worker`` processes)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lunar_drake.cli import main
from lunar_drake.errors import ConfigError
from lunar_drake.trade import metrics as tm
from lunar_drake.trade.study import design_points, expand_jobs, parse_study

TINY = """\
name: tiny
description: Two drive speeds on the goto site, 3 s each.
base:
  scenario: goto
  scenario_text: "{simulation_duration: 3, sensors: {camera: {enabled: false}}}"
factors:
  ground.drive_speed_mps: [0.1, 0.3]
replicates: [4]
metrics:
  - rover.distance_m: max
  - goals.reached
  - link.uplink.messages
"""


def _study(text: str, tmp_path: Path, name: str = "study.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_factorial_design_order_and_resolved_cases():
    s = parse_study(TINY.replace("replicates: [4]", "replicates: 2")
                    .replace("factors:\n", "factors:\n  comms.uplink.delay_s: [1.3, 5]\n"),
                    source="s.yaml")  # fmt: skip
    pts = design_points(s)
    assert pts == [{"comms.uplink.delay_s": a, "ground.drive_speed_mps": b}
                   for a in (1.3, 5) for b in (0.1, 0.3)]  # fmt: skip
    jobs = expand_jobs(s)
    assert [j.id for j in jobs][:3] == ["c0000-r0", "c0000-r1", "c0001-r0"]
    assert len(jobs) == 8 and len({j.key for j in jobs}) == 8
    from lunar_drake.scenario_files import scenario_from_text

    sc = scenario_from_text(jobs[3].scenario_yaml)  # c0001-r1
    assert sc.comms.uplink.delay_s == 1.3 and sc.ground.drive_speed_mps == 0.3
    assert sc.random_seed == 1 and sc.simulation_duration == 3.0
    assert sc.sensors.camera.enabled is False


def test_lhs_design_is_seeded_stratified_and_in_range():
    text = TINY.replace("factors:\n  ground.drive_speed_mps: [0.1, 0.3]\n",
                        "design: lhs\nlhs: {n: 8, seed: 3}\nfactors:\n"
                        "  ground.drive_speed_mps: {min: 0.1, max: 0.3}\n"
                        "  ground.max_replans: {min: 0, max: 7, int: true}\n"
                        "  ground.auto_resume: [true, false]\n")  # fmt: skip
    s = parse_study(text, source="s.yaml")
    a, b = design_points(s), design_points(s)
    assert a == b and len(a) == 8
    v = sorted(p["ground.drive_speed_mps"] for p in a)
    # one point in each eighth of the range (Latin hypercube stratification)
    assert [int((x - 0.1) / 0.2 * 8) for x in v] == list(range(8))
    assert all(isinstance(p["ground.max_replans"], int) for p in a)
    assert {p["ground.auto_resume"] for p in a} == {True, False}
    other = parse_study(text.replace("seed: 3", "seed: 4"), source="s.yaml")
    assert design_points(other) != a


def test_named_factor_levels_and_list_element_keys():
    text = TINY.replace(
        "factors:\n  ground.drive_speed_mps: [0.1, 0.3]\n",
        "factors:\n  pace:\n    levels:\n      slow: {ground: {drive_speed_mps: 0.1}}\n"
        "      fast: {ground: {drive_speed_mps: 0.3, heartbeat_s: 2.0}}\n"
        "  comms.downlink.channels[1].bandwidth_bps: [1.0e6, 4.0e6]\n",
    )
    jobs = expand_jobs(parse_study(text, source="s.yaml"))
    from lunar_drake.scenario_files import scenario_from_text

    fast = scenario_from_text(jobs[3].scenario_yaml)
    assert jobs[3].factors == {"pace": "fast", "comms.downlink.channels[1].bandwidth_bps": 4.0e6}
    assert fast.ground.drive_speed_mps == 0.3 and fast.ground.heartbeat_s == 2.0
    assert fast.comms.downlink.channels[1].bandwidth_bps == 4.0e6
    assert fast.comms.downlink.channels[1].name == "images"  # the rest of the list kept
    assert fast.comms.downlink.channels[0].name == "main"


@pytest.mark.parametrize(
    ("edit", "expect"),
    [
        (("ground.drive_speed_mps: [0.1, 0.3]", "ground.drive_sped_mps: [0.1]"),
         "line 7: factor ground.drive_sped_mps = 0.1: unknown key 'ground.drive_sped_mps'"),
        (("[0.1, 0.3]", "[0.1, -2.0]"),
         "line 7: factor ground.drive_speed_mps = -2.0: "),
        (("[0.1, 0.3]", "[]"), "line 7: factor 'ground.drive_speed_mps' has no values"),
        (("name: tiny", "nmae: tiny"), "line 1: unknown key 'nmae'"),
        (("replicates: [4]", "replicates: 0"), "line 8: replicates = 0 is out of range"),
        (("  - goals.reached", "  - goals.reachd"), "line 11: metric 'goals.reachd' is unknown"),
        (("  - goals.reached", "  - rovr.x"), "line 11: metric 'rovr.x' is unknown"),
        (("scenario: goto", "scenario: nowhere"), "line 3: base scenario: scenario 'nowhere'"),
        (("[0.1, 0.3]", "{min: 0.1, max: 0.3}"), "ranges need design: lhs"),
    ],
)
def test_bad_studies_name_the_file_line_and_key(tmp_path, edit, expect):
    path = _study(TINY.replace(*edit), tmp_path)
    from lunar_drake.trade.study import load_study

    with pytest.raises(ConfigError) as err:
        expand_jobs(load_study(path))
    msg = str(err.value)
    assert msg.startswith(str(path)) and expect in msg, msg
    assert "\n" not in msg


def test_derived_metrics_from_a_summary():
    summary = {
        "simulated_s": 700.0,
        "goals": [{"reached": True}, {"reached": False}, {"reached": True}],
        "ground": {"goals_judged_s": 450.0},
        "localization": {"error_per_distance": 0.0123},
        "rover": {"distance_m": 98.5},
    }
    got = tm.metric_values(summary, ["goals.reached", "goals.all_reached", "mission.time_s",
                                     "mission.goals_per_hour", "mission.time_per_goal_s",
                                     "localization.drift_pct", "rover.distance_m",
                                     "goals[1].reached"])  # fmt: skip
    assert got == {"goals.reached": 2, "goals.all_reached": 0, "mission.time_s": 450.0,
                   "mission.goals_per_hour": 16.0, "mission.time_per_goal_s": 225.0,
                   "localization.drift_pct": 1.23, "rover.distance_m": 98.5,
                   "goals[1].reached": False}  # fmt: skip
    summary["ground"]["goals_judged_s"] = None  # a goal still open: the whole run counts
    assert tm.derived(summary)["mission.time_s"] == 700.0
    with pytest.raises(ConfigError, match=r"'rover\.nothing' is not in this run"):
        tm.metric_values(summary, ["rover.nothing"])


def test_a_case_that_raises_is_an_error_row():
    from lunar_drake.trade.case import run_case

    r = run_case("random_seed: -3\n", ("rover.distance_m",))
    assert r["status"] == "error" and r["error"].startswith("OutOfRangeError: ")
    assert "random_seed" in r["error"] and r["metrics"] == {}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(
    ("edit", "args", "expect"),
    [
        (("ground.drive_speed_mps", "ground.drive_speedd"), (), "unknown key"),
        (("[0.1, 0.3]", "[0.1, 99.0]"), (), "ground.drive_speed_mps = 99.0"),
        (None, ("--scheduler", "tcp://127.0.0.1:{port}"), "cannot connect"),
        (None, ("--scheduler", "127.0.0.1"), "not a scheduler address"),
    ],
)
def test_trade_cli_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, edit, args,
                                                                expect):  # fmt: skip
    path = _study(TINY.replace(*edit) if edit else TINY, tmp_path)
    out = tmp_path / "out"
    args = [a.format(port=_free_port()) for a in args]
    code = main(["trade", str(path), "--out", str(out), "--no-progress", *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and expect in err and "\n" not in err, err
    assert not out.exists()


def _run(study: Path, out: Path, *extra: str) -> int:
    return main(["trade", str(study), "--out", str(out), "--no-progress", *extra])


@pytest.mark.slow
def test_results_are_the_same_bytes_with_1_and_2_workers_and_after_resume(tmp_path, capsys):
    study = _study(TINY, tmp_path)
    a, b = tmp_path / "w1", tmp_path / "w2"
    assert _run(study, a, "--workers", "1") == 0
    assert _run(study, b, "--workers", "2") == 0
    ref = (a / "results.csv").read_bytes()
    assert ref == (b / "results.csv").read_bytes()
    lines = ref.decode().splitlines()
    assert lines[0] == ("case,replicate,seed,ground.drive_speed_mps,rover.distance_m,"
                        "goals.reached,link.uplink.messages,status,error,key")  # fmt: skip
    assert [ln.split(",")[:4] for ln in lines[1:]] == [["c0000", "0", "4", "0.1"],
                                                       ["c0001", "0", "4", "0.3"]]  # fmt: skip
    assert all(",ok,," in ln for ln in lines[1:])
    d_slow, d_fast = (float(ln.split(",")[4]) for ln in lines[1:])
    assert 0.0 < d_slow < d_fast  # faster commanded speed, farther in the same 3 s
    # The case's scenario.yaml reruns it alone: the same summary figure.
    from lunar_drake.scenario_files import load_scenario

    sc = load_scenario(filename=a / "cases" / "c0001-r0" / "scenario.yaml")
    assert sc.ground.drive_speed_mps == 0.3 and sc.random_seed == 4
    # Resume after losing a row: only that run runs again; the same bytes.
    (b / "cases" / "c0001-r0" / "row.json").unlink()
    (b / "results.csv").unlink()
    capsys.readouterr()
    assert _run(study, b, "--resume", "--workers", "1") == 0
    out = capsys.readouterr().out
    assert "2 runs (1 already done); 1 to run" in out
    assert (b / "results.csv").read_bytes() == ref
    assert (b / "report.md").is_file() and (b / "plots" / "rover_distance_m.png").is_file()
    # Without --resume a used directory is refused.
    assert _run(study, b) == 2


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("dask", path=os.path.dirname(sys.executable)) is None,
                    reason="the dask command is not installed beside this Python")  # fmt: skip
def test_a_study_runs_on_a_real_scheduler_with_two_workers(tmp_path):
    dask_cmd = shutil.which("dask", path=os.path.dirname(sys.executable))
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    procs = [subprocess.Popen([dask_cmd, "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env, cwd=tmp_path,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]  # fmt: skip
    try:
        for k in range(2):
            procs.append(subprocess.Popen(
                [dask_cmd, "worker", address, "--nthreads", "1", "--name", f"remote{k}",
                 "--no-dashboard"], env=env, cwd=tmp_path, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL))  # fmt: skip
        from distributed import Client

        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(address, timeout="2s") as c:
                    if len(c.scheduler_info()["workers"]) == 2:
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline, "the scheduler and workers did not start"
            time.sleep(0.5)
        study = _study(TINY, tmp_path)
        out = tmp_path / "out"
        assert _run(study, out, "--scheduler", address) == 0
        rows = (out / "results.csv").read_text().splitlines()[1:]
        assert len(rows) == 2 and all(",ok,," in r for r in rows)
        workers = {ln.split(",")[2] for ln in (out / "timing.csv").read_text().splitlines()[1:]}
        assert workers <= {"remote0", "remote1"}
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


@pytest.mark.slow
def _square(x):
    return x * x


def test_map_cases_runs_here_with_one_worker_and_refuses_none():
    from lunar_drake.trade.engine import map_cases

    assert map_cases(_square, [3, 1, 2], workers=1, progress=False) == [9, 1, 4]
    with pytest.raises(ConfigError, match="workers = 0"):
        map_cases(_square, [1], workers=0, progress=False)


def test_slip_study_runs_on_the_study_engine_with_the_same_rows(tmp_path):
    """slip-study keeps its command; with --workers > 1 its cases run on the trade
    engine (dask.distributed) and slip.csv is the same bytes as in one process."""
    from lunar_drake.studies.slip_study import run_slip_study

    kw = dict(rovers=["explicit"], slopes_deg=[8.0], distance_m=0.4, seeds=2, progress=False)
    run_slip_study(out_dir=tmp_path / "one", workers=1, **kw)
    run_slip_study(out_dir=tmp_path / "two", workers=2, **kw)
    one = (tmp_path / "one" / "slip.csv").read_bytes()
    assert one == (tmp_path / "two" / "slip.csv").read_bytes()
    assert len(one.decode().splitlines()) == 3  # header + two seeds


@pytest.mark.slow
def test_two_studies_in_one_fresh_process(tmp_path):
    """The engine's dask settings go over distributed's defaults and come off again: a
    second study in the same process (a notebook's second run) still starts its
    cluster. In a fresh interpreter, where nothing imported distributed before."""
    study = _study(TINY.replace("simulation_duration: 3", "simulation_duration: 0.5")
                   .replace("[0.1, 0.3]", "[0.1]"), tmp_path)  # fmt: skip
    code = ("from lunar_drake.trade.engine import run_study\n"
            "from lunar_drake.trade.study import load_study\n"
            "if __name__ == '__main__':\n"
            "    for k in range(2):\n"
            f"        r = run_study(study=load_study({str(study)!r}), out={str(tmp_path)!r}"
            " + f'/out{k}', workers=1, progress=False)\n"
            "        assert r.failed == 0 and len(r.rows) == 1\n"
            "    print('ok')\n")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600, check=False)  # fmt: skip
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
