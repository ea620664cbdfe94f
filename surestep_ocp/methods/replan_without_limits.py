"""A Planner's re-plan where the motion limits are not enforced: the problem left from the
tracker's estimate, solved by projected Newton's re-plan strategy, else by the OCP's whole strategy.

The estimate's pose is the new start (its joints by IK from the current plan's), the goal's joints
are kept, and the rest of the current plan is the warm start. Projected Newton's attempts
(`strategy.replan_strategy`) evaluate their plans by the compiled EKF in one call; IPOPT's
models, or a Newton run that does not converge, run `solve_ocp_warm`'s whole strategy from the
previous plan.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import SurestepError
from ..model.belief import vech
from ..ocp.iterate import InitialGuess
from ..output.solution import Solution
from ..ocp.plan_evaluation import evaluate
from ..output.solution_records import SolveRecord
from ..problem.setup import Setup
from ..solvers.backends import Context
from ..solvers.strategy import records, replan_strategy
from ..solvers.strategy import run as run_strategy
from .ocp import resolved_solver, solve_ocp_warm
from .replan_solvers import UNVECH


def remaining_problem(base: Setup, mean: np.ndarray, cov: np.ndarray, plan_q: np.ndarray,
                      n: int) -> tuple[Setup, InitialGuess]:
    """(the problem over the `n` steps left from the tracker's `mean`, its warm start): the start's
    joints by IK from the current plan's joints there (`plan_q[0]`; its rest `plan_q[1:]` the warm
    start's), Sigma_0 the estimate's covariance; an unreachable mean is an error."""
    seed = plan_q[0]
    q, ok, res_m, res_rad = base.joints_along(mean[None], seed, guesses=seed[None])
    if not ok[0]:
        raise SurestepError(f"replan: the tracker's mean {np.round(mean, 4).tolist()} "
                            f"is not reachable (IK residual {res_m[0] * 1e3:.3f} mm, "
                            f"{res_rad[0]:.4f} rad)")
    sub = replace(base.with_ocp(horizon=n, sigma0=cov), q_start=q[0])
    # the goal's as seen from this start
    sub.x_start, sub.x_goal = sub.pose_of(q[0]), sub.pose_of(sub.q_goal)
    warm = InitialGuess(np.vstack([q[:1], plan_q[1:]]), "previous plan")
    return sub, warm


def replan_without_limits(sub: Setup, warm: InitialGuess, cov: np.ndarray, moved: bool,
                          built: tuple | None) -> Solution:
    """The re-plan of `sub` from `warm`: the Newton attempts with the `built` (solver, compiled EKF)
    of its horizon when there is one (`moved`: the camera moved since the last plan), else or where
    they fail the OCP's whole strategy."""
    sol = None
    if built is not None:
        # the re-plan's Newton attempts (strategy.replan_strategy), evaluated in one call
        def evaluate_run(setup, method, start, run):
            sig = np.asarray(built[1](run.poses.T, vech(cov))).T[:, UNVECH]
            return evaluate(setup, method, run.poses, list(run.q), success=run.success,
                            status=run.status, solve_time_s=run.solve_time_s,
                            iterations=run.iterations, objective=run.objective,
                            sigma=sig, run=SolveRecord(solver="newton", init=start.source,
                                                       initial_trace=run.initial_trace,
                                                       compiled=built[0].codegen))

        ctx = Context(sub, resolved_solver(sub), "ocp-replan", {}, evaluate_newton=evaluate_run)
        tried = run_strategy(replan_strategy(ctx, moved), ctx, warm, None)
        if tried and tried[-1].outcome.solution.success:
            sol = tried[-1].outcome.solution.replaced(attempts=records(tried, len(tried) - 1))
    if sol is None:
        # IPOPT's models, or Newton did not converge: the whole strategy from the previous plan
        sol = solve_ocp_warm(sub, warm, method="ocp-replan")[0]
    return sol.replaced(run=replace(sol.run, warm_start_q=np.asarray(warm.q, float).tolist()))
