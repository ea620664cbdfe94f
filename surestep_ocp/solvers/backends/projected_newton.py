"""The projected Newton solver (`newton.py`) on the condensed scalar recursion, and its barrier run
for the depth bound; a plan over an enforced motion limit is reported as such (Newton has no step
constraints)."""

from __future__ import annotations

from ...model.limits import enforce as enforce_limits
from ...problem.solver_config import SolverName
from ...ocp.iterate import InitialGuess, Iterate
from ..newton import EXACT_BELOW
from ..nlp_cache import newton_solver
from .base import Backend, Context, Handles, Outcome


class NewtonBackend(Backend):
    """Exact for the surrogate model with six joints moving the tracked frame
    (`ResolvedSolver.newton_fits`).

    Options: `depth_barrier` (bool) runs Newton on IPOPT's barrier problem, which keeps the depth
    bound; `exact_below` the projected gradient's norm below which it takes exact Hessian steps
    (inf: from the start, for warm starts). The plan is evaluated by `ctx.evaluate_newton` when
    the caller has a faster evaluation (the Planner's)."""

    name = SolverName.NEWTON
    label = "newton"
    # the limits are checked on its plan, not kept by its steps
    handles = Handles(limits=False, newton_fit=True,
                      options=frozenset({"depth_barrier", "exact_below"}))

    def prebuild(self, setup, background: bool = False):
        return newton_solver(setup, background=background)

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        spec = ctx.setup.ocp.solver
        solver = newton_solver(ctx.setup)
        kw = dict(tol=spec.tol, max_iter=min(spec.surrogate_max_iter, spec.max_iter),
                  verbose=spec.print_level > 0)
        if options.get("depth_barrier"):
            run = solver.run_barrier(ctx.setup, start, **kw)
        else:
            run = solver.run(ctx.setup, start, exact_below=options.get("exact_below", EXACT_BELOW),
                             **kw)
        sol = (ctx.evaluate_newton or solver.solution)(ctx.setup, ctx.method, start, run)
        # a plan over an enforced limit is not a success: the strategy goes on
        sol = enforce_limits(ctx.setup, sol)
        return Outcome(sol, Iterate(sol.joints) if sol.success else None)
