"""lunar-drake vo-study (studies/vo_study.py): VO against fused odometry on rendered
stereo pairs, on the small site at 320 x 240 (the study's own figures are in the docs)."""

import csv
import json
import math

import pytest

from lunar_drake.cli import main
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.studies.vo_study import CSV_COLUMNS, VoStudyConfig, parse_angles, summarize

SMALL = ["--scenario", "small", "--width", "320", "--height", "240", "--spawn-radius", "2",
         "--seeds", "1", "--no-progress"]  # fmt: skip


def test_parse_angles_and_config_errors():
    assert parse_angles("0:20:10") == (0.0, 10.0, 20.0)
    assert parse_angles("5,50") == (5.0, 50.0)
    with pytest.raises(ConfigError, match="--angles"):
        parse_angles("10:0:5")
    with pytest.raises(OutOfRangeError, match="angle"):
        VoStudyConfig(angles_deg=(200.0,)).validate()
    with pytest.raises(OutOfRangeError, match="turn_rate_dps"):
        VoStudyConfig(turn_rate_dps=0.0).validate()
    with pytest.raises(OutOfRangeError, match="baseline_m"):
        VoStudyConfig(baseline_m=0.0).validate()


def test_rotation_study_writes_vo_csv_and_png(tmp_path, capsys):
    out = tmp_path / "vo"
    assert main(["vo-study", "--angles", "0,15", "--images", "--out", str(out), *SMALL]) == 0
    assert "Outputs:" in capsys.readouterr().out
    rows = list(csv.DictReader(open(out / "vo.csv")))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 2
    still, turned = rows
    # standing still, the estimate barely moves; the turn is a real turn in place, by
    # the angle asked for (the command lengthened by the measured turn efficiency)
    assert float(still["odom_error_m"]) < 0.005 and float(still["true_rotation_deg"]) < 0.1
    assert 0.5 < float(turned["turn_efficiency"]) < 1.0
    assert abs(float(turned["true_rotation_deg"]) - 15.0) < 1.0
    for r in rows:  # VO as the ground uses it: the odometry where it was rejected
        used = r["odom_error_m"] if r["rejected"] == "1" else r["vo_error_m"]
        assert r["used_error_m"] == used
    images = sorted(p.name for p in (out / "images").iterdir())
    assert images == ["a0_s0_0.png", "a0_s0_1.png", "a15_s0_0.png", "a15_s0_1.png"]
    assert float(turned["true_translation_m"]) < 0.5  # the mast swings round the chassis
    for r in rows:
        assert math.isfinite(float(r["vo_error_m"])) and r["rejected"] in ("0", "1")
    assert (out / "vo.png").stat().st_size > 10_000
    assert json.loads((out / "params.json").read_text())["config"]["angles_deg"] == [0.0, 15.0]
    from lunar_drake.scenario_files import load_scenario

    d = load_scenario(scenario_name="small").rover.description
    assert float(rows[0]["baseline_m"]) == d.camera_baseline_m
    assert float(rows[0]["mast_height_m"]) == d.mast_height_m
    # on the trade-study engine (two dask workers, each loading the site itself): the
    # same runs, the same bytes
    again = tmp_path / "vo_on_dask"
    assert main(["vo-study", "--angles", "0,15", "--workers", "2", "--out", str(again),
                 *SMALL]) == 0  # fmt: skip
    assert (again / "vo.csv").read_bytes() == (out / "vo.csv").read_bytes()


def test_straight_study_writes_straight_json(tmp_path):
    out = tmp_path / "straight"
    assert main(["vo-study", "--straight", "2", "--keyframe", "0.5", "--out", str(out),
                 *SMALL]) == 0  # fmt: skip
    doc = json.loads((out / "straight.json").read_text())
    assert {"distance_m", "vo_error_m", "odom_error_m"} <= set(doc)
    # the ground stopped it at the distance by the on-board estimate (slip included)
    assert 1.8 < doc["distance_m"] < 2.2 and doc["links"] >= 3
    assert 0 <= doc["rejected"] <= doc["links"]


def test_summary_counts_bad_alignments_let_through():
    rows = [
        {"angle_deg": 10.0, "vo_error_m": 0.01, "odom_error_m": 0.02, "rejected": False},
        {"angle_deg": 10.0, "vo_error_m": 0.30, "odom_error_m": 0.02, "rejected": True},
        {"angle_deg": 10.0, "vo_error_m": 0.05, "odom_error_m": 0.02, "rejected": False},
    ]
    (s,) = summarize(rows)
    assert s["runs"] == 3 and s["rejected"] == 1 and s["bad"] == 2 and s["bad_accepted"] == 1
    assert s["vo_accepted_error_m"] == pytest.approx(0.03)
    assert s["vo_error_m"] == pytest.approx(0.12)
