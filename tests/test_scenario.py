"""Scenario loading: named and bare scenarios, overrides, errors that name the file, the
line and the full key, and OneOfEverything (every field set to a non-default value)."""

import dataclasses as dc
from pathlib import Path

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError
from lunar_drake.scenario import Scenario
from lunar_drake.scenario_files import (
    apply_overrides,
    default_scenario_file,
    dump_scenario,
    load_scenario,
    scenario_from_text,
    scenario_names,
)

#: Fields OneOfEverything leaves at their default, with the reason ("[*]": any item).
KEPT_AT_DEFAULT = {
    "ground.route[*].vy_mps": "its rover is skid-steer (steering is non-default), which "
    "cannot move sideways",
    "ground.perception.map.focal_px": "ground.perception takes it from the rig's calibration",
    "ground.perception.map.baseline_m": "ground.perception takes it from the rig's calibration",
    "ground.goals": "goals replace the route, which OneOfEverything exercises (the goto "
    "scenario and tests/test_goto.py drive to goals)",
    "flight.estimator.slip_calibration": "it makes slip_vs_slope, which OneOfEverything "
    "writes by hand (the default, skid and prospect scenarios calibrate)",
    "power.enabled": "OneOfEverything simulates the power system with its other fields "
    "(tests/test_power_system.py builds a plant with it off)",
    "flight.heading.policy": "its rover is skid-steer, which allows only the default "
    "'path' (tests/test_heading.py drives 'sun')",
}


