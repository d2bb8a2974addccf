"""Tests for lunar_drake.studies.slip_fit, lunar_drake.dynamics.soil_io and `slip-fit`."""

from __future__ import annotations

import dataclasses as dc
import math
import re

import numpy as np
import pytest

from lunar_drake.cli import main
from lunar_drake.dynamics.soil_io import JSC1A, load_soil, soil_yaml
from lunar_drake.dynamics.terramechanics import LUNAR_REGOLITH, SoilParams
from lunar_drake.errors import ConfigError
from lunar_drake.studies import slip_fit as sf

TRUE = dc.replace(LUNAR_REGOLITH, name="true", phi=math.radians(30.0), K=0.025, K_y=0.025)
SLOPES = np.array([0.0, 2.0, 4.0, 6.0, 8.0, 10.0])  # this soil immobilizes krex2 at ~11 deg


@pytest.fixture(scope="module")
def clean():
    """Noise-free reference slips of the explicit rover on TRUE at SLOPES."""
    return sf.model_slips(slopes_deg=SLOPES, rover="explicit", soil=TRUE)


def _noisy(clean, repeats=3, seed=11):
    rng = np.random.default_rng(seed)
    a = np.repeat(SLOPES, repeats)
    return a, np.repeat(clean, repeats) + rng.normal(0.0, 0.01, a.size)


