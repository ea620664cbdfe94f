"""The belief-space OCP solved by its strategy: choices resolved, attempts run, the plan picked and
reported.

`solve_ocp` / `solve_ocp_warm` take a Setup and an initial joint trajectory (`ocp_initial_guess`:
the straight line's or a gradient plan's IK) and return one Solution.
The solver choices are resolved once (`problem/solver_config.py`), the attempts are data
(`strategy.py`), each runs on a backend (`backends/`); here the best converged attempt is kept (or
the feasible start, when every converged point is above it), the attempts are recorded, and a
6x6-recursion model gets its second start.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.limits import enforce as enforce_limits
from ..output.solution import Solution
from ..output.solution_records import CondensedStart, SecondStart
from ..problem.setup import Setup
from ..problem.solver_config import resolve
from ..solvers.backends import Context
from ..ocp.iterate import InitialGuess, Iterate
from ..ocp.straight_line import straight_line
from ..solvers.newton import EXACT_MAX_N
from ..solvers.nlp_cache import newton_solver, transcription
from ..solvers.strategy import default_strategy, record, run
from ..status import Status

__all__ = ["ocp_initial_guess", "resolved_solver", "solve_ocp", "solve_ocp_warm"]


def ocp_initial_guess(setup: Setup, source: str = "baseline",
                      gradient: Solution | None = None) -> InitialGuess:
    """Joint trajectory to start the OCP from: IK of the straight line or of a gradient solution."""
    if source == "baseline":
        poses = straight_line(setup.x_start, setup.x_goal, setup.ocp.horizon)
    else:
        poses = np.asarray(gradient.poses)
    q_best, ok, _, _ = setup.joints_along(poses, setup.q_start,
                                          guesses=setup.joint_line(len(poses) - 1))
    note = (source if ok.all()
            else f"{source} ({int((~ok).sum())} waypoints unreachable, best-effort IK used)")
    return InitialGuess(q_best, note)


def resolved_solver(setup: Setup, form: str | None = None):
    """The problem's solver choices resolved for its model and robot (`solver_config.resolve`)."""
    return resolve(setup.ocp.solver, setup.model, len(setup.robot.supporting_joints()), form,
                   str(setup.ocp.source), limited=setup.ocp.limits.enforce)


def solve_ocp(setup: Setup, init: InitialGuess, solver_options: dict | None = None,
              method: str = "ocp", form: str | None = None) -> Solution:
    """Solve the belief-space OCP from the initial joint trajectory `init` (see
    `solve_ocp_warm`)."""
    return solve_ocp_warm(setup, init, solver_options, method, form)[0]


def solve_ocp_warm(setup: Setup, init: InitialGuess, solver_options: dict | None = None,
                   method: str = "ocp", form: str | None = None,
                   warm: Iterate | None = None) -> tuple[Solution, Iterate | None]:
    """Solve the belief-space OCP; also return where it ended, for a later warm start.

    The attempts are `strategy.default_strategy`'s; the lifted form starts at the condensed
    solution. A feasible start is returned (`Initial_Guess_Kept`) when every converged point is
    worse, so the plan is never worse than where it began. With `limits.enforce` the returned plan
    is checked against the motion limits (`Motion_Limits_Violated` otherwise). Every attempt is in
    `Solution.attempts` (with `kept`); time and iterations are their sums. Returns a Solution
    whatever the solvers' status; check `success` (the CLI turns a failure into an error carrying
    the status).
    """
    resolved = resolved_solver(setup, form)
    spec, opts = setup.ocp.solver, dict(solver_options or {})
    ctx = Context(setup, resolved, method, opts)
    pinned = "ipopt.mu_strategy" in opts or "mu_strategy" in spec.options
    limited = setup.ocp.limits.enforce
    pre, cold = None, init
    if resolved.form == "full" and resolved.hessian == "surrogate" and warm is None:
        # The lifted NLP starts at the condensed solution (joints; means, covariances and
        # multipliers follow): from the straight line IPOPT's first steps left the recursion and the
        # PSD cone (docs/general_models.md).
        pre = solve_ocp_warm(setup, init, solver_options, method, "condensed")[0]
        # no stationary point to start the lifted NLP from: the same plan
        if pre.status == Status.INITIAL_GUESS_KEPT:
            return pre.replaced(run=replace(pre.run, lifted=(
                "not run: the condensed solve kept its start, where the lifted NLP does not "
                "converge (docs/general_models.md)"))), None
        if pre.success:
            init = InitialGuess(np.array(pre.q), f"condensed solution ({init.source})")
    strategy = default_strategy(ctx, warm, pinned, lifted_start=pre is not None and pre.success)
    ran = run(strategy, ctx, init, warm)
    tried = [(t.label, t.attempt.hessian, t.outcome.solution, t.outcome.iterate) for t in ran]
    finished = [k for k, (_, _, s_k, _) in enumerate(tried) if s_k.success]
    pick = min(finished, key=lambda k: tried[k][2].objective) if finished else len(tried) - 1
    smooth0 = setup.ocp.smoothness * float(np.sum(np.diff(np.asarray(cold.q, float), axis=0) ** 2))
    costly = setup.model.structured and not setup.model.scalar
    if warm is None and ((finished and tried[pick][2].objective
                          > _start_objective(tried[pick][2], smooth0))
                         or ((costly or limited) and not finished and tried)):
        # Every converged point is above the (cold) start: keep the start if it is a feasible plan,
        # rather than return a plan worse than the one we began from. With enforced limits also when
        # nothing converged and the start meets every limit (docs/hessian_and_newton.md,
        # "Fallbacks").
        pick = _kept_start(ran, tried, finished, init, pick)
    sol, last = tried[pick][2], tried[pick][3]
    sol = _report(sol, tried, pick, init, warm, _start_objective(sol, smooth0))
    # the condensed solve that started the lifted one: reported, and counted in time
    if pre is not None:
        sol = _count_condensed_start(sol, pre)
    if (costly and resolved.form == "condensed" and warm is None and not limited
            and resolved.newton_fits and spec.name != "ipopt"):
        sol, last = _second_start(setup, cold, sol, last, solver_options, method)
    sol = enforce_limits(setup, sol)
    if setup.ocp.limits.enforce and not sol.success:
        last = None  # no warm start from a plan that breaks a limit
    return sol, last