def _differs(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return not np.array_equal(np.asarray(a), np.asarray(b))
    return a != b


def _defaults_kept(obj, default, path="") -> list[str]:
    """Leaf fields of ``obj`` equal to ``default``'s; items of lists of dataclasses are
    compared with their class defaults."""
    if dc.is_dataclass(obj) or hasattr(obj, "__fields__"):
        names = [f.name for f in (dc.fields(obj) if dc.is_dataclass(obj) else obj.__fields__)]
        out = []
        for n in names:
            out += _defaults_kept(getattr(obj, n), getattr(default, n), f"{path}{n}.")
        return out
    if isinstance(obj, list) and obj and dc.is_dataclass(obj[0]):
        out = []
        for item in obj:
            out += _defaults_kept(item, type(item)(), f"{path[:-1]}[*].")
        return out
    return [] if _differs(obj, default) else [path[:-1]]


def test_named_scenarios_load():
    names = scenario_names()
    assert {"Defaults", "default", "small", "skid", "night", "OneOfEverything"} <= set(names)
    for n in names:
        s = load_scenario(scenario_name=n)
        assert isinstance(s, Scenario) and s.name == (
            n if n != "OneOfEverything" else "one_of_everything"
        )


def test_defaults_equal_dataclass_defaults():
    s = load_scenario(scenario_name="Defaults")
    assert dump_scenario(dc.replace(s, name="")) == dump_scenario(Scenario())


def test_one_of_everything_sets_every_field_to_a_non_default_value():
    every = load_scenario(scenario_name="OneOfEverything")
    same = sorted(set(_defaults_kept(every, Scenario())) - set(KEPT_AT_DEFAULT))
    assert not same, f"OneOfEverything leaves these at their defaults: {same}"
    assert every.rover.lights and every.ground.route  # list items are checked too


def test_one_of_everything_builds_and_simulates_a_second(cache, tmp_path):
    """Every option at once: a DEM upscaled from a file, a skid rover with a lamp, delayed
    sensors, the raycast camera, an extra SPICE kernel, Drake config changes."""
    from lunar_drake import metrics
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    s = load_scenario(scenario_name="OneOfEverything")
    site = load_site(s, progress=False)
    logs = simulate(scenario=s, site=site, frames_dir=tmp_path / "frames")
    assert logs.stop_reason == "duration reached"
    assert logs.simulated_s == pytest.approx(1.0)
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    assert summary["site"]["shape_px"] == [256, 256]  # 32 px DEM x 8
    assert summary["rover"]["distance_m"] > 0.01  # it drove
    lat = summary["link"]["uplink"]["latency_s"]  # commands: 0.15 s + jitter [0, 0.01]
    assert set(lat) == {"min", "median", "max"}
    assert 0.15 <= lat["min"] <= lat["median"] <= lat["max"] <= 0.16 + 2e-6
    # Starts at 0.1 s: frames at 0.5 s (delivered 0.6 s) and 1.0 s (due after the end).
    assert logs.frames_written == 1
    imu = logs.vectors["rover.imu"]
    assert np.abs(imu.data[-1]).max() > 0  # delayed samples arrived


def test_round_trip_dump_load():
    s = load_scenario(scenario_name="OneOfEverything")
    assert dump_scenario(scenario_from_text(dump_scenario(s))) == dump_scenario(s)


def test_overrides_apply_on_top():
    s = load_scenario(
        scenario_name="small", scenario_text="{random_seed: 99, terrain: {factor: 8}}"
    )
    assert s.random_seed == 99 and s.terrain.factor == 8
    assert s.terrain.size_px == 256  # untouched
    t = apply_overrides(s, "{sensors: {imu: {delay_s: 0.02}}}")
    assert t.sensors.imu.delay_s == 0.02 and t.sensors.imu.rate_hz == 100.0


def test_a_run_scenario_file_is_a_bare_scenario(tmp_path):
    s = load_scenario(scenario_name="small", scenario_text="{random_seed: 5}")
    path = tmp_path / "scenario.yaml"
    path.write_text(dump_scenario(s))
    assert scenario_names(filename=path) == []
    again = load_scenario(filename=path)
    assert dump_scenario(again) == dump_scenario(s) and again.name == "small"


@pytest.mark.parametrize(
    "text, key",
    [
        ("{terrain: {bogus_key: 1}}", "'terrain.bogus_key'"),
        ("{not_a_section: {}}", "'not_a_section'"),
        ("{rover: {description: {wheel_radius: 0.3}}}", "'rover.description.wheel_radius'"),
        ("{sensors: {imu: {sample_rate_hz: 10}}}", "'sensors.imu.sample_rate_hz'"),
        ("{ground: {route: [{duration_s: 1}, {speed: 2}]}}", "'ground.route[1].speed'"),
        ("{plant_config: {time_stepp: 0.01}}", "'plant_config.time_stepp'"),
    ],
)
def test_unknown_keys_are_named_with_their_full_path(text, key):
    with pytest.raises(ConfigError, match=f"unknown key {key}".replace("[", r"\[")):
        load_scenario(scenario_text=text)


@pytest.mark.parametrize(
    "text, message",
    [
        ("{ground: {map: {confirm_slope_deg: abc}}}",
         "ground.map.confirm_slope_deg = 'abc' must be a number"),
        ("{random_seed: 1.5}", "random_seed = '1.5' must be an integer"),
        ("{ground: {route: [{duration_s: soon}]}}",
         r"ground.route\[0\].duration_s = 'soon' must be a number"),
        ("{sensors: {camera: {width: wide}}}", "sensors.camera.width = 'wide' must be an integer"),
    ],
)  # fmt: skip
def test_a_value_that_is_not_a_number_is_named_with_its_path(text, message):
    with pytest.raises(ConfigError, match=r"--scenario-text, line 1: " + message):
        load_scenario(scenario_text=text)


@pytest.mark.parametrize("value", ["1e-3", "12", ".nan", "-.inf", "7.5"])
def test_numbers_yaml_writes_in_any_form_pass_the_number_check(value):
    from lunar_drake.errors import OutOfRangeError

    try:
        load_scenario(scenario_text=f"{{ground: {{map: {{confirm_slope_deg: {value}}}}}}}")
    except OutOfRangeError as exc:  # .nan / -.inf: a number, out of range
        assert "confirm_slope_deg" in str(exc) and value in (".nan", "-.inf")


def test_unknown_key_in_a_file_names_the_file_and_line(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("mission:\n  rover:\n    description:\n      wheel_radius: 0.3\n")
    with pytest.raises(
        ConfigError, match=r"mine\.yaml.*line 4.*'rover\.description\.wheel_radius'"
    ):
        load_scenario(filename=f, scenario_name="mission")


def test_a_value_out_of_range_names_the_file_and_line_that_wrote_it(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("mission:\n  simulation_duration: 10.0\n  sensors:\n    nss:\n"
                 "      height_m: 0.0\n  ground:\n    route:\n      - {duration_s: 1.0}\n"
                 "      - {duration_s: -1.0}\n")  # fmt: skip
    where = r"^\S*mine\.yaml, line 5: sensors\.nss\.height_m = 0 "
    with pytest.raises(OutOfRangeError, match=where):
        load_scenario(filename=f, scenario_name="mission")
    f.write_text(f.read_text().replace("height_m: 0.0", "height_m: 0.5"))
    with pytest.raises(OutOfRangeError, match=r"mine\.yaml, line 9: ground\.route\[1\]\.dur"):
        load_scenario(filename=f, scenario_name="mission")
    # A key the message names second, written by the overrides (the first is a default).
    with pytest.raises(OutOfRangeError, match=r"^--scenario-text, line 2: ground\.heartbeat_s"):
        load_scenario(filename=f, scenario_name="mission",
                      scenario_text="{ground: {route: [{duration_s: 1.0}]},\n flight: "
                                    "{safety: {uplink_timeout_s: 4.0}}}")  # fmt: skip
    # A key the message names second by its short name, written (the first is a default).
    with pytest.raises(OutOfRangeError,
                       match=r"^--scenario-text, line 3: science\.oh\.min_ppm = 100\.0 is above"):
        load_scenario(filename=f, scenario_name="mission",
                      scenario_text="science:\n  oh:\n    max_ppm: 50.0\n")  # fmt: skip
    # A default inside a written list element: the element's line.
    g = tmp_path / "drill.yaml"
    g.write_text("sensors: {nirvss: {enabled: true}, drill: {enabled: true}}\nground:\n"
                 "  actions:\n    - {t_s: 1.0, action: drill, depth_m: 0.5}\n"
                 "    - {t_s: 9.0, action: drill, depth_m: 0.05}\n")  # fmt: skip
    with pytest.raises(OutOfRangeError, match=r"drill\.yaml, line 5: ground\.actions\[1\]\.step"):
        load_scenario(filename=g)

    with pytest.raises(OutOfRangeError, match=r"--scenario-text, line 2: sensors\.nss\.height_m"):
        load_scenario(filename=f, scenario_name="mission",
                      scenario_text="{simulation_duration: 5.0,\n sensors: {nss: {height_m: -1}}}")
    # A default out of range written nowhere: the key alone (as before).
    with pytest.raises(OutOfRangeError, match=r"^simulation_duration = -1 "):
        apply_overrides(Scenario(simulation_duration=-1.0), "{}")


def test_malformed_yaml_names_the_file_and_line(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("default:\n  random_seed: [1\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml, line 3: malformed YAML"):
        load_scenario(filename=f)
    with pytest.raises(ConfigError, match=r"--scenario-text, line 1: malformed YAML"):
        load_scenario(scenario_text="{random_seed: [")


def test_yaml_never_executes_code(tmp_path):
    marker = tmp_path / "pwned"
    f = tmp_path / "evil.yaml"
    f.write_text(f'default:\n  random_seed: !!python/object/apply:os.system ["touch {marker}"]\n')
    with pytest.raises(ConfigError, match=r"evil\.yaml, line 2: YAML tag .*python.* not allowed"):
        load_scenario(filename=f)
    assert not marker.exists()
    with pytest.raises(ConfigError, match="not allowed"):
        load_scenario(scenario_text="{name: !!python/name:os.system }")


def test_missing_file_and_name():
    with pytest.raises(ConfigError, match=r"/no/such/file\.yaml.*does not exist"):
        load_scenario(filename="/no/such/file.yaml")
    with pytest.raises(LunarDrakeError, match="'nope' not found") as exc:
        load_scenario(scenario_name="nope")
    assert "did you mean" not in str(exc.value) and "'goto'" in str(exc.value)
    assert "Defaults" not in str(exc.value)  # the internal test scenarios are not offered
    for typo, want in (("smal", "small"), ("Small", "small"), ("gotto", "goto"),
                       ("defaults", "default")):  # fmt: skip
        with pytest.raises(ConfigError, match=f"did you mean '{want}'\\? choose one of"):
            load_scenario(scenario_name=typo)


def test_a_range_names_integer_ends_exactly_and_a_node_as_written():
    seed = r"random_seed = -1 is out of range; allowed \[0, 2\*\*63 - 1\]$"
    with pytest.raises(OutOfRangeError, match=seed):
        load_scenario(scenario_name="small", scenario_text="{random_seed: -1}")
    goal = r"ground\.goals\[0\] must be a mapping of keys \(x_m, y_m\), not \[12\.5, 0\]$"
    with pytest.raises(ConfigError, match=goal):
        load_scenario(scenario_name="small", scenario_text="{ground: {goals: [[12.5, 0]]}}")


@pytest.mark.parametrize(
    "text, message",
    [
        ("{terrain: {factor: 3}}", "terrain.factor = 3"),
        ("{terrain: {sfd: lunar}}", "terrain.sfd = 'lunar'"),
        ("{terrain: {resolution_m: -0.1}}", "terrain.resolution_m = -0.1 is out of range"),
        ("{simulation_duration: -2}", "simulation_duration = -2"),
        ("{site: {latitude_deg: -95}}", "site.latitude_deg = -95"),
        ("{site: {epoch_utc: '2027-11-15T00:00:00+05:00'}}", r"is \+05:00 off UTC"),
        ("{site: {epoch_utc: '2027-11-15T00:00:00-03:30'}}", "is -03:30 off UTC"),
        ("{terrain: {min_crater_m: 2.0, max_crater_m: 1.0}}", "terrain.max_crater_m = 1 must"),
        ("{sensors: {imu: {rate_hz: 0}}}", "sensors.imu.rate_hz = 0 is out of range"),
        ("{sensors: {camera: {engine: gpu}}}", "sensors.camera.engine = 'gpu' is unknown"),
        ("{sensors: {camera: {width: 8}}}", "sensors.camera.width = 8 is out of range"),
        ("{soil: {phi: 2.0}}", "soil.phi = 2"),
        ("{rover: {description: {wheel_radius_m: -1}}}", "rover.description.wheel_radius_m"),
        ("{comms: {uplink: {delay_s: -1}}}", "comms.uplink.delay_s = -1"),
        ("{flight: {gimbal: {lookahead_m: 0.1}}}", "flight.gimbal.lookahead_m = 0.1"),
        ("{ground: {route: [{duration_s: -1}]}}", r"ground.route\[0\].duration_s = -1"),
        ("{logging: {period_s: 0}}", "logging.period_s = 0"),
        ("{power: {battery: {capacity_Wh: 0}}}", "power.battery.capacity_Wh = 0"),
        ("{power: {period_s: 0}}", "power.period_s = 0 is out of range"),
        ("{rover: {lights: [{body: chassis, xyz: [1, 2]}]}}", r"rover.lights\[0\]: xyz"),
    ],
)
def test_out_of_range_values_name_the_scenario_key(text, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.").replace(r"\\.", r"\.")):
        load_scenario(scenario_text=text)


def test_messages_round_numbers():
    with pytest.raises(OutOfRangeError) as err:
        load_scenario(scenario_text="{terrain: {resolution_m: -0.30000000000000004}}")
    assert "-0.3 is out of range" in str(err.value)


def test_skid_rover_cannot_be_routed_sideways():
    with pytest.raises(ConfigError, match=r"ground\.route\[0\]\.vy_mps = 0\.1: a skid-steer"):
        load_scenario(scenario_name="skid", scenario_text="{ground: {route: [{vy_mps: 0.1}]}}")


def test_relative_paths_resolve_against_the_scenario_file():
    s = load_scenario(scenario_name="OneOfEverything")
    here = default_scenario_file().parent
    assert Path(s.terrain.dem).is_absolute() and Path(s.terrain.dem).parent.parent == here
    assert all(Path(k).is_file() for k in s.lighting.extra_kernels)


def test_errors_are_value_errors_and_lunar_errors():
    with pytest.raises(ValueError):
        load_scenario(scenario_text="{terrain: {factor: 3}}")
    with pytest.raises(OutOfRangeError):
        load_scenario(scenario_text="{terrain: {resolution_m: 0}}")