def _write_csv(path, slopes, slips, header="slope_deg,slip"):
    rows = [header] + [f"{a:g},{s:.6f}" for a, s in zip(slopes, slips, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_fit_recovers_the_generating_soil(clean):
    a, s = _noisy(clean)
    fit = sf.fit_soil(data=sf.SlipData(slope_deg=a, slip=s), rover="explicit",
                      base_soil=LUNAR_REGOLITH)  # fmt: skip
    assert fit.rms_pp < 2.0  # 1 pp noise
    assert math.degrees(fit.soil.phi) == pytest.approx(30.0, abs=1.0)
    assert fit.soil.K == pytest.approx(0.025, rel=0.1)
    assert fit.soil.K_y == fit.soil.K  # the isotropic base stays isotropic
    assert fit.soil.c == LUNAR_REGOLITH.c and fit.soil.k_phi == LUNAR_REGOLITH.k_phi
    assert fit.soil.name == "lunar_regolith_fit"
    grid = np.linspace(0.0, 10.0, 6)
    curve = sf.model_slips(slopes_deg=grid, rover="explicit", soil=fit.soil)
    truth = sf.model_slips(slopes_deg=grid, rover="explicit", soil=TRUE)
    assert np.max(np.abs(curve - truth)) < 0.015
    # The base soil is far off: the fit really moved.
    assert 100 * math.sqrt(np.mean((fit.base_slip - s) ** 2)) > 10.0
    assert 0.0 < fit.stderr["phi"] < math.radians(1.0)
    assert 0.0 < fit.stderr["K"] < 0.005


def test_cli_writes_the_three_files(tmp_path, clean, capsys):
    a, s = _noisy(clean, repeats=1, seed=3)
    data = _write_csv(tmp_path / "data.csv", a, s)
    out = tmp_path / "fit"
    assert main(["slip-fit", str(data), "--rover", "explicit", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "phi = " in printed and "RMS residual" in printed
    assert sorted(p.name for p in out.iterdir()) == ["fit.csv", "fit.png", "soil.yaml"]
    lines = (out / "fit.csv").read_text().splitlines()
    assert lines[0] == "slope_deg,measured_slip,fitted_slip"
    assert len(lines) == 1 + len(a)
    assert (out / "fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    soil = load_soil(str(out / "soil.yaml"))
    assert math.degrees(soil.phi) == pytest.approx(30.0, abs=1.5)
    # The file is a scenario's soil section, as written.
    from lunar_drake.scenario_files import scenario_from_text

    scenario = scenario_from_text((out / "soil.yaml").read_text())
    assert scenario.soil == soil


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (None, "does not exist"),
        ("slope,slip\n1,0.1\n", "no column 'slope_deg'"),
        ("slope_deg,s\n1,0.1\n", "no column 'slip'"),
        ("slope_deg,slip\n0,0.1\n5,abc\n10,0.3\n", r"line 3: slip = 'abc' is not a number"),
        ("slope_deg,slip\n0,0.1\n5,nan\n10,0.3\n", "line 3: slip = 'nan' must be finite"),
        ("slope_deg,slip\n0,0.1\n5,1.0\n10,0.3\n", r"slip = 1 is out of range; allowed \[0, 1\)"),
        ("slope_deg,slip\n0,-0.1\n5,0.2\n10,0.3\n", "slip = -0.1 is out of range"),
        ("slope_deg,slip\n0,0.1\n5,0.2\n5,0.25\n", "2 distinct slope"),
        ("slope_deg,slip\n0,10\n5,20\n10,30\n", "slip = 10 is out of range"),
        ("", "is empty"),
    ],
)
def test_bad_data_files(tmp_path, capsys, text, match):
    path = tmp_path / "data.csv"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError, match=match) as e:
        sf.read_slip_data(path)
    assert "\n" not in str(e.value)
    # The command line: exit 2, one line, no traceback, nothing written.
    out = tmp_path / "out"
    assert main(["slip-fit", str(path), "--rover", "skid", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and "ConfigError" in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("slopes", "slips", "why"),
    [
        # 90 % slip on gentle slopes: only soils that cannot climb them come close.
        ([1.0, 2.0, 3.0], [0.9, 0.92, 0.95], "cannot climb 1 deg, where the data has slip 0.9"),
        # Slip falling and rising with slope: no monotone model curve comes near it.
        ([0.0, 5.0, 10.0], [0.9, 0.05, 0.9], r"leaves an RMS residual of \d+\.\d pp > 10 pp"),
    ],
)
def test_unreachable_data_is_rejected(tmp_path, capsys, slopes, slips, why):
    path = _write_csv(tmp_path / "d.csv", slopes, slips)
    assert main(["slip-fit", str(path), "--rover", "explicit", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no soil with phi in [15, 55] deg and K in [0.05, 10] cm fits the data" in err
    assert re.search(why, err) and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_bad_rover_and_base_soil(tmp_path, clean):
    a, s = _noisy(clean, repeats=1)
    data = _write_csv(tmp_path / "data.csv", a, s)
    with pytest.raises(ConfigError, match="rover = 'tracked' is unknown"):
        sf.run_slip_fit(data_path=data, rover="tracked", out_dir=tmp_path / "o")
    with pytest.raises(ConfigError, match="soil 'clay' is neither a preset"):
        sf.run_slip_fit(data_path=data, rover="skid", out_dir=tmp_path / "o", base_soil="clay")
    with pytest.raises(SystemExit):  # argparse: --rover has choices
        main(["slip-fit", str(data), "--rover", "tracked", "--out", str(tmp_path / "o")])


# ---------------------------------------------------------------------------- soil_io
def test_load_soil_presets_and_round_trip(tmp_path):
    assert load_soil("lunar_regolith") == LUNAR_REGOLITH
    assert load_soil("GRC-1").name == "grc1"
    for name in ("jsc1a", "JSC-1A", "jsc_1a"):
        j = load_soil(name)
        assert j == JSC1A and j is not JSC1A
    soil = dc.replace(JSC1A, name="mine", phi=0.6)
    path = tmp_path / "s.yaml"
    path.write_text(soil_yaml(soil, comment="a comment\nsecond line"))
    assert path.read_text().startswith("# a comment\n# second line\nsoil:\n")
    assert load_soil(str(path)) == soil
    bare = tmp_path / "bare.yml"
    bare.write_text("phi: 0.5\nK: 0.02\n")  # no 'soil:' level; the rest from the defaults
    assert load_soil(bare) == dc.replace(SoilParams(), phi=0.5, K=0.02)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (None, "does not exist"),
        ("soil: [1, 2]\n", "must hold a mapping"),
        ("soil:\n  phi: 0.5\n  friction: 3\n", "unknown key 'friction'"),
        ("soil:\n  phi: 2.0\n", r"phi = 2 is out of range"),
        ("soil:\n  K: fast\n", "K = 'fast' must be a real number"),
        ("soil: {phi: [\n", "is not valid YAML"),
    ],
)
def test_load_soil_bad_files(tmp_path, text, match):
    path = tmp_path / "soil.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ConfigError, match=match) as e:
        load_soil(str(path))
    assert "\n" not in str(e.value) and "soil.yaml" in str(e.value)


def test_load_soil_unknown_name():
    msg = r"'clay' is neither a preset \(grc1, jsc1a, lunar_regolith"
    with pytest.raises(ConfigError, match=msg):
        load_soil("clay")
    with pytest.raises(ConfigError, match="must be a preset name or a YAML file path"):
        load_soil(3.5)
