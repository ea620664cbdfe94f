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
from .backends import BACKENDS, Backend, Context, Outcome, Warm
from ..ocp.iterate import InitialGuess, Iterate
from .newton import EXACT_BELOW
from ..status import Status

DEPTH = Status.DEPTH_BOUND_VIOLATED
INFEASIBLE = Status.INFEASIBLE_PROBLEM_DETECTED
# IPOPT statuses that, from a feasible start, say more about the barrier's path than about the
# problem
FALSE_VERDICTS = (Status.INFEASIBLE_PROBLEM_DETECTED, Status.RESTORATION_FAILED,
                  Status.ERROR_IN_STEP_COMPUTATION)
MONOTONE = {"barrier_update": "monotone"}  # the general backend's option
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


def first_backend(ctx: Context) -> Backend | None:
    """The backend tried before the general one (`Handles.any_model`): the one `solver.name`
    names, else (auto) the first registered that applies and, with enforced limits, carries them;
    None where none applies or the general one is named."""
    name, limited = ctx.resolved.name, ctx.setup.ocp.limits.enforce
    for b in BACKENDS.values():
        if b.handles.any_model or b.applies(ctx) is not None:
            continue
        if name == b.name or (name == "auto" and (b.handles.limits or not limited)):
            return b
    return None


def general_backend() -> Backend:
    """The backend declaring any model, form and Hessian: every strategy's fallback."""
    (general,) = [b for b in BACKENDS.values() if b.handles.any_model]
    return general


def replan_backend(ctx: Context) -> Backend | None:
    """The backend a Planner re-plans with from the moving robot within enforced limits (one
    declaring `moving_start` that applies, as `solver.name` allows), or None: its re-plans run the
    whole strategy."""
    first = first_backend(ctx) if ctx.setup.ocp.limits.enforce else None
    return first if first is not None and first.handles.moving_start else None


def default_strategy(ctx: Context, warm: Iterate | None, pinned: bool, lifted_start: bool) -> tuple:
    """The attempts of one solve, in order (docs/hessian_and_newton.md, "Fallbacks: the order of
    attempts"), from what the backends declare (`Handles`): the first backend where one applies
    (`first_backend`), then the general one's attempts.

    Args:
        ctx: the solve's context (resolved solver choices, set-up).
        warm: the caller's warm start, if any.
        pinned: the problem or the caller sets IPOPT's barrier update (`mu_strategy`): no barrier
            fallbacks.
        lifted_start: the lifted form starts at a converged condensed solution (a KKT point with
            multipliers).
    """
    setup = ctx.setup
    limited = setup.ocp.limits.enforce
    # a warm start with the general backend's primal-dual point goes to it
    first = first_backend(ctx) if warm is None or not warm.has_duals else None
    out: list = []
    if first is not None:
        out.append(Attempt(first.label, first.name, start=Start.GIVEN))
        if limited and first.handles.limits:
            # its infeasibility verdict (the relaxed rows stopped shrinking) stands: IPOPT takes
            # far longer to agree (benchmarks/realtime.py checks each verdict; docs/realtime.md)
            out.append(Stop(Condition(last_status_in=(INFEASIBLE,))))
        elif "depth_barrier" in first.handles.options and setup.model.scalar:
            # the depth bound broken: the same method on IPOPT's barrier problem, which has it
            out.append(Attempt(f"{first.label}, depth barrier", first.name,
                               options={"depth_barrier": True},
                               when=Condition(unsolved=False, first_status_in=(DEPTH,))))
    return tuple(out) + _general_attempts(ctx, warm, pinned, lifted_start)


