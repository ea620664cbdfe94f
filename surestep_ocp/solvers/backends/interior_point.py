"""The interior-point Newton method (`interior/`) on the OCP within the enforced motion limits:
the joint-space problem of the projected Newton solver plus the limit rows, solved with a banded
system per iteration."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ...model.limits import enforce as enforce_limits
from ...problem.solver_config import SolverName
from ...ocp.straight_line import TIME_LAWS, timed_line
from ...ocp.iterate import InitialGuess, Iterate
from ..nlp_cache import interior_solver
from .base import Backend, Context, Handles, Outcome, ReplanSolver, Warm


def feasible_line(setup, solver, near: InitialGuess | None = None) -> InitialGuess:
    """The straight line at the first of TIME_LAWS whose curve keeps within every row (the
    interior-point method then keeps them); else at the one closest to them (the rows outside get
    slacks). Its IK starts from `near`'s joint path (e.g. the line at a constant pace) re-timed to
    the law, then from the previous law's line: a few Newton steps instead of the joint line's
    many, the same solutions."""
    best, margin = None, -np.inf
    T = setup.ocp.horizon
    path = None if near is None else (np.linspace(0.0, 1.0, T + 1), np.asarray(near.q, float))
    for name, law in TIME_LAWS:
        fractions = law(T)
        guesses = (None if path is None
                   else np.stack([np.interp(fractions, path[0], q) for q in path[1].T], axis=1))
        guess = timed_line(setup, law, name, guesses=guesses)
        path = (fractions, np.asarray(guess.q, float))
        m = solver.start_margin(setup, guess)
        if m > 0:
            return guess
        if m > margin:
            best, margin = guess, m
    return best


class InteriorPointBackend(Backend):
    """The OCP with enforced limits where projected Newton's reformulation is exact (`newton_fits`);
    a start within every row (the caller's, else the straight line at a minimum-jerk pace); warm
    starts from its own multipliers."""

    name = SolverName.INTERIOR
    label = "interior point"
    handles = Handles(limits=True, only_limits=True, newton_fit=True, warm=Warm.PRIMAL_DUAL,
                      moving_start=True)

    def replan_solver(self, setup, moving: bool = True) -> ReplanSolver:
        return interior_solver(setup, moving=moving)

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        setup, spec = ctx.setup, ctx.setup.ocp.solver
        solver = interior_solver(setup)  # built (and compiled) once per structure, not timed
        # the solve's time counts its start's search, as IPOPT's counts its call's set-up
        t0 = time.perf_counter()
        kw = dict(tol=spec.tol, max_iter=min(spec.surrogate_max_iter, spec.max_iter),
                  verbose=spec.print_level > 0)
        multipliers = warm.multipliers if warm is not None else None
        if warm is None and not solver.starts_inside(setup, start):
            # e.g. a start at a constant pace: the same line, timed (the rows no time law keeps
            # are relaxed at the start)
            start = feasible_line(setup, solver, near=start)
            run = solver.run(setup, start, relax=True, **kw)
        else:
            run = solver.run(setup, start, warm=multipliers, **kw)
        run = replace(run, solve_time_s=time.perf_counter() - t0)
        sol = solver.solution(setup, ctx.method, start, run)
        # the played curve checked densely, as every plan within the limits
        sol = enforce_limits(setup, sol)
        return Outcome(sol, (Iterate(sol.joints, multipliers=run.multipliers) if sol.success
                             else None))
