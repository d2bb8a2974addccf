"""Leaf: the base of our systems, without pydrake's per-step witness-function lookup, and
its own-context lookup."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import (
    DiagramBuilder,
    LeafSystem,
    PublishEvent,
    WitnessFunctionDirection,
)

import lunar_drake.systems as systems_pkg
from lunar_drake.systems.leaf import Leaf


def _counting(base):
    """A system on ``base`` with a 100 Hz unrestricted update (after which the Simulator
    asks the system for its witness functions again) that counts how often its
    ``DoGetWitnessFunctions`` attribute is looked up (pybind11's override lookup goes
    through ``__getattribute__``)."""

    class Counting(base):
        lookups = 0

        def __init__(self):
            super().__init__()
            self._count = self.DeclareDiscreteState(1)
            self.DeclarePeriodicUnrestrictedUpdateEvent(0.01, 0.0, self._update)

        def _update(self, context, state):
            xd = state.get_mutable_discrete_state(self._count)
            xd.SetAtIndex(0, xd.GetAtIndex(0) + 1.0)

        def __getattribute__(self, name):
            if name == "DoGetWitnessFunctions":
                type(self).lookups += 1
            return super().__getattribute__(name)

    return Counting


def _run(system, t_s=0.5):
    sim = Simulator(system)
    sim.get_mutable_context().SetAccuracy(1e-8)  # a witness is isolated to that
    sim.AdvanceTo(t_s)
    return sim


def test_the_override_lookup_happens_once_per_class_not_once_per_step():
    plain, leaf = _counting(LeafSystem)(), _counting(Leaf)()
    _run(plain)
    _run(leaf)
    # pydrake's trampoline asks after every unrestricted update (50 here) ...
    assert type(plain).lookups >= 50
    # ... ours once: pybind11 finds a C++ function and remembers the class has no override
    assert type(leaf).lookups == 1
    assert leaf.GetWitnessFunctions(leaf.CreateDefaultContext()) == []


def test_a_python_override_of_the_witness_functions_still_runs():
    class Crossing(Leaf):
        """Publishes once when its continuous state x = t crosses 0.25 (a witness)."""

        def __init__(self):
            super().__init__()
            self.DeclareContinuousState(1)  # witnesses are checked while integrating
            self.hits = []
            self._witness = self.MakeWitnessFunction(
                "x = 0.25",
                WitnessFunctionDirection.kCrossesZero,
                lambda ctx: ctx.get_continuous_state_vector()[0] - 0.25,
                PublishEvent(lambda ctx, event: self.hits.append(ctx.get_time())),
            )

        def DoCalcTimeDerivatives(self, context, derivatives):
            derivatives.get_mutable_vector().SetAtIndex(0, 1.0)

        def DoGetWitnessFunctions(self, context):
            return [self._witness]

    system = Crossing()
    _run(system)
    assert len(system.hits) == 1 and np.isclose(system.hits[0], 0.25, atol=1e-3)


def test_every_system_of_the_package_is_a_leaf():
    classes = []
    for info in pkgutil.iter_modules(systems_pkg.__path__):
        mod = importlib.import_module(f"{systems_pkg.__name__}.{info.name}")
        classes += [
            c
            for _, c in inspect.getmembers(mod, inspect.isclass)
            if issubclass(c, LeafSystem) and c.__module__ == mod.__name__ and c is not Leaf
        ]
    assert len(classes) >= 30
    assert [c.__name__ for c in classes if not issubclass(c, Leaf)] == []


def test_own_context_from_its_own_or_the_root_and_not_from_another():
    builder = DiagramBuilder()
    inner = DiagramBuilder()
    a = inner.AddSystem(Leaf())
    sub = builder.AddSystem(inner.Build())
    b = builder.AddSystem(Leaf())
    root = builder.Build().CreateDefaultContext()
    own_a = a.GetMyContextFromRoot(root)
    assert a.own_context(own_a) is own_a and a.own_mutable_context(own_a) is own_a
    assert a.own_context(root) is own_a and a.own_mutable_context(root) is own_a
    with pytest.raises(RuntimeError, match=r"[Cc]ontext"):
        a.own_context(b.GetMyContextFromRoot(root))  # another system's
    with pytest.raises(RuntimeError, match="root"):
        a.own_context(sub.GetMyContextFromRoot(root))  # a subdiagram's, not the root
