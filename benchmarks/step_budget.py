"""Benchmark: where a simulated step's time goes, system by system.

    .venv/bin/python benchmarks/step_budget.py --out bench_step_budget.json
    .venv/bin/python benchmarks/step_budget.py --scenario-text '{}' --sim-s 20

Builds the scenario's mission diagram (default: the default scenario without cameras,
what ``mission_rate.py --no-cameras`` times), runs an untimed ``--warmup-s``, then
``--sim-s`` simulated seconds twice from fresh contexts, timing the thread that runs
the simulator by one clock, wall seconds (its CPU time, and other threads' -- the
camera's worker when there is one -- are reported apart):

1. **plain**: nothing instrumented (the real-time factor the breakdown belongs to);
2. **instrumented**: before the diagram is built, every method of every ``LeafSystem``
   class in :mod:`lunar_drake.systems` is wrapped in a timer, and so are the
   output-port calculators those classes declare with lambdas. Each call's
   *exclusive* time (its own, less that of the timed calls inside it) is charged to
   the class of its system. Work a method asks of Drake (an input port's
   ``Eval``, the ``MultibodyPlant``'s ports) or of the functional core
   (``executor_step``, the numba kernels) is charged to that method.

The table lists each class's ms per ``--step-ms`` (10 ms, the plant's step) of simulated
time, its calls per simulated second and its share. **The rest** is the run's time that
none of our Python accounts for: Drake's simulator loop, the plant's own step,
event dispatch, cache invalidation and pybind11's calls into Python (the timers' own
cost outside what they charge, measured by :func:`wrapper_overhead_s`, is taken out of
it). ``--by-method`` gives a row per method or output port. ``step / rest`` bounds the
real-time factor any speed-up of our Python could reach. A closer estimate adds, for
each call Drake makes into our code a step (a timed call entered with none running),
the body of the cheapest useful update: a ring of trivial Python systems, each reading
one input port and writing its state (:func:`trivial_call_cost`; its Drake side is
already in the rest): ``floor_ms_per_step``. An estimate, not a bound: some calls
(an output that copies a state) can be cheaper than that body. Runs of the same code
differ by more than the timers cost: compare the two rates on the first line.

JSON ``{plain, instrumented, systems: [{name, ms_per_step, calls_per_s, share}], rest,
wrapper_overhead_s, bound_rtf, trivial_system, calls_per_step, floor_ms_per_step,
floor_rtf, speed_index_s, ...}``.
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
    """Exclusive time (``clock``: wall seconds by default, as the simulator's own
    timing) and calls per label, for nested timed calls on the thread that made the
    ledger (calls from other threads run untimed)."""

    def __init__(self, *, clock=time.perf_counter):
        import threading

        self.seconds = collections.defaultdict(float)
        self.calls = collections.Counter()
        self.drake_calls = 0  # calls entered with no timed method running: from Drake
        self.active = True
        self._stack: list[float] = []
        self._thread = threading.get_ident()
        self._get_ident = threading.get_ident
        self._clock = clock

    def clear(self) -> None:
        self.seconds.clear()
        self.calls.clear()
        self.drake_calls = 0

    def wrap(self, fn, *, label):
        """``fn`` with its calls' exclusive time charged to ``label``: a text, or a
        function of the call's positional arguments that returns one."""
        clock, stack, seconds, calls = self._clock, self._stack, self.seconds, self.calls
        me, ident = self._thread, self._get_ident
        ledger = self
        fixed = label if isinstance(label, str) else None

        def timed(*args, **kwargs):
            if not ledger.active or ident() != me:
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
                key = fixed or label(args)
                seconds[key] += dt - inner
                calls[key] += 1
                if stack:
                    stack[-1] += dt

        timed.__wrapped__ = fn
        return timed


