"""The neutron spectrometer on the rover: a plant sensor whose records reach the ground
only through the downlink (seams, nss.csv, scoring)."""

import csv
import math

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator

from lunar_drake.diagrams.flight import flight_inputs
from lunar_drake.diagrams.mission import MakeMissionDiagram
from lunar_drake.diagrams.plant import INSTRUMENT_PORTS, SENSOR_PORTS
from lunar_drake.scenario_files import apply_overrides
from lunar_drake.science.nss import HydrogenMap, NSSConfig, count_rates
from lunar_drake.systems.neutron_spectrometer import NeutronSpectrometer

NSS_ON = "{sensors: {nss: {enabled: true, rate_hz: 2.0}, nirvss: {enabled: true}}}"


def _counts(ice_wt_pct: float, seconds: float = 30.0) -> np.ndarray:
    n = 80
    hmap = HydrogenMap.centred(
        dry_layer_m=np.zeros((n, n)),
        ice_wt_pct=np.full((n, n), ice_wt_pct),
        h_minerals_ppm=np.zeros((n, n)),
        resolution_m=0.1,
    )
    cfg = NSSConfig(rate_hz=2.0, x_m=0.0)
    nss = NeutronSpectrometer(body_index=0, hmap=hmap, seed=3, config=cfg)
    sim = Simulator(nss)
    ctx = sim.get_mutable_context()
    nss.body_poses_input.FixValue(ctx, [RigidTransform()])
    out = []
    for k in range(1, int(seconds * 2) + 1):
        sim.AdvanceTo(k / 2.0)
        out.append(nss.measurement_output.Eval(ctx).copy())
    return np.array(out)


def test_the_sensor_counts_fewer_epithermal_neutrons_over_ice():
    dry, icy = _counts(0.0), _counts(4.0)
    cfg = NSSConfig(rate_hz=2.0)
    epi_dry, _ = count_rates(0.0, config=cfg)
    epi_icy, _ = count_rates(4.0 * 1.0, config=cfg)  # all of the depth weight: no dry layer
    assert dry[:, 0].mean() == pytest.approx(epi_dry / 2.0, rel=0.03)
    assert icy[:, 0].mean() == pytest.approx(epi_icy / 2.0, rel=0.03)
    assert icy[:, 1].mean() > dry[:, 1].mean()  # thermal neutrons rise
    assert np.all(dry == np.round(dry))  # counts


