"""benchmarks/step_budget.py: exclusive time per system, nested calls charged once, the
methods put back, and a real run whose parts add up to its CPU time."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import step_budget as sb  # noqa: E402


class _FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_nested_calls_are_charged_exclusively():
    clock = _FakeClock()
    ledger = sb.Ledger(clock=clock)

    def inner():
        clock.t += 3.0

    def outer():
        clock.t += 1.0
        w_inner()
        clock.t += 0.5
        w_inner()

    w_inner = ledger.wrap(inner, "B")
    w_outer = ledger.wrap(outer, "A")
    w_outer()
    w_inner()
    assert ledger.seconds["A"] == pytest.approx(1.5)
    assert ledger.seconds["B"] == pytest.approx(9.0)
    assert ledger.calls == {"A": 1, "B": 3}
    assert ledger.drake_calls == 2  # outer, and the second inner: entered with none running
    assert sum(ledger.seconds.values()) == pytest.approx(clock.t)


def test_an_exception_still_charges_and_unwinds():
    clock = _FakeClock()
    ledger = sb.Ledger(clock=clock)

    def boom():
        clock.t += 2.0
        raise ValueError("x")

    w = ledger.wrap(boom, "C")
    with pytest.raises(ValueError):
        w()
    assert ledger.seconds["C"] == pytest.approx(2.0) and ledger._stack == []


def test_instrument_and_restore_put_every_method_back():
    classes = sb.leaf_system_classes()
    names = {c.__name__ for c in classes}
    assert {"WheelRegolithContact", "StateEstimator", "CommandExecutor", "Imu"} <= names
    before = {(c, k): v for c in classes for k, v in vars(c).items()}
    undo = sb.instrument(sb.Ledger(), classes)
    assert undo and all(getattr(c, k).__wrapped__ is v for c, k, v in undo)
    sb.restore(undo)
    assert {(c, k): v for c in classes for k, v in vars(c).items()} == before


def test_a_short_run_accounts_for_its_cpu_time(tmp_path, capsys):
    out = tmp_path / "budget.json"
    assert sb.main(["--scenario", "small", "--sim-s", "1", "--warmup-s", "0.2",
                    "--out", str(out)]) == 0  # fmt: skip
    r = json.loads(out.read_text())
    rows = {s["name"]: s for s in r["systems"]}
    # the plant's contact runs every 10 ms step, the executor at its 50 Hz
    assert rows["WheelRegolithContact"]["calls_per_s"] >= 100
    assert rows["CommandExecutor"]["calls_per_s"] >= 50
    step_cpu = r["instrumented"]["cpu_s"] * r["step_ms"] / r["sim_s"]  # ms a step
    # our methods' time is measured, not derived: it must fit inside the CPU time
    assert sum(s["ms_per_step"] for s in r["systems"]) == pytest.approx(r["python_ms_per_step"])
    assert 0 < r["python_ms_per_step"] < step_cpu
    assert r["rest"]["ms_per_step"] == pytest.approx(step_cpu - r["python_ms_per_step"])
    assert r["bound_rtf"] == pytest.approx(r["step_ms"] / r["rest"]["ms_per_step"])
    # the floor adds the calls Drake makes (at least the contact's and executor's updates)
    # at a trivial update's body each: between the rest and the step's CPU time
    tr = r["trivial_system"]
    assert tr["calls"] == tr["systems"] * round(tr["sim_s"] / 0.01)
    assert 0 < tr["body_s"] and 0 < tr["dispatch_s"]
    assert r["calls_per_step"] >= 1 + 0.5  # contact every step, executor every other
    assert r["rest"]["ms_per_step"] < r["floor_ms_per_step"] < step_cpu
    assert r["floor_rtf"] == pytest.approx(r["step_ms"] / r["floor_ms_per_step"])
    assert r["plain"]["final_xy_m"] == r["instrumented"]["final_xy_m"]
    assert "the rest (Drake, plant, bindings)" in capsys.readouterr().out
