"""What a new user reads first: ``lunar-drake --help`` and each command's help (no reST,
defaults shown), ``./lunar.sh --help`` (usage without set-up), the ``scenarios``
listing, the line printed before a run, and the console's goal line."""

import argparse
import math
import os
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest

from lunar_drake.cli import build_parser, main
from lunar_drake.cli.run import describe_estimate, describe_goals, resolve_run_scenario
from lunar_drake.cli.scenarios import INTERNAL_SCENARIOS, short_description
from lunar_drake.errors import OutOfRangeError
from lunar_drake.scenario_files import dump_scenario, load_scenario, scenario_names

ROOT = Path(__file__).resolve().parents[1]


def _subparsers(parser):
    """(name, parser) of every command and nested command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, p in action.choices.items():
                yield name, p
                yield from ((f"{name} {n}", q) for n, q in _subparsers(p))


def test_help_texts_have_no_rest_markup_and_say_where_to_start():
    parser = build_parser()
    top = parser.format_help()
    assert top.startswith("usage: lunar-drake")
    assert "``" not in top and ":func:" not in top
    assert "lunar-drake run --scenario goto" in top and "lunar-drake scenarios" in top
    names = dict(_subparsers(parser))
    expected = {"run", "scenarios", "plan", "render", "terrain", "terrain synth", "world",
                "world build", "trade", "slip-study", "vo-study", "slip-fit", "ephemeris",
                "lightmap"}  # fmt: skip
    assert expected <= set(names)
    for name, p in names.items():
        text = p.format_help()
        assert "``" not in text and ":mod:" not in text, name
        assert "(default: None)" not in text and "(default: False)" not in text, name


def test_run_help_gives_the_defaults():
    text = " ".join(dict(_subparsers(build_parser()))["run"].format_help().split())
    assert "(default: default)" in text  # --scenario
    assert "(default: 127.0.0.1)" in text  # --meshcat-host
    assert "(default: runs/<scenario>)" in text  # --out
    assert "--scenario goto" in text  # the epilog's first look


def test_main_help_exits_zero(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    assert "commands:" in capsys.readouterr().out


@pytest.mark.parametrize("flag", ["--help", "-h", "help"])
def test_lunar_sh_help_is_usage_without_setup(flag, tmp_path):
    # PYTHON points nowhere: a set-up would fail (no venv can be made) before printing.
    env = {**os.environ, "PYTHON": str(tmp_path / "no-python")}
    r = subprocess.run(["bash", str(ROOT / "lunar.sh"), flag], capture_output=True, text=True,
                       env=env, timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert out.startswith("Usage: ./lunar.sh")
    for word in ("./lunar.sh setup", "./lunar.sh run", "./lunar.sh test", "--help"):
        assert word in out, word
    assert "installing" not in r.stderr


def test_scenarios_lists_each_shipped_scenario_with_a_description(capsys):
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.splitlines()
    public = [n for n in scenario_names() if n not in INTERNAL_SCENARIOS]
    listed = {ln.split()[0]: ln for ln in lines if not ln.startswith("(")}
    assert set(listed) == set(public)
    for name, line in listed.items():
        desc = line[len(name) :].strip()
        assert len(desc.split("[")[0].strip()) >= 10 and "(no description)" not in desc, line
    # The default mission's facts, from its fields.
    d = load_scenario(scenario_name="default")
    assert f"[{d.simulation_duration:g} s, {len(d.ground.goals)} goals on the " in listed["default"]
    assert "Defaults" not in listed and "--all" in lines[-1]
    assert main(["scenarios", "--all"]) == 0
    text = capsys.readouterr().out
    for n in INTERNAL_SCENARIOS:
        line = next(ln for ln in text.splitlines() if ln.startswith(n + " "))
        assert "(internal test scenario)" in line


def test_scenarios_of_a_user_file_take_the_comment_above_each(tmp_path, capsys):
    f = tmp_path / "mine.yaml"
    f.write_text(
        "# Scenarios of my own.\n\n"
        "# Two goals on the small site. The rest of the comment is not shown.\n"
        "two_goals:\n  simulation_duration: 90.0\n"
        "  ground:\n    goals:\n      - {x_m: 1.0, y_m: 0.0}\n      - {x_m: 2.0, y_m: 0.0}\n"
        "    map: {source: truth}\n"
        "bare_route:\n  sensors:\n    camera: {enabled: true}\n"
    )
    assert main(["scenarios", str(f)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines == [
        "two_goals   Two goals on the small site [90 s, 2 goals on the truth map, no cameras]",
        "bare_route  (no description) [5 s, open-loop route, cameras]",
    ]


def test_short_description_cuts_outside_parentheses():
    assert short_description("A small site (for tests, notebooks). More.") == (
        "A small site (for tests, notebooks)"
    )
    long = "The same mission with the skid-steer Husky-class rover (trade study: steering type)."
    assert short_description(long) == "The same mission with the skid-steer Husky-class rover"
    words = "word " * 30
    cut = short_description(words)
    assert cut.endswith("...") and len(cut) <= 72


def _run_args(**kw):
    base = dict(scenario="default", scenario_text="{}", duration=None, no_cameras=False,
                soil=None)  # fmt: skip
    return SimpleNamespace(**{**base, **kw})


def test_the_line_before_a_run_gives_time_size_and_a_first_look():
    default, _ = resolve_run_scenario(_run_args())
    text = describe_estimate(default, meshcat=True, out=Path("runs/default"))
    assert f"simulates {default.simulation_duration:g} s with the stereo cameras" in text
    assert "min on 2 cores" in text and "meshcat.html ~" in text and "frames/ ~" in text
    assert "--scenario goto" in text and "run.mcap ~" in text
    paced = describe_estimate(default, meshcat=True, out=Path("runs/default"), rate=1.0)
    assert f"about {math.ceil(default.simulation_duration / 60)} min" in paced  # 1x real time
    small, _ = resolve_run_scenario(_run_args(scenario="small"))
    text = describe_estimate(small, meshcat=False, out=Path("runs/small"))
    assert "under a minute" in text and "--scenario goto" not in text
    assert "meshcat.html" not in text
    goto, _ = resolve_run_scenario(_run_args(scenario="goto"))
    text = describe_estimate(goto, meshcat=True, out=Path("runs/goto"))
    assert "For a first look" not in text  # it is the first look


def test_duration_flag_out_of_range_is_named_as_the_flag():
    for bad in ("-3", "nan", "1e9"):
        with pytest.raises(OutOfRangeError, match=r"^--duration = \S+ is out of range; allowed"):
            resolve_run_scenario(_run_args(scenario="small", duration=float(bad)))


def test_goals_are_emptied_of_the_unused_route_and_the_dump_reproduces():
    s, _ = resolve_run_scenario(_run_args(scenario="goto"))
    assert s.ground.goals and s.ground.route == []
    text = dump_scenario(s)
    assert "route: []" in text
    again = load_scenario(filename=None, scenario_name="goto")  # the packaged one keeps it
    assert again.ground.route
    # A route scenario keeps its route.
    r, _ = resolve_run_scenario(_run_args(scenario="route"))
    assert len(r.ground.route) == 4


def test_reloaded_resolved_scenario_dumps_the_same_bytes(tmp_path, capsys):
    s, _ = resolve_run_scenario(_run_args(scenario="goto"))
    f = tmp_path / "scenario.yaml"
    f.write_text(dump_scenario(s))
    t, _ = resolve_run_scenario(_run_args(scenario=str(f)))
    assert dump_scenario(t) == f.read_text()
    # `scenarios` on a run's scenario.yaml: one bare scenario, its facts.
    assert main(["scenarios", str(f)]) == 0
    cams = "cameras" if s.sensors.camera.enabled else "no cameras"
    facts = f"{s.simulation_duration:g} s, 1 goal on the {s.ground.map.source} map, {cams}"
    assert (
        capsys.readouterr().out
        == f"{f} holds one bare scenario (a run's scenario.yaml) [{facts}]\n"
    )


def test_goal_line_names_the_goal_not_reached():
    goals = [
        {"goal_xy_m": [-23.0, 9.0], "closest_m": 0.41, "reached": True},
        {"goal_xy_m": [7.0, -7.0], "closest_m": 12.345, "reached": False},
        {"goal_xy_m": [36.0, 7.0], "closest_m": 40.0, "final_distance_m": 81.02,
         "reached": False},
    ]  # fmt: skip
    line = describe_goals(goals)
    assert line.startswith("Goals: 1 of 3 reached (truth)")
    assert "goal 2 at (7, -7) m not reached: the rover came within 12.35 m of it" in line
    assert "1 more not reached" in line and "81.02" not in line
    goals = [{**g, "reached": True} for g in goals]
    goals[-1]["final_distance_m"] = 0.31
    assert describe_goals(goals) == (
        "Goals: 3 of 3 reached (truth; at the end the rover was 0.31 m from the last)"
    )


def test_the_oracle_map_is_announced():
    from lunar_drake.cli.run import map_line

    truth, _ = resolve_run_scenario(
        _run_args(scenario="goto", scenario_text="{ground: {map: {source: truth}}}")
    )
    assert "planning on the TRUE map (oracle)" in map_line(truth)
    orbital, _ = resolve_run_scenario(
        _run_args(scenario="goto", scenario_text="{ground: {map: {source: orbital}}}")
    )
    assert map_line(orbital) is None


def test_the_calibration_line_says_when_the_flight_knows_the_true_soil():
    from lunar_drake.cli.run import calibration_line
    from lunar_drake.scenario_files import load_scenario

    assert calibration_line(load_scenario(scenario_name="default")) is None  # grc1
    oracle = load_scenario(scenario_name="default", scenario_text=(
        "{flight: {estimator: {slip_calibration: lunar_regolith}}}"))  # fmt: skip
    assert "slip calibrated on the TRUE soil (oracle)" in calibration_line(oracle)
    # The plant on GRC-1 and the flight calibrated on it: the oracle again.
    grc = load_scenario(scenario_name="default", scenario_text="{soil: {name: grc1, c: 100.0, "
                        "phi: 0.5759586531581288, K: 0.015, K_y: 0.015, density: 1700.0}}")
    assert calibration_line(grc) is not None