def _general_attempts(ctx: Context, warm: Iterate | None, pinned: bool,
                      lifted_start: bool) -> tuple:
    """The general backend's attempts of `default_strategy`, in order."""
    r, setup = ctx.resolved, ctx.setup
    spec, g = setup.ocp.solver, general_backend().name
    limited = setup.ocp.limits.enforce
    # the 6x6 recursion: no unrolled exact Hessian
    costly = setup.model.structured and not setup.model.scalar
    cap = spec.max_iter if r.forced else min(spec.surrogate_max_iter, spec.max_iter)
    exact_cap = {"max_iter": min(spec.surrogate_max_iter, spec.max_iter)} if limited else {}
    out: list = []
    # near the optimum: Newton's local convergence (lifted: its own Hessian)
    if warm is not None and warm.has_duals:
        hess = r.hessian if r.forced or r.form == "full" else "exact"
        out.append(Attempt(hess, g, hess, start=Start.GIVEN, when=ALWAYS))
    if r.hessian != "exact":
        near = {"near_start": True} if lifted_start and not pinned else {}
        main = {"max_iter": cap, **near}
        if r.form == "full":
            out.append(Attempt("lifted", g, r.hessian, main))
        else:
            # Newton's plan went below the depth bound: the monotone barrier, robust when it is
            # active
            if not pinned:
                out.append(Attempt(f"{r.hessian}, monotone barrier", g, r.hessian,
                                   {**main, **MONOTONE}, when=Condition(first_status_in=(DEPTH,))))
            out.append(Attempt(r.hessian, g, r.hessian, main,
                               when=Condition(first_status_not_in=(DEPTH,) if not pinned else ())))
        # the small monotone barrier did not settle: the adaptive update from the same point
        if near:
            out.append(Attempt("lifted, adaptive barrier", g, r.hessian, {"max_iter": cap}))
        # "infeasible" from a feasible start is the barrier's restoration failing
        if not (near or pinned or limited):
            out.append(Attempt(f"{r.hessian}, monotone barrier", g, r.hessian,
                               {"max_iter": cap, **MONOTONE},
                               when=Condition(first_status_not_in=(DEPTH,),
                                              last_status_in=FALSE_VERDICTS)))
        # with enforced limits an infeasibility verdict is the limits': no exact-Hessian attempts
        if limited:
            out.append(Stop(Condition(last_status_in=(INFEASIBLE,))))
        if not r.forced and r.form == "condensed" and not costly:  # polish from the point reached
            out.append(Attempt("exact", g, "exact", exact_cap, start=Start.REACHED))
    # the exact Hessian asked for: always tried
    if not r.forced and (not costly or r.hessian == "exact"):
        out.append(Attempt("exact", g, "exact", exact_cap))
        if not pinned:
            out.append(Attempt("exact, monotone barrier", g, "exact", {**MONOTONE, **exact_cap}))
    return tuple(out)


def replan_strategy(ctx: Context, moved: bool) -> tuple:
    """A re-plan's attempts from the previous plan (`Planner.replan`) by the first backend where
    it takes `exact_below` (projected Newton): near the optimum after a tracker update, exact
    steps from the first iteration (the surrogate's converge linearly there); after a camera move,
    or when exact steps from the first stall, the usual switch to exact steps near the optimum.
    What they leave unsolved goes to `default_strategy` from the same start (the Planner's
    fallback); no attempts where no backend takes it."""
    first = first_backend(ctx)
    if first is None or "exact_below" not in first.handles.options:
        return ()
    switch = Attempt(first.label, first.name, options={"exact_below": EXACT_BELOW},
                     start=Start.INIT)
    if moved:
        return (switch,)
    return (Attempt(f"{first.label}, exact steps", first.name, options={"exact_below": np.inf},
                    when=ALWAYS),
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
        backend = BACKENDS[step.backend]
        unknown = set(step.options) - backend.handles.options
        if unknown:
            raise ValueError(f"attempt {step.label!r}: {backend.name} takes no options "
                             f"{sorted(unknown)} (it takes {sorted(backend.handles.options)})")
        joints = backend.handles.warm is Warm.JOINTS  # it starts from a warm start's joints
        start, from_iterate = init, None
        if step.start is Start.GIVEN and warm is not None:
            from_iterate = warm
            if joints:
                start = InitialGuess(np.asarray(warm.q), f"warm start ({init.source})")
        elif step.start is Start.REACHED and tried:
            from_iterate = tried[-1].outcome.iterate
        outcome = backend.solve(ctx, start, from_iterate, step.hessian, step.options)
        warm_started = from_iterate is not None and (joints or from_iterate.has_duals)
        tried.append(Tried(step.label + (", warm start" if warm_started else ""), step, outcome))
    return tried
