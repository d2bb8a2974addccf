"""The neutron spectrometer on the rover: a plant sensor whose records reach the ground
only through the downlink (seams, nss.csv, scoring)."""

import csv

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
    assert 0.3 < summary["science"]["lcs_rmse_K"] < 3.0  # the 1 K noise, a few samples
    outputs.write_run(tmp_path, scenario=s, logs=logs, summary=summary, timing=logs.wall)
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
