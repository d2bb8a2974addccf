"""Benchmark: where a simulated step's time goes, system by system.

    .venv/bin/python benchmarks/step_budget.py --out bench_step_budget.json
    .venv/bin/python benchmarks/step_budget.py --scenario-text '{}' --sim-s 20

Builds the scenario's mission diagram (default: the default scenario without cameras,
what ``mission_rate.py --no-cameras`` times), runs an untimed ``--warmup-s``, then
``--sim-s`` simulated seconds twice from fresh contexts:

1. **plain**: CPU seconds of this process, nothing instrumented (the real-time factor
   the breakdown below belongs to);
2. **instrumented**: every method of every ``LeafSystem`` class in
   :mod:`lunar_drake.systems` is wrapped in a timer before the diagram is built, and
   each call's *exclusive* wall time (its own, less that of the wrapped methods it
   calls) is charged to its class. Work a method does in Drake (an input port's
   ``Eval`` that computes another system's output in C++, the ``MultibodyPlant``'s
   ports) or in the functional core (``executor_step``, the numba kernels) is charged
   to the method that asked for it.

The table lists each class's ms per ``--step-ms`` (10 ms, the plant's step) of simulated
time, its calls per simulated second and its share; **the rest** is the instrumented
run's CPU time that no Python method of ours accounts for: Drake's simulator loop, the
plant's own discrete step, event dispatch, cache invalidation and pybind11's calls into
Python. ``--by-method`` gives a row per method instead. The rest per step bounds the
real-time factor any speed-up of our Python code could reach: ``step / rest``. A
tighter bound: a ring of trivial Python systems (each a 100 Hz update that reads one
input port and writes its state) times the cheapest such an update can be on this
machine (:func:`trivial_call_cost`): ``floor_ms_per_step`` = the rest + the calls Drake
makes into our methods a step (those entered with no timed method running; calls that
Drake makes from inside one, through an ``Eval``, are not counted, so the floor stays a
lower bound) x that update's own time (its Drake side is already in the rest). The
timers cost a little themselves (mostly charged to the methods): compare the two runs'
rates, printed on the first line.

JSON ``{plain, instrumented, systems: [{name, ms_per_step, calls_per_s, share}], rest,
bound_rtf, trivial_system, calls_per_step, floor_ms_per_step, floor_rtf, speed_index_s,
...}``.
"""

from __future__ import annotations

import argparse
import collections
import importlib
import inspect
import json
import os
import pkgutil
import sys
import time

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import measure_speed_index, speed_index_line
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import measure_speed_index, speed_index_line


class Ledger:
    """Exclusive wall time and calls per label, for nested timed calls (one thread: the
    simulator's; calls from other threads are not timed)."""

    def __init__(self, *, clock=time.perf_counter):
        import threading

        self.seconds = collections.defaultdict(float)
        self.calls = collections.Counter()
        self.drake_calls = 0  # calls entered with no timed method running: from Drake
        self._stack: list[float] = []
        self._thread = threading.get_ident()
        self._get_ident = threading.get_ident
        self._clock = clock

    def clear(self) -> None:
        self.seconds.clear()
        self.calls.clear()
        self.drake_calls = 0

    def wrap(self, fn, label: str):
        """``fn`` with its calls' exclusive time charged to ``label``."""
        clock, stack, seconds, calls = self._clock, self._stack, self.seconds, self.calls
        me, ident = self._thread, self._get_ident
        ledger = self

        def timed(*args, **kwargs):
            if ident() != me:
                return fn(*args, **kwargs)
            if not stack:
                ledger.drake_calls += 1
            t0 = clock()
            stack.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                dt = clock() - t0
                inner = stack.pop()
                seconds[label] += dt - inner
                calls[label] += 1
                if stack:
                    stack[-1] += dt

        timed.__wrapped__ = fn
        return timed


def leaf_system_classes():
    """Every ``LeafSystem`` subclass defined in a module of :mod:`lunar_drake.systems`."""
    from pydrake.systems.framework import LeafSystem

    import lunar_drake.systems as pkg

    out = []
    for info in pkgutil.iter_modules(pkg.__path__):
        mod = importlib.import_module(f"{pkg.__name__}.{info.name}")
        for _, cls in inspect.getmembers(mod, inspect.isclass):
            if issubclass(cls, LeafSystem) and cls.__module__ == mod.__name__:
                out.append(cls)
    return out