def _start_objective(s_k: Solution, smooth0: float) -> float:
    """The planner's objective at the cold start (trace + smoothness `smooth0`)."""
    return s_k.run.initial_trace * (1 + smooth0)


def _kept_start(ran: list, tried: list, finished: list[int], init: InitialGuess, pick: int) -> int:
    """The feasible start appended to `tried` as the plan kept (the last NLP's start point and
    bounds), when there is one; returns the index picked."""
    nlps = [t.outcome.start_solution for t in ran if t.outcome.start_solution is not None]
    start = nlps[-1](init) if nlps else None  # the last NLP's start point and bounds
    if start is not None:
        ran = sorted({s_k.run.solver for _, _, s_k, _ in tried})
        start = start.replaced(run=replace(start.run, solver=(
            f"none (the initial guess; {', '.join(ran)} did not end below it)")))
        tried.append(("none: the feasible initial guess, below every converged point"
                      if finished
                      else "none: the feasible initial guess (no attempt converged)",
                      None, start, None))
        pick = len(tried) - 1
    return pick


def _report(sol: Solution, tried: list, pick: int, init: InitialGuess, warm: Iterate | None,
            initial_objective: float) -> Solution:
    """The plan kept (`tried[pick]`) with every attempt recorded, its time and iterations their
    sums."""
    run = replace(sol.run, hessian=" + ".join(label for label, _, _, _ in tried),
                  initial_objective=initial_objective,
                  worse_than_initial_guess=bool(sol.objective > initial_objective),
                  init=init.source if warm is None else f"warm start ({init.source})")
    return sol.replaced(
        attempts=[record(label, hess, s_k, k == pick)
                  for k, (label, hess, s_k, _) in enumerate(tried)],
        run=run, solve_time_s=sum(s_k.solve_time_s for _, _, s_k, _ in tried),
        iterations=sum(s_k.iterations for _, _, s_k, _ in tried))


def _count_condensed_start(sol: Solution, pre: Solution) -> Solution:
    """`sol` with the condensed solve `pre` that started the lifted one reported, and counted in
    its time and iterations."""
    run = replace(sol.run, condensed_start=CondensedStart(
        pre.status, pre.iterations, pre.run.solver, pre.solve_time_s, pre.objective),
        initial_trace=pre.run.initial_trace, initial_objective=pre.run.initial_objective,
        worse_than_initial_guess=bool(sol.objective > pre.run.initial_objective))
    return sol.replaced(run=run, solve_time_s=sol.solve_time_s + pre.solve_time_s,
                        iterations=sol.iterations + pre.iterations)


SECOND_START_ITER = 60
# Newton iterations for the diagonal model's plan beyond EXACT_MAX_N joint variables
GATE_ITER = 100


