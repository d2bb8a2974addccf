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

    w_inner = ledger.wrap(inner, label="B")
    w_outer = ledger.wrap(outer, label=lambda args: "A")
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

    w = ledger.wrap(boom, label="C")
    with pytest.raises(ValueError):
        w()
    assert ledger.seconds["C"] == pytest.approx(2.0) and ledger._stack == []


def test_an_inactive_ledger_times_nothing():
    clock = _FakeClock()
    ledger = sb.Ledger(clock=clock)
    ledger.active = False
    ledger.wrap(lambda: setattr(clock, "t", 5.0), label="D")()
    assert not ledger.seconds and not ledger.calls and ledger.drake_calls == 0


def test_instrument_and_restore_put_every_method_back():
    classes = sb.leaf_system_classes()
    names = {c.__name__ for c in classes}
    assert {"WheelRegolithContact", "StateEstimator", "CommandExecutor", "Imu"} <= names
    before = {(c, k): v for c in classes for k, v in vars(c).items()}
    undo = sb.instrument(ledger=sb.Ledger(), classes=classes)
    methods = [(c, k, v) for c, k, v in undo if k not in sb._OUTPUT_DECLARATIONS]
    assert methods and all(getattr(c, k).__wrapped__ is v for c, k, v in methods)
    sb.restore(undo=undo)
    assert {(c, k): v for c, k, v in ((c, k, v) for c in classes for k, v in vars(c).items())} \
        == before  # fmt: skip


def test_calls_are_charged_to_the_instance_class_and_lambdas_are_timed():
    """An inherited method is charged to the subclass it runs for; an output port
    declared with a lambda is timed too (it would otherwise sit in "the rest")."""
    from pydrake.systems.framework import BasicVector, LeafSystem

    class Base(LeafSystem):
        def __init__(self):
            super().__init__()
            self.DeclareVectorOutputPort("y", BasicVector(1), lambda c, o: o.SetAtIndex(0, 2.0))

        def helper(self):
            return 1

    class Child(Base):
        pass

    ledger = sb.Ledger()
    undo = sb.instrument(ledger=ledger, classes=[Base, Child], by_method=True)
    try:
        child = Child()
        assert child.helper() == 1
        assert child.get_output_port().Eval(child.CreateDefaultContext())[0] == 2.0
    finally:
        sb.restore(undo=undo)
    assert ledger.calls == {"Child.helper": 1, "Child.<y>": 1}
    assert "DeclareVectorOutputPort" not in vars(Child) and "helper" in vars(Base)


def test_a_short_run_accounts_for_its_cpu_time(tmp_path, capsys):
    out = tmp_path / "budget.json"
    assert sb.main(["--scenario", "small", "--sim-s", "1", "--warmup-s", "0.2",
                    "--out", str(out)]) == 0  # fmt: skip
    r = json.loads(out.read_text())
    rows = {s["name"]: s for s in r["systems"]}
    # the plant's contact runs every 10 ms step, the executor at its 50 Hz
    assert rows["WheelRegolithContact"]["calls_per_s"] >= 100
    assert rows["CommandExecutor"]["calls_per_s"] >= 50
    step_ms = r["instrumented"]["wall_s"] * r["step_ms"] / r["sim_s"]  # ms a step
    # our code's time is measured by the same clock as the run: it fits inside it, and
    # Drake's part (the plant's step at least) is left over
    assert 0 < r["python_ms_per_step"] < step_ms
    assert 0 < r["rest"]["ms_per_step"] < step_ms
    # the ring counts its own calls: 10 systems at 100 Hz
    tr = r["trivial_system"]
    assert tr["calls"] == tr["systems"] * round(tr["sim_s"] / 0.01)
    assert 0 < tr["body_s"] and 0 < tr["dispatch_s"]
    assert r["calls_per_step"] >= 1 + 0.5  # contact every step, executor every other
    assert r["rest"]["ms_per_step"] < r["floor_ms_per_step"] < step_ms
    assert "the rest (Drake, plant, bindings)" in capsys.readouterr().out
    # the timers are gone afterwards
    assert not any(sb._is_timed(f) for c in sb.leaf_system_classes() for f in vars(c).values())


@pytest.mark.parametrize(
    ("args", "says"),
    [(["--scenario", "nope"], "scenario 'nope' not found"),
     (["--out", "/nonexistent/dir/budget.json"], "does not exist")],
)  # fmt: skip
def test_bad_input_is_one_line_and_exit_2(args, says, tmp_path):
    import subprocess

    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "step_budget.py"), *args],
                       capture_output=True, text=True, timeout=300, cwd=tmp_path)  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert says in r.stderr and len(r.stderr.strip().splitlines()) == 1
