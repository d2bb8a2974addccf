"""TerrainSource, TerrainVisualizer, MakeMissionDiagram and `lunar-drake run`/`terrain synth`."""

import json

import numpy as np
import pytest
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator

from lunar_drake.cli import main
from lunar_drake.diagrams.mission import MakeMissionDiagram
from lunar_drake.scenario import load_scenario
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.terrain_visualizer import terrain_lod_mesh
from lunar_drake.terrain.heightfield import Heightfield


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("LUNAR_DRAKE_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _ramp():
    _yy, xx = np.mgrid[0:64, 0:64]
    return Heightfield.from_array((0.1 * xx).astype(np.float32), resolution_m=0.5)


def test_terrain_source_outputs_heightfield_and_can_swap_it():
    hf = _ramp()
    src = TerrainSource(heightfield=hf)
    ctx = src.CreateDefaultContext()
    assert src.heightfield_output.Eval(ctx) is hf
    other = Heightfield.from_array(np.zeros((8, 8), np.float32), resolution_m=1.0)
    src.set_heightfield(ctx, other)
    assert src.heightfield_output.Eval(ctx) is other
    with pytest.raises(TypeError):
        TerrainSource(heightfield=np.zeros((4, 4)))


def test_lod_mesh_is_decimated_and_matches_heights():
    hf = _ramp()
    v, f, c = terrain_lod_mesh(hf, max_px=16, albedo=np.full((64, 64), 0.1), albedo_gain=4.0)
    assert v.shape[0] == 3 and v.shape[1] <= 16 * 16
    assert f.shape[0] == 3 and f.max() < v.shape[1]
    np.testing.assert_allclose(c, 0.4)
    # vertex heights follow the ramp z = 0.1 * col = 0.2 * (x - x_min) - 0.05
    x0 = hf.bounds.left
    np.testing.assert_allclose(v[2], 0.2 * (v[0] - x0) - 0.05, atol=1e-6)
    # triangles face up
    p = v.T[f.T]
    nz = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
    assert (nz > 0).all()


def test_mission_diagram_with_meshcat_simulates():
    scenario = load_scenario(scenario_name="small")
    meshcat = Meshcat()
    diagram = MakeMissionDiagram(scenario=scenario, heightfield=_ramp(), meshcat=meshcat)
    ctx = diagram.CreateDefaultContext()
    hf = diagram.GetOutputPort("terrain.heightfield").Eval(ctx)
    assert hf.shape == (64, 64)
    sim = Simulator(diagram)
    sim.AdvanceTo(0.1)
    assert meshcat.HasPath("/terrain")


def test_cli_run_is_deterministic(cache, tmp_path, capsys):
    args = ["run", "--scenario", "small", "--no-meshcat", "--no-progress", "--duration", "0.2"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    first = capsys.readouterr().out
    assert "Outputs:" in first and "built" in first
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    assert "cached" in capsys.readouterr().out
    a = (tmp_path / "a" / "summary.json").read_bytes()
    assert a == (tmp_path / "b" / "summary.json").read_bytes()
    for log in ("truth.csv", "imu.csv", "wheels.csv", "encoders.csv", "star_tracker.csv"):
        assert (tmp_path / "a" / log).read_bytes() == (tmp_path / "b" / log).read_bytes(), log
    frames = sorted((tmp_path / "a" / "frames").iterdir())
    assert frames
    for f in frames:
        assert f.read_bytes() == (tmp_path / "b" / "frames" / f.name).read_bytes(), f.name
    summary = json.loads(a)
    assert summary["simulated_s"] == pytest.approx(0.2)
    assert summary["site"]["shape_px"] == [256, 256]
    assert summary["site"]["craters"] > 0
    assert (tmp_path / "a" / "scenario.yaml").read_text().startswith("random_seed: 7")


def test_cli_errors_are_clear(cache, tmp_path, capsys):
    assert main(["run", "--scenario", "nope", "--no-meshcat", "--out", str(tmp_path)]) == 2
    assert "nope" in capsys.readouterr().err
    assert (
        main(
            [
                "run",
                "--scenario",
                "small",
                "--no-meshcat",
                "--out",
                str(tmp_path),
                "--scenario-text",
                "{terrain: {colour: red}}",
            ]
        )
        == 2
    )
    assert "colour" in capsys.readouterr().err
    assert (
        main(
            [
                "terrain",
                "synth",
                "--from-dem",
                str(tmp_path / "missing.tif"),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 2
    )
    assert "missing.tif" in capsys.readouterr().err
    assert (
        main(["terrain", "synth", "--size", "100", "--factor", "32", "--out", str(tmp_path / "o")])
        == 2
    )
    with pytest.raises(SystemExit):
        main(["terrain", "synth", "--size", "-5", "--out", str(tmp_path / "o")])


def test_cli_terrain_synth_writes_everything(tmp_path, capsys):
    out = tmp_path / "site"
    assert (
        main(
            [
                "terrain",
                "synth",
                "--size",
                "256",
                "--resolution",
                "0.05",
                "--factor",
                "16",
                "--seed",
                "2",
                "--tile",
                "128",
                "--workers",
                "2",
                "--sfd",
                "viper",
                "--no-progress",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    for f in (
        "dem.tif",
        "albedo.tif",
        "rock_mask.tif",
        "normals.tif",
        "craters.csv",
        "rocks.csv",
        "overview.png",
    ):
        assert (out / f).exists(), f
    assert "craters" in capsys.readouterr().out


def test_run_mission_with_meshcat_writes_replay(cache, tmp_path):
    from lunar_drake.mission import run_mission

    scenario = load_scenario(scenario_name="small")
    meshcat = Meshcat()
    result = run_mission(
        scenario=scenario,
        scenario_name="small",
        out_dir=tmp_path,
        meshcat=meshcat,
        duration=0.3,
        progress=False,
    )
    assert result.meshcat_url.startswith("http://")
    assert (tmp_path / "meshcat.html").stat().st_size > 10_000
    assert meshcat.HasPath("/terrain")
    systems = result.summary["systems"]
    assert {"terrain", "terrain_view", "plant", "scene_graph"} <= set(systems)
    assert not any("@" in s for s in systems)  # no addresses: summary.json is reproducible


@pytest.mark.slow
def test_default_rover_drives_100_m_over_the_default_site(cache, tmp_path):
    """The issue's traverse check: the default mission (about 100 m over the synthesized
    site, craters and rocks included) with no blow-up, tipping or sinking."""
    from lunar_drake.mission import load_site_layers, run_mission
    from lunar_drake.site import ensure_site

    scenario = load_scenario(scenario_name="default")
    result = run_mission(
        scenario=scenario, scenario_name="default", out_dir=tmp_path, progress=False, cameras=False
    )
    rv = result.summary["rover"]
    assert result.summary["stop_reason"] == "duration reached"
    assert rv["distance_m"] >= 100.0
    assert rv["max_tilt_deg"] < 20.0
    assert rv["max_sinkage_m"] < 0.05
    truth = np.loadtxt(tmp_path / "truth.csv", delimiter=",", skiprows=1)
    assert np.isfinite(truth).all()
    hf, _ = load_site_layers(ensure_site(scenario, progress=False))
    ground = hf.height(truth[:, 1], truth[:, 2])
    clearance = truth[:, 3] - ground
    # The chassis centre stays above the terrain by about its nominal height.
    assert clearance.min() > 0.25 and clearance.max() < 1.0  # never airborne
    assert np.abs(truth[:, 7:10]).max() < 1.0  # no blow-up (m/s)
