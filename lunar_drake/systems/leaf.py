"""The base of every LeafSystem in :mod:`lunar_drake.systems`: pydrake's ``LeafSystem``
without the per-step cost of its witness-function trampoline.

After every step with a discrete or unrestricted update the Simulator asks the whole
diagram for its witness functions (``System::GetWitnessFunctions``). For a system
written in Python, pydrake's trampoline looks for a Python override of
``DoGetWitnessFunctions`` through pybind11, which remembers a method that is *not*
overridden only when the attribute it finds is a bound C++ function. pydrake binds no
``DoGetWitnessFunctions``, so the lookup fails, raises and formats an ``AttributeError``
and clears it, in every system, at every step: 5-6 % of a no-camera mission's run time
(perf, 2026-11-29), 10-20 % of its rate once removed.

:class:`Leaf` names a bound C++ function (``System.GetWitnessFunctions``, which calls the
C++ ``DoGetWitnessFunctions``) under that attribute: pybind11 finds a C++ function, records
the class as not overriding it and, from then on, calls the C++ default (no witness
functions) without touching Python. A subclass that declares witness functions overrides
``DoGetWitnessFunctions`` in Python as usual, in the class itself or a base ahead of
:class:`Leaf` in its MRO; pybind11 then finds and calls that. (An override set on an
instance after the class's first lookup, or in a mixin listed after Leaf, is not seen.)

:meth:`Leaf.own_context` gives a system's own context from its own or the root's without
the C++ exception that ``GetMyContextFromRoot`` throws for a system's own context
(about 14 us a call, 70 us inside a running simulation).
"""

from __future__ import annotations

from pydrake.systems.framework import LeafContext, LeafSystem

__all__ = ["Leaf"]


class Leaf(LeafSystem):
    """A ``LeafSystem`` whose trampoline knows it declares no witness functions (see the
    module docstring); construct and subclass it exactly as ``LeafSystem``."""

    #: a bound C++ function under the trampoline's name: pybind11 caches "not overridden"
    DoGetWitnessFunctions = LeafSystem.GetWitnessFunctions

    def own_context(self, context):
        """This system's context: ``context`` itself when it is a leaf context (checked to
        be this system's: ``ValidateContext`` raises otherwise), else this system's
        subcontext of the root ``context``."""
        if isinstance(context, LeafContext):
            self.ValidateContext(context)
            return context
        return self.GetMyContextFromRoot(context)

    def own_mutable_context(self, context):
        """:meth:`own_context`, mutable."""
        if isinstance(context, LeafContext):
            self.ValidateContext(context)
            return context
        return self.GetMyMutableContextFromRoot(context)