def diagonal_model_setup(setup: Setup) -> Setup:
    """The same setup with every base covariance replaced by its diagonal and no joint-space motion
    noise: a scalar model, cheap to solve."""
    n = setup.ocp.noise
    diag = {k: np.diag(np.diag(np.asarray(getattr(n, k), float)))
            for k in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "V_min", "Sigma0")}
    return setup.with_ocp(noise=replace(n, **diag, joint_sigma=None))


def _objective_at(setup: Setup, sol: Solution, other: Solution) -> float:
    """The planner's objective (its model's Tr(Sigma_T) plus the smoothness term, scaled like
    `sol.objective`) at the joints of another plan."""
    q = np.asarray(other.q, float)
    sig, pred = setup.model.propagate(setup.poses_of(q), joint=setup.joint_noises(q))
    trace = float(np.trace(pred[-1] if setup.model.noise.objective == "predicted" else sig[-1]))
    smooth = setup.ocp.smoothness * float(np.sum(np.diff(np.asarray(other.q, float), axis=0) ** 2))
    return trace + smooth * sol.run.initial_trace


def _second_start(setup: Setup, cold: InitialGuess, sol: Solution, last, solver_options,
                  method: str):
    """A 6x6-recursion model also solves its diagonal approximation (a scalar model, a few ms);
    where that plan scores below the first one in this model, Newton starts from it too and the
    better converged plan is kept, so the plan is never above the diagonal model's: from the
    straight line alone a few per cent of the optima were above the paper plan evaluated in the same
    model (docs/general_models.md)."""
    diag = diagonal_model_setup(setup)
    if setup.robot.nq * (setup.ocp.horizon + 1) <= EXACT_MAX_N:
        approx = solve_ocp_warm(diag, cold, solver_options, method, "condensed")[0]
    else:
        # long horizons: the scalar recursion has no exact end-game there; a capped Newton run, not
        # the full strategy, which can cost many times the plan itself (docs/general_models.md)
        spec = setup.ocp.solver
        approx = newton_solver(diag).solve(diag, cold, method, tol=spec.tol,
                                           max_iter=min(GATE_ITER, spec.max_iter))
    extra_time, extra_it = approx.solve_time_s, approx.iterations
    ahead = (approx.success and approx.status != Status.INITIAL_GUESS_KEPT
             and _objective_at(setup, sol, approx) < sol.objective)
    # the diagonal plan itself scores below the first plan: worth a Newton run from it
    gate = SecondStart(approx.status, approx.iterations, approx.solve_time_s, bool(ahead))
    if ahead:
        spec = setup.ocp.solver
        # a short Newton run (the surrogate converges linearly on the 6x6 recursion, so a long run
        # is slow: docs/general_models.md, "The secant end-game"), then IPOPT finishes it if it is
        # the better point
        second = newton_solver(setup).solve(
            setup, InitialGuess(np.array(approx.q), "diagonal model's plan"), method, tol=spec.tol,
            max_iter=min(SECOND_START_ITER, spec.max_iter))
        gate = replace(gate, newton_status=second.status, newton_iterations=second.iterations,
                       newton_objective=second.objective)
        extra_time += second.solve_time_s
        extra_it += second.iterations
        if (not second.success and second.status == Status.MAXIMUM_ITERATIONS_EXCEEDED
            and second.objective < sol.objective):
            # Newton's surrogate converges linearly on the 6x6 recursion; a better unfinished point
            # is finished by IPOPT (same surrogate Hessian, with the depth bound)
            tr = transcription(setup, "condensed", solver_options, hessian="surrogate")
            second, _ = tr.solve(
                setup, InitialGuess(np.array(second.q), "Newton from the diagonal model's plan"),
                method)
            gate = replace(gate, ipopt_status=second.status, ipopt_iterations=second.iterations)
            extra_time += second.solve_time_s
            extra_it += second.iterations
        if second.success and (not sol.success or second.objective < sol.objective * (1 - 1e-9)):
            label = f"{second.run.solver} from the diagonal model's plan"
            run = replace(second.run, initial_trace=sol.run.initial_trace,
                          initial_objective=sol.run.initial_objective,
                          hessian=sol.run.hessian + f" + {label}", init=sol.run.init,
                          worse_than_initial_guess=bool(
                              second.objective > sol.run.initial_objective))
            attempts = ([replace(a, kept=False) for a in sol.attempts]
                        + [record(label, "surrogate", second, True)])
            second = second.replaced(attempts=attempts, run=run, solve_time_s=sol.solve_time_s,
                                     iterations=sol.iterations)
            sol, last = second, (Iterate(np.array(second.q))
                                 if second.run.solver == "newton" else None)
    return sol.replaced(run=replace(sol.run, second_start=gate),
                        solve_time_s=sol.solve_time_s + extra_time,
                        iterations=sol.iterations + extra_it), last
