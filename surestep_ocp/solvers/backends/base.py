"""The interface every OCP solver backend implements, and what one attempt hands back.

A backend solves the belief-space OCP of a Setup from a start: `applies` says why it cannot
(or None), `solve` runs one attempt of the strategy (`strategy.Attempt`) and returns an `Outcome`.
Backends are registered in `backends/__init__.py` by their name, a `SolverName` (the `solver.name`
values, problem/solver_config.py); the strategy refers to them by that name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from ...output.solution import Solution
from ...problem.setup import Setup
from ...problem.solver_config import ResolvedSolver, SolverName
from ...ocp.iterate import InitialGuess, Iterate


@dataclass(frozen=True)
class Context:
    """What every attempt of one solve shares: the set-up, the resolved solver choices, the method's
    name and the caller's extra IPOPT options."""

    setup: Setup
    resolved: ResolvedSolver
    method: str
    options: dict  # extra raw IPOPT options (`solve_ocp`'s solver_options)
    # (setup, method, start, NewtonRun) -> Solution: a faster evaluation of Newton's plans
    # (the Planner's)
    evaluate_newton: Callable | None = None


@dataclass
class Outcome:
    """One attempt's plan, the iterate a later attempt or solve can start from (None: none to
    offer), and the feasible start as a plan when the backend can tell (`start_solution`, for the
    strategy's keep-start rule)."""

    solution: Solution
    iterate: Iterate | None
    start_solution: Callable[[InitialGuess], Solution | None] | None = None


class Backend(Protocol):
    """An OCP solver behind the strategy."""

    name: SolverName  # what `solver.name` calls it

    def applies(self, ctx: Context) -> str | None:
        """Why this backend cannot solve the context's OCP, or None when it can."""

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        """One attempt from `start` (or warm-started from `warm`) with the attempt's Hessian and
        options."""
