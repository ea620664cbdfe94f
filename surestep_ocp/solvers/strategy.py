"""The solve strategy as data: which backend runs first, which fallbacks follow, on what condition.

A strategy is a tuple of `Attempt`s and `Stop`s, built once per solve from the resolved solver
choices (`default_strategy`) and run in order by `run`: an attempt runs when its `Condition` holds
on the attempts so far, a `Stop` ends the strategy when its condition holds. Why this order:
docs/hessian_and_newton.md, "Fallbacks: the order of attempts".
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from ..output.attempt_record import AttemptRecord
from ..output.solution import Solution
from .backends import BACKENDS, Context, Outcome
from ..ocp.iterate import InitialGuess, Iterate
from .newton import EXACT_BELOW
from .nlp_cache import LIFTED_FROM_CONDENSED
from ..status import Status

DEPTH = Status.DEPTH_BOUND_VIOLATED
INFEASIBLE = Status.INFEASIBLE_PROBLEM_DETECTED
# IPOPT statuses that, from a feasible start, say more about the barrier's path than about the
# problem
FALSE_VERDICTS = (Status.INFEASIBLE_PROBLEM_DETECTED, Status.RESTORATION_FAILED,
                  Status.ERROR_IN_STEP_COMPUTATION)
MONOTONE = {"ipopt.mu_strategy": "monotone"}
# Newton's ends the switch may change
HANDOVER = (Status.STALLED, Status.MAXIMUM_ITERATIONS_EXCEEDED, Status.LINE_SEARCH_FAILED)


class Start(Enum):
    """Where an attempt starts."""

    INIT = "init"  # the initial guess (the condensed solution for the lifted form)
    GIVEN = "given"  # the iterate the caller passed (a warm start), else the initial guess
    REACHED = "reached"  # where the previous attempt ended


@dataclass(frozen=True)
class Condition:
    """When an attempt runs (or a Stop stops), given the attempts so far."""

    unsolved: bool = True  # only while no attempt has succeeded
    first_status_in: tuple[str, ...] = ()  # the first attempt ended with one of these
    # no attempt yet, or the first did not end with one of these
    first_status_not_in: tuple[str, ...] = ()
    last_status_in: tuple[str, ...] = ()  # the last attempt ended with one of these

    def holds(self, tried: list[Tried]) -> bool:
        if self.unsolved and any(t.outcome.solution.success for t in tried):
            return False
        first = tried[0].outcome.solution.status if tried else None
        if self.first_status_in and first not in self.first_status_in:
            return False
        if self.first_status_not_in and first in self.first_status_not_in:
            return False
        return (not self.last_status_in or bool(tried)
                and tried[-1].outcome.solution.status in self.last_status_in)


ALWAYS = Condition(unsolved=False)


@dataclass(frozen=True)
class Attempt:
    """One solve by a backend: its label in the records, the Hessian, the backend's options, the
    start."""

    label: str
    backend: str  # a solver name (`SolverName`'s value), a key of backends.BACKENDS
    hessian: str | None = None
    options: dict = field(default_factory=dict)
    start: Start = Start.INIT
    when: Condition = Condition()


@dataclass(frozen=True)
class Stop:
    """The strategy ends here when the condition holds."""

    when: Condition


@dataclass
class Tried:
    """An attempt that ran: its label (with ", warm start" when it started from an iterate) and
    outcome."""

    label: str
    attempt: Attempt
    outcome: Outcome


def default_strategy(ctx: Context, warm: Iterate | None, pinned: bool, lifted_start: bool) -> tuple:
    """The attempts of one solve, in order (docs/hessian_and_newton.md, "Fallbacks: the order of
    attempts").

    Args:
        ctx: the solve's context (resolved solver choices, set-up).
        warm: the caller's warm start, if any.
        pinned: the problem or the caller sets IPOPT's barrier update (`mu_strategy`): no barrier
            fallbacks.
        lifted_start: the lifted form starts at a converged condensed solution (a KKT point with
            multipliers).
    """
    r, setup = ctx.resolved, ctx.setup
    spec = setup.ocp.solver
    limited = setup.ocp.limits.enforce
    # the 6x6 recursion: no unrolled exact Hessian
    costly = setup.model.structured and not setup.model.scalar
    cap = spec.max_iter if r.forced else min(spec.surrogate_max_iter, spec.max_iter)
    exact_cap = {"ipopt.max_iter": min(spec.surrogate_max_iter, spec.max_iter)} if limited else {}
    out: list = []
    if (limited and r.newton_fits and r.name in ("auto", "interior")
        and (warm is None or not warm.has_duals)):
        # within enforced limits: the interior-point Newton method, which carries them (projected
        # Newton does not); IPOPT follows where it does not converge
        # (benchmarks/results/realtime.md)
        out.append(Attempt("interior point", "interior", start=Start.GIVEN))
        # its infeasibility verdict (the relaxed rows stopped shrinking) stands: IPOPT takes far
        # longer to agree (benchmarks/realtime.py checks each verdict with IPOPT; docs/realtime.md)
        out.append(Stop(Condition(last_status_in=(INFEASIBLE,))))
    elif (r.name == "newton" or (r.name == "auto" and not limited)) and r.newton_fits and (
            warm is None or not warm.has_duals):  # Newton first where it applies
        out.append(Attempt("newton", "newton", start=Start.GIVEN))
        # the depth bound broken: Newton on IPOPT's barrier problem, which has it
        if setup.model.scalar:
            out.append(Attempt("newton, depth barrier", "newton", options={"barrier": True},
                               when=Condition(unsolved=False, first_status_in=(DEPTH,))))
    # near the optimum: Newton's local convergence (lifted: its own Hessian)
    if warm is not None and warm.has_duals:
        hess = r.hessian if r.forced or r.form == "full" else "exact"
        out.append(Attempt(hess, "ipopt", hess, start=Start.GIVEN, when=ALWAYS))
    if r.hessian != "exact":
        near = LIFTED_FROM_CONDENSED if lifted_start and not pinned else {}
        main = {"ipopt.max_iter": cap, **near}
        if r.form == "full":
            out.append(Attempt("lifted", "ipopt", r.hessian, main))
        else:
            # Newton's plan went below the depth bound: the monotone barrier, robust when it is
            # active
            if not pinned:
                out.append(Attempt(f"{r.hessian}, monotone barrier", "ipopt", r.hessian,
                                   {**main, **MONOTONE}, when=Condition(first_status_in=(DEPTH,))))
            out.append(Attempt(r.hessian, "ipopt", r.hessian, main,
                               when=Condition(first_status_not_in=(DEPTH,) if not pinned else ())))
        # the small monotone barrier did not settle: the adaptive update from the same point
        if near:
            out.append(Attempt("lifted, adaptive barrier", "ipopt", r.hessian,
                               {"ipopt.max_iter": cap}))
        # "infeasible" from a feasible start is the barrier's restoration failing
        if not (near or pinned or limited):
            out.append(Attempt(f"{r.hessian}, monotone barrier", "ipopt", r.hessian,
                               {"ipopt.max_iter": cap, **MONOTONE},
                               when=Condition(first_status_not_in=(DEPTH,),
                                              last_status_in=FALSE_VERDICTS)))
        # with enforced limits an infeasibility verdict is the limits': no exact-Hessian attempts
        if limited:
            out.append(Stop(Condition(last_status_in=(INFEASIBLE,))))
        if not r.forced and r.form == "condensed" and not costly:  # polish from the point reached
            out.append(Attempt("exact", "ipopt", "exact", exact_cap, start=Start.REACHED))
    # the exact Hessian asked for: always tried
    if not r.forced and (not costly or r.hessian == "exact"):
        out.append(Attempt("exact", "ipopt", "exact", exact_cap))
        if not pinned:
            out.append(Attempt("exact, monotone barrier", "ipopt", "exact",
                               {**MONOTONE, **exact_cap}))
    return tuple(out)


def replan_strategy(moved: bool) -> tuple:
    """A re-plan's attempts from the previous plan (`Planner.replan`): near the optimum after a
    tracker update, Newton's exact steps from the first iteration (the surrogate's converge linearly
    there); after a camera move, or when exact steps from the first stall, the usual switch to exact
    steps near the optimum. What they leave unsolved goes to `default_strategy` from the same start
    (the Planner's fallback)."""
    switch = Attempt("newton", "newton", options={"exact_below": EXACT_BELOW}, start=Start.INIT)
    if moved:
        return (switch,)
    return (Attempt("newton, exact steps", "newton", options={"exact_below": np.inf}, when=ALWAYS),
            replace(switch, when=Condition(last_status_in=HANDOVER)))


def records(tried: list[Tried], pick: int) -> list[AttemptRecord]:
    """The typed records of the attempts that ran; `pick` is the one whose plan is returned."""
    return [record(t.label, t.attempt.hessian, t.outcome.solution, k == pick)
            for k, t in enumerate(tried)]


def record(label: str, hessian: str | None, sol: Solution, kept: bool) -> AttemptRecord:
    """One attempt's record from its plan (the backend is the plan's `solver`; "none" for a kept
    start)."""
    solver = str(sol.run.solver)
    return AttemptRecord(label, "none" if solver.startswith("none") else solver,
                         hessian if solver == "ipopt" else None, sol.status, sol.iterations,
                         sol.solve_time_s, sol.objective, kept, bool(sol.run.compiled))


def run(strategy: tuple, ctx: Context, init: InitialGuess, warm: Iterate | None) -> list[Tried]:
    """Run the strategy's attempts in order from `init` (or the caller's `warm` iterate where an
    attempt says so); returns every attempt that ran."""
    tried: list[Tried] = []
    for step in strategy:
        if not step.when.holds(tried):
            continue
        if isinstance(step, Stop):
            break
        start, from_iterate = init, None
        if step.start is Start.GIVEN and warm is not None:
            from_iterate = warm
            if step.backend == "newton":
                start = InitialGuess(np.asarray(warm.q), f"warm start ({init.source})")
        elif step.start is Start.REACHED and tried:
            from_iterate = tried[-1].outcome.iterate
        outcome = BACKENDS[step.backend].solve(ctx, start, from_iterate, step.hessian, step.options)
        warm_started = (from_iterate is not None
                        and (step.backend == "newton" or from_iterate.has_duals))
        tried.append(Tried(step.label + (", warm start" if warm_started else ""), step, outcome))
    return tried
