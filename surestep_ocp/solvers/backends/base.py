"""The interface every OCP solver backend implements, and what one attempt hands back.

A backend solves the belief-space OCP of a Setup from a start and declares what it handles
(`Handles`: the models, the motion limits, its warm start, the options an attempt may give it).
`applies` is derived from that declaration, and so is the strategy (strategy.py picks backends by
what they declare, never by name); `solve` runs one attempt (`strategy.Attempt`) and returns an
`Outcome`. Backends are registered in `backends/__init__.py` by their name, a `SolverName` (the
`solver.name` values, problem/solver_config.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

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


class Warm(Enum):
    """What a backend starts from when an attempt gives it the caller's iterate."""

    JOINTS = "joints"  # the iterate's joints, as its initial guess
    PRIMAL_DUAL = "primal-dual"  # the iterate's primal-dual point where it has one, else cold


# why a backend does not apply, per declaration
ONLY_LIMITS = "it is for problems with enforced motion limits (limits.enforce: true)"
NEWTON_FIT = ("it needs the condensed scalar recursion with the mean observation noise and six "
              "joints moving the tracked frame")


@dataclass(frozen=True)
class Handles:
    """What a backend declares it solves and takes; the strategy is derived from these.

    A backend that handles `any_model` (every model, form and Hessian) is the strategy's general
    solver, the fallback of the others; the others are tried first where they apply."""

    limits: bool  # carries enforced motion limits as constraints: its infeasibility verdict stands
    only_limits: bool = False  # applies only with enforced limits
    newton_fit: bool = False  # applies only where projected Newton's reformulation is exact
    any_model: bool = False  # any model, covariance form and Hessian
    warm: Warm = Warm.JOINTS
    options: frozenset[str] = frozenset()  # the attempt options it takes
    # re-plans from the moving robot's state (joints, velocities, accelerations) within the limits,
    # by `replan_solver` (a Planner's re-plans)
    moving_start: bool = False


def why_not(handles: Handles, ctx: Context) -> str | None:
    """Why a backend declaring `handles` cannot solve the context's OCP, or None when it can."""
    if handles.only_limits and not ctx.setup.ocp.limits.enforce:
        return ONLY_LIMITS
    if handles.newton_fit and not ctx.resolved.newton_fits:
        return NEWTON_FIT
    return None


class Backend(Protocol):
    """An OCP solver behind the strategy."""

    name: SolverName  # what `solver.name` calls it
    label: str  # what the attempt records call its attempts
    handles: Handles

    def applies(self, ctx: Context) -> str | None:
        """Why this backend cannot solve the context's OCP, or None when it can (`why_not` of its
        declaration)."""
        return why_not(self.handles, ctx)

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        """One attempt from `start` (or warm-started from `warm`) with the attempt's Hessian and
        options."""

    def prebuild(self, setup: Setup, background: bool = False):
        """Build (and compile) its solver of `setup`'s structure now, kept for its attempts (a
        Planner's, before its loop; `background`: the C compiled in a thread); returns it, or None
        where it builds nothing ahead."""
        return None

    def replan_solver(self, setup: Setup, moving: bool = True) -> ReplanSolver:
        """Its solver of re-plans over `setup`'s structure (`moving`: from the robot in motion; else
        from rest), built (and compiled) on first use and kept (`Handles.moving_start`)."""
        raise NotImplementedError(f"{self.name} does not re-plan from a moving start")


@dataclass(frozen=True)
class ReplanOptions:
    """One re-plan's run from the moving robot (a Planner's): where it starts and how far it may
    go."""

    v0: np.ndarray | None  # the executed curve's joint velocities at the start (None: at rest)
    a0: np.ndarray | None  # and accelerations
    tol: float
    mu0: float  # the barrier it starts with (near the optimum: small)
    max_iter: int  # 0: the start's plan, no iteration
    reserve: float  # the fraction of the limits kept for later corrections
    # the objective change (relative, over 3 iterations) it stops at (None: the method's own)
    acceptable_change: float | None = None
    relaxed_max: int | None = None  # iterations with relaxed rows beyond max_iter (None: its own)
    relax: bool = True  # rows the start breaks are relaxed, not refused
    feasible_ok: bool = True  # a run out of iterations within every row is a success


class ReplanSolver(Protocol):
    """A backend's solver of re-plans from a moving start over one structure (`replan_solver`):
    its runs, their plans, and what a real-time iteration's feedback needs."""

    def replan(self, setup: Setup, warm: InitialGuess, options: ReplanOptions):
        """The run from `warm` (its joints, the first the robot's) with `options`."""

    def parameters(self, setup: Setup) -> np.ndarray:
        """Its compiled functions' parameters for `setup` (camera, objective scale, Sigma_0)."""

    def rows(self, x, P, v0, a0, min_depth) -> np.ndarray:
        """Every constraint row at the joints `x` (flat): positive inside."""

    def plan_at(self, setup: Setup, x, P, trace_ref: float, status, iterations: int,
                relaxed_iterations: int, t0: float):
        """The run that ends at `x` with `status` (no iteration of its own), timed from `t0`."""

    def solution(self, setup: Setup, method: str, start: InitialGuess, run,
                 sigma=None) -> Solution:
        """A run's Solution (`sigma`: its covariances when the caller has them)."""
