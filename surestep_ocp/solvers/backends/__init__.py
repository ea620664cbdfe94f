"""The OCP solver backends, registered by name: the strategy's attempts name one of these.

The names are `SolverName`'s (problem/solver_config.py: the values `solver.name` takes), the one
list of them: adding a solver is its name there, one module implementing `base.Backend` with that
name and its declaration (`Handles`: the strategy is derived from it), and one entry in `BACKENDS`
(tests/test_backends.py checks that every name but `auto` has exactly one backend). `SolverName`
is a str enum, so the strategy's strings look them up too.
"""

from __future__ import annotations

from ...problem.solver_config import SolverName
from .base import Backend, Context, Handles, Outcome, ReplanOptions, ReplanSolver, Warm
from .interior_point import InteriorPointBackend
from .ipopt import IpoptBackend
from .projected_newton import NewtonBackend

# in the order the strategy prefers them where several apply (`strategy.first_backend`)
BACKENDS: dict[SolverName, Backend] = {
    b.name: b for b in (NewtonBackend(), InteriorPointBackend(), IpoptBackend())}

__all__ = ["BACKENDS", "Backend", "Context", "Handles", "Outcome", "ReplanOptions", "ReplanSolver",
           "Warm"]
