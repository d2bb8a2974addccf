"""Scenario loading: named scenarios, overrides, unknown keys, ranges."""

import pytest

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError
from lunar_drake.scenario import (
    Scenario,
    dump_scenario,
    load_scenario,
    scenario_from_text,
    scenario_names,
)


def test_named_scenarios_load():
    names = scenario_names()
    assert {"Defaults", "default", "small", "OneOfEverything"} <= set(names)
    for n in names:
        s = load_scenario(scenario_name=n)
        assert isinstance(s, Scenario)


def test_defaults_equal_dataclass_defaults():
    assert dump_scenario(load_scenario(scenario_name="Defaults")) == dump_scenario(Scenario())


def test_one_of_everything_sets_values():
    s = load_scenario(scenario_name="OneOfEverything")
    assert s.terrain.sfd == "powerlaw"
    assert s.terrain.powerlaw_exponent == -1.9
    assert s.site.latitude_deg == -89.9
    assert s.simulator_config.max_step_size == 0.01
    assert s.visualization.publish_period == 0.05
    assert s.camera.engine == "raycast"


def test_unknown_camera_engine_is_rejected():
    from lunar_drake.errors import ConfigError

    with pytest.raises(ConfigError, match=r"camera\.engine = 'gpu'; allowed heightfield, raycast"):
        load_scenario(scenario_name="small", scenario_text="{camera: {engine: gpu}}")


def test_round_trip_dump_load():
    s = load_scenario(scenario_name="OneOfEverything")
    assert dump_scenario(scenario_from_text(dump_scenario(s))) == dump_scenario(s)


def test_overrides_apply_on_top():
    s = load_scenario(
        scenario_name="small", scenario_text="{random_seed: 99, terrain: {factor: 8}}"
    )
    assert s.random_seed == 99 and s.terrain.factor == 8
    assert s.terrain.size_px == 256  # untouched


@pytest.mark.parametrize(
    "text, word",
    [
        ("{terrain: {bogus_key: 1}}", "bogus_key"),
        ("{not_a_section: {}}", "not_a_section"),
    ],
)
def test_unknown_keys_rejected(text, word):
    with pytest.raises(ConfigError, match=word):
        load_scenario(scenario_text=text)


@pytest.mark.parametrize(
    "text, word",
    [
        ("{terrain: {factor: 3}}", "terrain.factor = 3"),
        ("{terrain: {sfd: lunar}}", "'lunar'"),
        ("{terrain: {resolution_m: -0.1}}", "terrain.resolution_m = -0.1"),
        ("{terrain: {rock_abundance: 1.5}}", "terrain.rock_abundance = 1.5"),
        ("{simulation_duration: -2}", "simulation_duration = -2"),
        ("{site: {latitude_deg: -95}}", "site.latitude_deg = -95"),
        ("{terrain: {min_crater_m: 2.0, max_crater_m: 1.0}}", "terrain.max_crater_m = 1.0"),
        ("{terrain: {size_px: 1000, factor: 64}}", "multiple"),
    ],
)
def test_out_of_range_rejected(text, word):
    with pytest.raises(ConfigError, match=word.replace(".", r"\.").replace("(", r"\(")):
        load_scenario(scenario_text=text)


def test_errors_are_value_errors_and_lunar_errors():
    with pytest.raises(ValueError):
        load_scenario(scenario_text="{terrain: {factor: 3}}")
    with pytest.raises(OutOfRangeError):
        load_scenario(scenario_text="{terrain: {resolution_m: 0}}")
    with pytest.raises(LunarDrakeError, match="nope"):
        load_scenario(scenario_name="nope")
    with pytest.raises(ConfigError, match="does not exist"):
        load_scenario(filename="/no/such/file.yaml")