def wrapper_overhead_s(*, calls: int = 100_000) -> float:
    """Seconds a top-level timed call costs outside the time it charges (the part of a
    call from Drake that lands in "the rest"), per call."""
    ledger = Ledger()
    noop = ledger.wrap(lambda: None, label="noop")
    t0 = time.perf_counter()
    for _ in range(calls):
        noop()
    total = time.perf_counter() - t0
    return max(total - ledger.seconds["noop"], 0.0) / calls


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


_ABSENT = object()
#: LeafSystem methods whose ``calc`` (third positional argument, or keyword) is wrapped
#: when it is not a timed method already: the lambdas systems declare outputs with
_OUTPUT_DECLARATIONS = ("DeclareVectorOutputPort", "DeclareAbstractOutputPort")


def instrument(*, ledger: Ledger, classes, by_method: bool = False) -> list:
    """Wraps the plain functions defined on each class (not dunders, not properties) and
    the output-port calculators its instances declare with lambdas; each call is charged
    to the class of the instance (``Class.method``, ``Class.<port name>`` with
    ``by_method``). Returns what :func:`restore` puts back."""
    from pydrake.systems.framework import LeafSystem

    undo = []
    for cls in classes:
        for name, attr in list(vars(cls).items()):
            if name.startswith("__") or not inspect.isfunction(attr):
                continue
            if by_method:
                label = lambda args, n=name: f"{type(args[0]).__name__}.{n}"  # noqa: E731
            else:
                label = lambda args: type(args[0]).__name__  # noqa: E731
            undo.append((cls, name, attr))
            setattr(cls, name, ledger.wrap(attr, label=label))
        for name in _OUTPUT_DECLARATIONS:
            undo.append((cls, name, vars(cls).get(name, _ABSENT)))
            setattr(cls, name, _declaring(getattr(LeafSystem, name), ledger, by_method))
    return undo


def _is_timed(fn) -> bool:
    """Whether ``fn`` (or the function of a bound method) is a :meth:`Ledger.wrap` timer."""
    return getattr(getattr(fn, "__func__", fn), "__qualname__", "").endswith("wrap.<locals>.timed")


def _declaring(declare, ledger: Ledger, by_method: bool):
    def wrapped(self, *args, **kwargs):
        owner = type(self).__name__
        label = f"{owner}.<{args[0] if args else kwargs.get('name')}>" if by_method else owner
        if "calc" in kwargs and not _is_timed(kwargs["calc"]):
            kwargs["calc"] = ledger.wrap(kwargs["calc"], label=label)
        elif len(args) > 2 and not _is_timed(args[2]):
            args = (*args[:2], ledger.wrap(args[2], label=label), *args[3:])
        return declare(self, *args, **kwargs)

    return wrapped


def restore(*, undo) -> None:
    """Puts back what :func:`instrument` replaced (last first)."""
    for cls, name, attr in reversed(undo):
        if attr is _ABSENT:
            delattr(cls, name)
        else:
            setattr(cls, name, attr)


