"""TerrainSource, TerrainVisualizer, the mission diagram with Meshcat, the default
traverse, and `lunar-drake run`/`terrain synth` errors."""

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams
from pydrake.systems.analysis import Simulator

from lunar_drake.cli import main
from lunar_drake.diagrams.mission import MakeMissionDiagram
from lunar_drake.scenario_files import load_scenario
from lunar_drake.site import SiteData
from lunar_drake.systems.terrain_source import TerrainSource
from lunar_drake.systems.terrain_visualizer import terrain_lod_mesh
from lunar_drake.terrain.heightfield import Heightfield


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
    meshcat = Meshcat(MeshcatParams(host="127.0.0.1"))
    site = SiteData.from_heightfield(_ramp(), name="ramp")
    diagram = MakeMissionDiagram(scenario=scenario, site=site, meshcat=meshcat)
    ctx = diagram.CreateDefaultContext()
    hf = diagram.GetOutputPort("truth.heightfield").Eval(ctx)
    assert hf.shape == (64, 64)
    sim = Simulator(diagram)
    sim.AdvanceTo(0.1)
    assert meshcat.HasPath("/terrain")


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
    assert "unknown key 'terrain.colour'" in capsys.readouterr().err
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


@pytest.mark.slow
def test_default_rover_drives_100_m_over_the_default_site(cache):
    """The default mission (three operator goals about 100 m over the synthesized site,
    craters and rocks included, planned on the ground and driven through the link)
    drives to every goal (within the estimate's drift) with no hazard strike, blow-up,
    tipping or sinking, and the parked rover holds still at the end."""
    from lunar_drake import metrics
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario = apply_overrides(
        load_scenario(scenario_name="default"), "{sensors: {camera: {enabled: false}}}"
    )
    site = load_site(scenario, progress=False)
    logs = simulate(scenario=scenario, site=site)
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    rv = summary["rover"]
    assert summary["stop_reason"] == "duration reached"
    assert rv["distance_m"] >= 90.0  # the string-pulled path: 94 m
    assert rv["max_tilt_deg"] < 20.0
    assert rv["max_sinkage_m"] < 0.05
    truth = logs.vectors["truth.pose"].data
    assert np.isfinite(truth).all()
    ground = site.heightfield.height(truth[:, 0], truth[:, 1])
    clearance = truth[:, 2] - ground
    # The chassis centre stays above the terrain by about its nominal height (0.475 m
    # on level ground; less where the ground under the centre bulges between the wheels,
    # measured down to 0.247 m).
    assert clearance.min() > 0.2 and clearance.max() < 1.0  # never airborne
    assert np.abs(truth[:, 6:9]).max() < 1.0  # no blow-up (m/s)
    assert summary["parked"] is not None and summary["parked"]["drift_m"] < 0.01
    assert summary["link"]["uplink"]["dropped"] == 0
    # The ground judged every goal reached on the downlinked estimate; truth agrees
    # within the estimate's drift (no position fix on board: 2-4 % of the distance).
    assert [g["status"] for g in summary["ground"]["goals"]] == ["reached"] * 3
    assert summary["goals"][0]["reached"]
    drift = summary["localization"]["final_position_error_m"]
    assert all(g.get("final_distance_m", g["closest_m"]) < drift + 1.0 for g in summary["goals"])
    assert drift < 0.05 * rv["distance_m"]
    # The estimate's sigma means something: the horizontal position NEES over the run
    # (2 when consistent; 0.46 with the earlier, 4x too wide slip sigma; 2.7 measured)
    assert 0.5 < summary["localization"]["position_nees"]["mean"] < 4.0
    assert summary["hazards"]["strikes"] == 0 and summary["modes"]["safings"] == {}


def test_the_logged_ports_are_recorded_each_as_itself(small_site):
    """``build_mission`` logs every port of ``LOGGED_PORTS`` the mission has through one
    sink; ``collect_logs`` hands each port back with its own columns: at the run's last
    sample (the end time is a logging instant) they are the port's own value."""
    import dataclasses as dc

    from lunar_drake.simulation import LOGGED_PORTS, build_mission, collect_logs, run_mission

    scenario, site = small_site
    scenario = dc.replace(
        scenario,
        simulation_duration=0.5,
        sensors=dc.replace(
            scenario.sensors, camera=dc.replace(scenario.sensors.camera, enabled=False)
        ),
    )
    run = build_mission(scenario=scenario, site=site)
    logs = collect_logs(run, stop_reason=run_mission(run))
    mctx = run.mission.GetMyContextFromRoot(run.simulator.get_context())
    names = [n for n in LOGGED_PORTS if run.mission.HasOutputPort(n)]
    assert sorted(logs.vectors) == sorted(names) and len(names) >= 14
    n = round(0.5 / scenario.logging.period_s) + 1
    for name in names:
        v = logs.vectors[name]
        assert v.data.shape == (n, len(LOGGED_PORTS[name])), name
        np.testing.assert_array_equal(v.times, logs.vectors["truth.pose"].times)
        np.testing.assert_array_equal(v.data[-1], run.mission.GetOutputPort(name).Eval(mctx))