def instrument(ledger: Ledger, classes, *, by_method: bool = False) -> list:
    """Wraps the plain functions defined on each class (not dunders, not properties),
    charged to the class (``Class.method`` with ``by_method``); returns ``(cls, name,
    original)`` to :func:`restore`."""
    undo = []
    for cls in classes:
        for name, attr in list(vars(cls).items()):
            if name.startswith("__") or not inspect.isfunction(attr):
                continue
            label = f"{cls.__name__}.{name}" if by_method else cls.__name__
            setattr(cls, name, ledger.wrap(attr, label))
            undo.append((cls, name, attr))
    return undo


def restore(undo) -> None:
    for cls, name, attr in undo:
        setattr(cls, name, attr)


def trivial_call_cost(*, systems: int = 10, sim_s: float = 20.0, step_s: float = 0.01) -> dict:
    """The cheapest a useful Python system's update is here: a ring of ``systems``
    LeafSystems, each with a periodic discrete update (``step_s``) that reads its
    10-vector input port and writes its state (the next one's input), simulated
    ``sim_s``. ``body_s`` is the update's own time (timed inside it, like a method in
    the table), ``dispatch_s`` the rest of the CPU time, per call."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder, LeafSystem

    body = [0.0]
    clock = time.perf_counter

    class Trivial(LeafSystem):
        def __init__(self):
            super().__init__()
            self.u = self.DeclareVectorInputPort("u", 10)
            state = self.DeclareDiscreteState(10)
            self.DeclareStateOutputPort("y", state)
            self.DeclarePeriodicDiscreteUpdateEvent(step_s, 0.0, self._update)

        def _update(self, context, discrete_state):
            t0 = clock()
            discrete_state.set_value(0, self.u.Eval(context) * 0.5 + 1.0)
            body[0] += clock() - t0

    builder = DiagramBuilder()
    ring = [builder.AddSystem(Trivial()) for _ in range(systems)]
    for a, b in zip(ring, ring[1:] + ring[:1], strict=True):
        builder.Connect(a.get_output_port(), b.get_input_port())
    sim = Simulator(builder.Build())
    sim.Initialize()
    c0 = time.process_time()
    sim.AdvanceTo(sim_s)
    cpu = time.process_time() - c0
    calls = systems * round(sim_s / step_s)
    return {"systems": systems, "sim_s": sim_s, "cpu_s": cpu, "calls": calls,
            "body_s": body[0] / calls, "dispatch_s": (cpu - body[0]) / calls}  # fmt: skip


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenario", default="default")
    p.add_argument("--scenario-text", default="{sensors: {camera: {enabled: false}}}",
                   help="YAML overrides (default: cameras off)")  # fmt: skip
    p.add_argument("--sim-s", type=float, default=20.0, help="simulated seconds per run")
    p.add_argument("--warmup-s", type=float, default=2.0)
    p.add_argument("--step-ms", type=float, default=10.0, help="the step the table is per (ms)")
    p.add_argument("--top", type=int, default=20, help="rows of the table")
    p.add_argument("--by-method", action="store_true", help="a row per method, not per class")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")
    if not (a.sim_s > 0 and a.step_ms > 0 and a.warmup_s >= 0):
        p.error("--sim-s and --step-ms must be > 0, --warmup-s >= 0")

    from pydrake.systems.analysis import ApplySimulatorConfig, Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    scenario = load_scenario(scenario_name=a.scenario, scenario_text=a.scenario_text)
    site = load_site(scenario, progress=False)

    def run(diagram, t_s):
        sim = Simulator(diagram)
        ApplySimulatorConfig(scenario.simulator_config, sim)
        sim.Initialize()
        c0, w0 = time.process_time(), time.perf_counter()
        sim.AdvanceTo(t_s)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        ctx = diagram.GetMyContextFromRoot(sim.get_context())
        xy = [float(v) for v in diagram.GetOutputPort("truth.pose").Eval(ctx)[:2]]
        return {"cpu_s": cpu, "wall_s": wall, "rtf": t_s / wall, "steps":
                sim.get_num_steps_taken(), "final_xy_m": xy}  # fmt: skip

    plain_diagram = MakeMissionDiagram(scenario=scenario, site=site)
    if a.warmup_s > 0:
        run(plain_diagram, a.warmup_s)
    plain = run(plain_diagram, a.sim_s)
    del plain_diagram

    ledger = Ledger()
    undo = instrument(ledger, leaf_system_classes(), by_method=a.by_method)
    try:
        diagram = MakeMissionDiagram(scenario=scenario, site=site)
        if a.warmup_s > 0:
            run(diagram, a.warmup_s)
        ledger.clear()
        timed = run(diagram, a.sim_s)
    finally:
        restore(undo)
    if timed["final_xy_m"] != plain["final_xy_m"]:
        raise SystemExit(
            f"the instrumented run ended at {timed['final_xy_m']}, the plain one at "
            f"{plain['final_xy_m']}: the timers changed the simulation"
        )

    per_step = a.step_ms * 1e-3 / a.sim_s  # seconds of the run -> ms per step: x 1e3 * this
    total = timed["cpu_s"]
    systems = [
        {
            "name": name,
            "ms_per_step": s * 1e3 * per_step,
            "calls_per_s": ledger.calls[name] / a.sim_s,
            "share": s / total,
        }
        for name, s in sorted(ledger.seconds.items(), key=lambda kv: -kv[1])
    ]
    ours = sum(ledger.seconds.values())
    rest = max(total - ours, 0.0)
    rest_ms = rest * 1e3 * per_step
    bound = a.step_ms / rest_ms if rest_ms > 0 else None
    trivial = trivial_call_cost()
    calls_per_step = ledger.drake_calls * a.step_ms * 1e-3 / a.sim_s
    floor_ms = rest_ms + calls_per_step * trivial["body_s"] * 1e3
    speed = measure_speed_index()
    result = {
        "benchmark": "step_budget",
        "scenario": a.scenario,
        "scenario_text": a.scenario_text,
        "sim_s": a.sim_s,
        "step_ms": a.step_ms,
        "plain": plain,
        "instrumented": timed,
        "systems": systems,
        "python_ms_per_step": ours * 1e3 * per_step,
        "rest": {"ms_per_step": rest_ms, "share": rest / total},
        "bound_rtf": bound,
        "trivial_system": trivial,
        "calls_per_step": calls_per_step,
        "floor_ms_per_step": floor_ms,
        "floor_rtf": a.step_ms / floor_ms,
        "cpu_count": os.cpu_count(),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    step_cpu = plain["cpu_s"] * 1e3 * per_step
    print(f"plain: {a.sim_s:g} s simulated in {plain['wall_s']:.2f} s (cpu {plain['cpu_s']:.2f} "
          f"s), {plain['rtf']:.2f}x, {step_cpu:.3f} ms cpu per {a.step_ms:g} ms step; "
          f"instrumented: {timed['rtf']:.2f}x")  # fmt: skip
    head = "system (class.method)" if a.by_method else "system (class)"
    print(f"{head:36} {'ms/step':>8} {'calls/s':>8} {'share':>6}")
    for s in systems[: a.top]:
        print(f"{s['name']:36} {s['ms_per_step']:8.3f} {s['calls_per_s']:8.1f} "
              f"{s['share'] * 100:5.1f}%")  # fmt: skip
    print(f"{'our Python methods, all':36} {result['python_ms_per_step']:8.3f} {'':8} "
          f"{ours / total * 100:5.1f}%")  # fmt: skip
    print(f"{'the rest (Drake, plant, bindings)':36} {rest_ms:8.3f} {'':8} "
          f"{rest / total * 100:5.1f}%")  # fmt: skip
    if bound:
        print(f"with our Python methods free, a step would cost {rest_ms:.3f} ms: at most "
              f"{bound:.1f}x real time")  # fmt: skip
    print(f"a trivial Python system's update: {trivial['body_s'] * 1e6:.1f} us in its body, "
          f"{trivial['dispatch_s'] * 1e6:.1f} us in Drake; with each of the {calls_per_step:.1f} "
          f"calls Drake makes into our methods a step that cheap, a step would cost "
          f"{floor_ms:.3f} ms: at most {a.step_ms / floor_ms:.1f}x")  # fmt: skip
    print(speed_index_line(speed))
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    sys.exit(main())