def trivial_call_cost(*, systems: int = 10, sim_s: float = 20.0, step_s: float = 0.01) -> dict:
    """What a useful Python system's update costs at the least, here: a ring of
    ``systems`` LeafSystems, each with a periodic discrete update (``step_s``) that reads
    its 10-vector input port and writes its state (the next one's input), simulated
    ``sim_s``. Per call (counted in the update): ``body_s``, the update's own time (timed
    inside it, as a method in the table is), and ``dispatch_s``, the rest of the run's
    time."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from lunar_drake.systems.leaf import Leaf

    body = [0.0, 0]
    clock = time.perf_counter

    class Trivial(Leaf):  # the base of our systems (no per-step witness lookup)
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
            body[1] += 1

    builder = DiagramBuilder()
    ring = [builder.AddSystem(Trivial()) for _ in range(systems)]
    for a, b in zip(ring, ring[1:] + ring[:1], strict=True):
        builder.Connect(a.get_output_port(), b.get_input_port())
    sim = Simulator(builder.Build())
    sim.Initialize()
    body[:] = [0.0, 0]
    c0 = clock()
    sim.AdvanceTo(sim_s)
    cpu = clock() - c0
    calls = body[1]
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

    def run(diagram, t_s, ledger=None):
        sim = Simulator(diagram)
        ApplySimulatorConfig(scenario.simulator_config, sim)
        sim.Initialize()
        if ledger is not None:
            ledger.clear()
            ledger.active = True
        c0, p0, w0 = time.thread_time(), time.process_time(), time.perf_counter()
        sim.AdvanceTo(t_s)
        wall = time.perf_counter() - w0
        cpu = time.thread_time() - c0
        others = time.process_time() - p0 - cpu
        if ledger is not None:
            ledger.active = False  # the pose read below is not part of the run
        ctx = diagram.GetMyContextFromRoot(sim.get_context())
        xy = [float(v) for v in diagram.GetOutputPort("truth.pose").Eval(ctx)[:2]]
        steps = sim.get_num_steps_taken()
        return {"cpu_s": cpu, "other_threads_cpu_s": max(others, 0.0), "wall_s": wall,
                "rtf": t_s / wall, "steps": steps, "final_xy_m": xy}  # fmt: skip

    plain_diagram = MakeMissionDiagram(scenario=scenario, site=site)
    if a.warmup_s > 0:
        run(plain_diagram, a.warmup_s)
    plain = run(plain_diagram, a.sim_s)
    del plain_diagram

    ledger = Ledger()
    undo = []
    try:
        undo = instrument(ledger=ledger, classes=leaf_system_classes(), by_method=a.by_method)
        diagram = MakeMissionDiagram(scenario=scenario, site=site)
        if a.warmup_s > 0:
            run(diagram, a.warmup_s, ledger)
        timed = run(diagram, a.sim_s, ledger)
    finally:
        restore(undo=undo)
    if timed["final_xy_m"] != plain["final_xy_m"]:
        raise SystemExit(
            f"the instrumented run ended at {timed['final_xy_m']}, the plain one at "
            f"{plain['final_xy_m']}: the timers changed the simulation"
        )

    per_step = a.step_ms * 1e-3 / a.sim_s  # seconds of the run -> ms per step: x 1e3 * this
    total = timed["wall_s"]  # the timers' clock: the table adds up to it
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
    overhead = wrapper_overhead_s()
    rest = max(total - ours - overhead * ledger.drake_calls, 0.0)
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
        "wrapper_overhead_s": overhead,
        "bound_rtf": bound,
        "trivial_system": trivial,
        "calls_per_step": calls_per_step,
        "floor_ms_per_step": floor_ms,
        "floor_rtf": a.step_ms / floor_ms,
        "cpu_count": os.cpu_count(),
        "speed_index_s": speed["speed_index_s"],
        "speed_index": speed,
    }
    step_ms = plain["wall_s"] * 1e3 * per_step
    print(f"plain: {a.sim_s:g} s simulated in {plain['wall_s']:.2f} s ({plain['rtf']:.2f}x, "
          f"{step_ms:.3f} ms a {a.step_ms:g} ms step; CPU {plain['cpu_s']:.2f} s on the "
          f"simulator's thread, {plain['other_threads_cpu_s']:.2f} s on others); instrumented: "
          f"{timed['rtf']:.2f}x")  # fmt: skip
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
          f"calls Drake makes into our methods a step that cheap, a step would cost about "
          f"{floor_ms:.3f} ms ({a.step_ms / floor_ms:.1f}x)")  # fmt: skip
    print(speed_index_line(speed))
    if a.out:
        atomic_write_text(a.out, json.dumps(result, indent=2) + "\n", what="results JSON")
    return 0


if __name__ == "__main__":
    from lunar_drake.allocator import reexec_or_exit

    reexec_or_exit("step_budget.py")  # as the lunar-drake program runs (lunar_drake/allocator.py)
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from benchmarks import run_main

    run_main(main, "step_budget.py")