def test_nss_records_reach_the_ground_only_through_the_downlink(small_site, tmp_path):
    from lunar_drake import metrics, outputs
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    s = apply_overrides(scenario, NSS_ON)
    diagram = MakeMissionDiagram(scenario=s, site=site)
    assert "rover.nss" in flight_inputs(s)
    cm = diagram.connection_map()
    flight, ground = diagram.GetSubsystemByName("flight"), diagram.GetSubsystemByName("ground")
    for (dst, k), (src, j) in cm.items():
        name = src.get_output_port(j).get_name()
        if dst is flight and dst.get_input_port(k).get_name() == "rover.nss":
            assert src.get_name() == "plant" and name in INSTRUMENT_PORTS
            assert name not in SENSOR_PORTS  # an instrument, fed like a sensor
        if dst is ground and dst.get_input_port(k).get_name() == "downlink.science":
            assert (src.get_name(), name) == ("downlink", "science")
    logs = simulate(scenario=apply_overrides(s, "{simulation_duration: 4.0}"), site=site)
    recs = [r for _t, r in logs.science_received if r.instrument == "nss"]
    assert [r.index for r in recs] == list(range(len(recs))) and len(recs) >= 7
    nir = [r for _t, r in logs.science_received if r.instrument == "nirvss"]
    assert [r.index for r in nir] == list(range(len(nir))) and len(nir) >= 2
    assert all(t >= r.t_sample_s for t, r in logs.science_received)  # after the link
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    assert summary["science"]["nss_records"] == len(recs)
    assert summary["science"]["nirvss_records"] == len(nir)
    sci = summary["science"]
    for k in ("footprint", "world"):  # scored cells only
        assert (sci[f"nss_{k}_bias_wt_pct"] is None) == (sci[f"nss_{k}_cells"] == 0)
    assert sci["nss_world_cells"] <= sci["nss_cells_seen"]
    assert 0.3 < sci["lcs_spot_rmse_K"] < 3.0  # the 1 K noise, a few samples
    assert sci["lcs_world_cells"] >= 1 and sci["lcs_world_rmse_K"] is not None
    assert set(sci["nirvss_world"]) >= {"oh", "plagioclase"}
    outputs.write_run(tmp_path, scenario=s, logs=logs, summary=summary, timing=logs.wall, site=site)
    import rasterio

    for stem, n_bands, n_records in (("nss_map", 4, len(recs)), ("nirvss_map", 8, len(nir)),
                                     ("lcs_map", 2, len(nir))):  # fmt: skip
        assert (tmp_path / f"{stem}.png").stat().st_size > 1000
        with rasterio.open(tmp_path / f"{stem}.tif") as ds:
            assert ds.count == n_bands and ds.crs is not None and ds.res == (2.0, 2.0)
            assert ds.descriptions[-1] == "records"
            a = ds.read()
        shown = a[-2] if stem == "nss_map" else a[0]  # NSS: the share, in every seen cell
        assert np.isfinite(shown).any() and np.isnan(shown).any()  # cells with and without
        assert a[-1].sum() == n_records and np.isnan(a[0][a[-1] == 0]).all()
    ox, oy = site.heightfield.origin_xy
    cfg = s.sensors.nss
    with rasterio.open(tmp_path / "nss_map.tif") as ds:
        assert ds.descriptions == ("weh_wt_pct", "weh_sigma_wt_pct", "footprint_share",
                                   "records")  # fmt: skip
        weh, sigma, share, count = ds.read()
        cells = {}
        for r in recs:  # each record in the cell of its footprint, 0.9 m ahead
            yaw = r.pose_estimate[5]
            row, col = ds.index(ox + r.pose_estimate[0] + cfg.x_m * math.cos(yaw),
                                oy + r.pose_estimate[1] + cfg.x_m * math.sin(yaw))  # fmt: skip
            cells.setdefault((row, col), []).append(r)
        for (row, col), rs in cells.items():  # the cell's pooled counts, inverted
            n = sum(r.values[0] for r in rs)
            t = sum(r.integration_s for r in rs)
            assert count[row, col] == len(rs) and 0.0 < share[row, col] < 1.0
            if share[row, col] < 0.5:  # most of what it measured lies outside the cell
                assert np.isnan(weh[row, col]) and np.isnan(sigma[row, col])
                continue
            assert weh[row, col] == pytest.approx((250.0 * t / n - 1.0) / 0.2, abs=1e-5)
            assert sigma[row, col] == pytest.approx(250.0 * t / (0.2 * n**1.5), rel=1e-5)
    with open(tmp_path / "nss.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == outputs.NSS_COLUMNS and len(rows) == len(recs)
    assert float(rows[3]["epithermal_counts"]) > 0
    assert (tmp_path / "nss_map.png").stat().st_size > 1000
    with open(tmp_path / "nirvss.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(nir) and "bd_oh" in rows[0] and float(rows[-1]["bd_oh"]) > 0
    with open(tmp_path / "lcs.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(nir) and 20.0 < float(rows[-1]["temperature_K"]) < 450.0


def test_drill_requests_beyond_a_metre_are_refused(tmp_path, capsys):
    from lunar_drake.cli import main
    from lunar_drake.errors import ConfigError, OutOfRangeError
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.science.drill import check_drill_request

    assert check_drill_request(0.5, 0.1) == 5
    with pytest.raises(OutOfRangeError, match=r"depth_m = 1\.2 .*the drill reaches 1 m"):
        check_drill_request(1.2, 0.1)
    with pytest.raises(OutOfRangeError, match=r"step_m = 0\.6"):
        check_drill_request(0.5, 0.6)
    text = ("{sensors: {nirvss: {enabled: true}, drill: {enabled: true}}, ground: {actions: "
            "[{t_s: 1.0, action: drill, depth_m: 1.5}]}}")  # fmt: skip
    with pytest.raises(OutOfRangeError, match=r"ground.actions\[0\].depth_m = 1.5"):
        load_scenario(scenario_name="small", scenario_text=text)
    with pytest.raises(ConfigError, match=r"needs sensors\.nirvss\.enabled"):
        load_scenario(scenario_name="small", scenario_text="{sensors: {drill: {enabled: true}}}")
    code = main(["run", "--scenario", "small", "--scenario-text", text, "--no-meshcat",
                 "--out", str(tmp_path / "r")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "1.5" in err


def test_the_drill_brings_up_samples_that_nirvss_reads(small_site, tmp_path):
    from lunar_drake import metrics, outputs
    from lunar_drake.science.nirvss import spot_means
    from lunar_drake.science.world import surface_map
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    # The hole lands in a cold pit (T_max 51 K, mean 34 K): an ice stability of 42 K and a
    # 0.3 m skin depth put its dry layer between the samples (about 0.16 m), and 5 wt% of
    # ice below it is 40 sigmas of NIRVSS's lamp noise, so every sample tells.
    s = apply_overrides(scenario, (
        "{simulation_duration: 15.0, sensors: {nirvss: {enabled: true}, drill: {enabled: true,"
        " seconds_per_step: 2.0}}, ground: {route: [{duration_s: 1.0}], actions: [{t_s: 2.5,"
        " action: drill, depth_m: 0.5, step_m: 0.1}]}, science: {ice: {stable_K: 42.0,"
        " skin_depth_m: 0.3, background_wt_pct: 5.0}}}"))  # fmt: skip
    logs = simulate(scenario=s, site=site)
    recs = [r for _t, r in logs.science_received if r.instrument == "drill"]
    assert [round(r.values[1], 6) for r in recs] == [0.1, 0.2, 0.3, 0.4, 0.5]
    assert [int(r.values[0]) for r in recs] == [1, 2, 3, 4, 5]
    # Truth at the hole: the drill 0.6 m ahead of the chassis when it started.
    pose = logs.vectors["truth.pose"]
    k = int(np.searchsorted(pose.times, 3.0))
    x, y, yaw = pose.data[k, 0], pose.data[k, 1], pose.data[k, 5]
    spot = spot_means(surface_map(scenario=s, site=site), x + 0.6 * np.cos(yaw),
                      y + 0.6 * np.sin(yaw), radius_m=0.05)  # fmt: skip
    cfg = s.sensors.nirvss
    dry, ice = spot["dry_layer_m"], spot["ice_wt_pct"]
    assert 0.1 < dry < 0.5 and ice >= 5.0  # samples on both sides of the dry layer
    for r in recs:  # none above the dry layer, the ice below it
        truth = ice if r.values[1] >= dry else 0.0
        assert r.values[2] / cfg.ice_per_wt_pct == pytest.approx(
            truth, abs=4 * cfg.sigma_lamp / cfg.ice_per_wt_pct
        )
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    sci = summary["science"]
    assert sci["drill_samples"] == 5
    # Scored against the world where the ground puts the hole (0.6 m ahead of its
    # estimate at the first sample): the world's layers over the 0.1 m square about it,
    # sampled here every 1 mm, each sample reading its own pixel.
    (hole,) = sci["drill_holes"]
    e = recs[0].pose_estimate
    hx, hy = e[0] + 0.6 * math.cos(e[5]), e[1] + 0.6 * math.sin(e[5])
    smap = surface_map(scenario=s, site=site)
    u = np.arange(-0.0495, 0.05, 0.001)
    cols = np.floor((hx + u - smap.x0_m) / smap.resolution_m).astype(int)
    rows = np.floor((smap.y1_m - (hy + u)) / smap.resolution_m).astype(int)
    dry_w, ice_w = (float(smap.layers[k][np.ix_(rows, cols)].mean())
                    for k in ("dry_layer_m", "ice_wt_pct"))  # fmt: skip
    assert hole["hole_xy_est_m"] == pytest.approx([hx, hy], abs=1e-4)
    assert hole["dry_layer_world_m"] == pytest.approx(dry_w, abs=2e-3)
    assert hole["ice_world_wt_pct"] == pytest.approx(ice_w, rel=2e-3)
    icy = [r.values[1] for r in recs if r.values[2] > 3 * cfg.sigma_lamp]
    assert hole["dry_layer_est_m"] == pytest.approx(icy[0]) and icy[0] >= dry
    assert hole["dry_layer_bracketed"] == (icy[0] - 0.1 < dry_w <= icy[0])
    world = [ice_w if r.values[1] >= dry_w else 0.0 for r in recs]
    got = [r.values[2] / cfg.ice_per_wt_pct for r in recs]
    assert sci["drill_world_rmse_wt_pct"] == pytest.approx(
        math.sqrt(np.mean(np.square(np.subtract(got, world)))), abs=1e-5)
    outputs.write_run(tmp_path, scenario=s, logs=logs, summary=summary, timing=logs.wall)
    with open(tmp_path / "drill.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == outputs.DRILL_COLUMNS and [r["depth_m"] for r in rows][-1] == "0.5"
    for row, r in zip(rows, recs, strict=True):  # the hole, 0.6 m ahead of the estimate
        x_e, y_e, yaw_e = r.pose_estimate[0], r.pose_estimate[1], r.pose_estimate[5]
        assert float(row["hole_x_est_m"]) == pytest.approx(x_e + 0.6 * math.cos(yaw_e), abs=1e-5)
        assert float(row["hole_y_est_m"]) == pytest.approx(y_e + 0.6 * math.sin(yaw_e), abs=1e-5)
        assert float(row["yaw_est_rad"]) == pytest.approx(yaw_e, abs=1e-6)


def test_a_run_says_when_it_builds_its_world_model(tmp_path, monkeypatch, capsys):
    """A run with a science sensor builds the site's world model before the diagram, with
    a line saying so and where it is cached; the next run finds it cached."""
    from lunar_drake.cli import main

    monkeypatch.setenv("LUNAR_DRAKE_CACHE", str(tmp_path / "cache"))
    args = ["run", "--scenario", "small", "--scenario-text", "{sensors: {nss: {enabled: true}}}",
            "--duration", "0.5", "--no-meshcat", "--no-progress"]  # fmt: skip
    lines = []
    for i in range(2):
        assert main([*args, "--out", str(tmp_path / f"r{i}")]) == 0
        lines.append([s for s in capsys.readouterr().out.splitlines() if "World model:" in s])
    assert len(lines[0]) == 1 and "World model: built in" in lines[0][0]
    assert str(tmp_path / "cache" / "worlds") in lines[0][0]
    assert len(lines[1]) == 1 and "World model: cached in" in lines[1][0]
