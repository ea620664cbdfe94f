"""The belief-space OCP's solve strategy: which solvers run in which order, and what is returned.

`solve_ocp` / `solve_ocp_warm` take a Setup and an initial joint trajectory and return one Solution. The
transcriptions are in `transcription.py` (condensed, gain-lifted, diagonal) and `lifted.py` (vech(Sigma)
multiple shooting with the structured Hessian), the projected Newton solver in `newton.py`, the choice of
form, Hessian and options and the caches in `solver_setup.py`. The names used elsewhere are re-exported here.
"""

from __future__ import annotations

import numpy as np

from ..errors import SurestepError
from ..model.limits import enforce as enforce_limits
from ..problem.setup import Setup
from ..output.solution import Solution
from .newton import EXACT_MAX_N
from .solver_setup import (LIFTED_FROM_CONDENSED, WARM_OPTIONS, cached_transcriptions, newton_applies,
                           newton_solver, resolve_codegen, resolve_hessian, transcription)
from .transcription import (CODEGEN_EXACT, FORMS, HESSIANS, InitialGuess, NewtonWarm, Transcription, WarmStart,
                            resolve_form)

__all__ = ["CODEGEN_EXACT", "FORMS", "HESSIANS", "InitialGuess", "NewtonWarm", "Transcription", "WarmStart",
           "cached_transcriptions", "newton_applies", "newton_solver", "resolve_codegen", "resolve_form",
           "resolve_hessian", "solve_ocp", "solve_ocp_warm", "transcription"]


def solve_ocp(setup: Setup, init: InitialGuess, solver_options: dict | None = None,
              method: str = "ocp", form: str | None = None) -> Solution:
    """Solve the belief-space OCP from the initial joint trajectory `init` (see `solve_ocp_warm`)."""
    return solve_ocp_warm(setup, init, solver_options, method, form)[0]


def solve_ocp_warm(setup: Setup, init: InitialGuess, solver_options: dict | None = None, method: str = "ocp",
                   form: str | None = None, warm: WarmStart | NewtonWarm | None = None
                   ) -> tuple[Solution, WarmStart | NewtonWarm | None]:
    """Solve the belief-space OCP; also return the primal-dual point for a later warm start.

    Newton first where it applies (`newton_applies`), then IPOPT attempts on the same NLP that differ in
    the Hessian (surrogate, then exact), the start (`init`, `warm`, or where the last attempt stopped) and
    the barrier update (adaptive, then monotone); the lifted form starts at the condensed solution. A feasible
    start is returned (`Initial_Guess_Kept`) when every converged point is worse, so the plan is never worse
    than where it began. With `limits.enforce` the returned plan is checked against the motion limits
    (`Motion_Limits_Violated` otherwise). The order and why, with measurements: docs/hessian_and_newton.md,
    "Fallbacks: the order of attempts".

    Every attempt is reported in `extras["attempts"]` (with `kept`); time and iterations are their sums.
    Returns a Solution whatever IPOPT's status; check `success` (the CLI turns a failure
    into an error carrying the status).
    """
    form = resolve_form(setup.model, form or setup.problem.solver.covariance)
    hessian = resolve_hessian(setup, form)
    spec, opts = setup.problem.solver, dict(solver_options or {})
    if spec.codegen is True and hessian == "exact":
        raise SurestepError(CODEGEN_EXACT)
    pinned = "ipopt.mu_strategy" in opts or "mu_strategy" in spec.options
    tried: list[tuple[str, Solution, WarmStart | NewtonWarm | None]] = []
    used: list[Transcription] = []

    def attempt(name: str, hess: str, extra: dict, start: WarmStart | None) -> bool:
        extra = {**extra, **WARM_OPTIONS} if start is not None else extra
        used.append(transcription(setup, form, {**opts, **extra}, hessian=hess))
        sol, reached = used[-1].solve(setup, init, method, warm=start)
        tried.append((name + (", warm start" if start is not None else ""), sol, reached))
        return sol.success

    pre, cold = None, init
    limited = setup.problem.limits.enforce
    exact_cap = {"ipopt.max_iter": min(spec.surrogate_max_iter, spec.max_iter)} if limited else {}
    if form == "full" and hessian == "surrogate" and warm is None:
        # The lifted NLP starts at the condensed solution (joints; means, covariances and multipliers follow):
        # from the straight line IPOPT's filter accepted first steps whose covariances left the recursion and the
        # PSD cone (lifted.py), although the step in the joints equals the condensed one.
        pre = solve_ocp_warm(setup, init, solver_options, method, "condensed")[0]
        if pre.status == "Initial_Guess_Kept":  # no stationary point to start the lifted NLP from: the same plan
            pre.extras["lifted"] = ("not run: the condensed solve kept its start, where the lifted NLP does not "
                                    "converge (docs/general_models.md)")
            return pre, None
        if pre.success:
            init = InitialGuess(np.array(pre.q), f"condensed solution ({init.source})")
    done = False
    forced = spec.hessian in ("surrogate", "gauss-newton")  # no exact-Hessian attempts
    # The exact Hessian of the 6x6 recursion is unrolled and interpreted: seconds per iteration (evaluation
    # configuration 45 with a correlated V_d0: 1009 iterations, 94 s, to keep the start anyway). For such models the
    # fallbacks stop at the structured Hessian, and a feasible start is kept when nothing converged below it.
    costly = setup.model.structured and not setup.model.scalar
    newton_fits = newton_applies(setup, form, hessian, forced)
    if spec.name == "newton" and not newton_fits:
        raise SurestepError("solver.name: newton needs the condensed form of a model with constant motion and "
                            "observation maps, noise.observation_noise: mean, solver.hessian: auto and exactly six joints moving the "
                            "tracked frame (the goal pose then fixes the last joints); use solver.name: auto or ipopt")
    warm_given = warm is not None
    # With enforced limits `auto` goes to IPOPT directly: Newton has no step constraints, and its plan broke the limits
    # in all 300 enforced solves measured (T = 40 at 0.05 s, T = 20 at 0.1 and 0.2 s; 0.08 s each, and IPOPT starts
    # from `init` either way: from Newton's plan it took 69 iterations against 54)
    if (spec.name == "newton" or (spec.name == "auto" and not limited)) and newton_fits and (
            warm is None or isinstance(warm, NewtonWarm)):
        start = init if warm is None else InitialGuess(np.asarray(warm.q), f"warm start ({init.source})")
        newton = newton_solver(setup)
        newton_cap = min(spec.surrogate_max_iter, spec.max_iter)
        first = newton.solve(setup, start, method, tol=spec.tol, max_iter=newton_cap, verbose=spec.print_level > 0)
        enforce_limits(setup, first)  # Newton has no step constraints: a plan over an enforced limit goes to IPOPT
        tried.append(("newton" + (", warm start" if warm is not None else ""), first,
                      NewtonWarm(np.array(first.q)) if first.success else None))
        done = first.success
        if first.status == "Depth_Bound_Violated" and setup.model.scalar:
            # Newton on IPOPT's barrier problem, which has the bound, from `init`: the central path of the IPOPT
            # fallback below (the monotone barrier) at Newton's cost per iteration (newton.run_barrier). Measured
            # with the scalar recursion; the 6x6 one (general models) keeps the IPOPT fallback.
            barrier = newton.solve(setup, init, method, tol=spec.tol, max_iter=newton_cap,
                                   verbose=spec.print_level > 0, barrier=True)
            enforce_limits(setup, barrier)
            tried.append(("newton, depth barrier", barrier,
                          NewtonWarm(np.array(barrier.q)) if barrier.success else None))
            done = barrier.success
    if isinstance(warm, NewtonWarm):  # IPOPT has no multipliers from Newton: it starts cold from init
        warm = None
    if warm is not None:  # near the optimum already: Newton's local convergence (the lifted form: its own Hessian)
        hess = hessian if forced or form == "full" else "exact"
        done = attempt(hess, hess, {}, warm)
    if not done and hessian != "exact":
        cap = spec.max_iter if forced else min(spec.surrogate_max_iter, spec.max_iter)
        near = LIFTED_FROM_CONDENSED if pre is not None and pre.success and not pinned else {}
        # Newton's plan went below the depth bound: the bound is active at the optimum, where the monotone barrier
        # is the robust choice (configuration 73 at T = 40: 37 iterations where the adaptive one declared the
        # problem infeasible after 215; the other depth fallbacks of T = 20 and 40 converge either way)
        depth = {} if pinned or not tried or tried[0][1].status != "Depth_Bound_Violated" else {
            "ipopt.mu_strategy": "monotone"}
        done = attempt("lifted" if form == "full" else hessian + (", monotone barrier" if depth else ""), hessian,
                       {"ipopt.max_iter": cap, **near, **depth}, None)
        if not done and near:  # the small monotone barrier did not settle: the adaptive update from the same point
            done = attempt("lifted, adaptive barrier", hessian, {"ipopt.max_iter": cap}, None)
        if not done and not (near or depth or pinned or limited) and tried[-1][1].status in FALSE_VERDICTS:
            # "infeasible" from a start that meets every bound (the straight line's IK) is the adaptive barrier's
            # restoration failing, not the problem: the monotone barrier with the same cheap Hessian first (evaluation
            # configuration 73 at T = 40: 37 iterations, 0.07 s, where the exact-Hessian fallbacks took 920, 34 s)
            done = attempt(f"{hessian}, monotone barrier", hessian, {"ipopt.max_iter": cap,
                                                                     "ipopt.mu_strategy": "monotone"}, None)
        # With enforced motion limits, IPOPT's infeasibility verdict is the limits' (the Hessian only shapes the
        # steps): the exact-Hessian attempts ended infeasible too (evaluation configurations 1, 2, 4 at step_s
        # 0.05: 9 of 9 attempts, 5-8 s each), so none follow; and they are capped at surrogate_max_iter (one that
        # did not converge ran 3 x 3000 iterations, 265 s).
        done = done or (limited and tried[-1][1].status == "Infeasible_Problem_Detected")
        if not done and not forced and form == "condensed" and not costly:  # polish from the point reached
            done = attempt("exact", "exact", exact_cap, tried[-1][2])
    if not done and not forced and (not costly or hessian == "exact"):  # the exact Hessian asked for: always tried
        done = attempt("exact", "exact", exact_cap, None)
        if not done and not pinned:
            attempt("exact, monotone barrier", "exact", {"ipopt.mu_strategy": "monotone", **exact_cap}, None)
    finished = [k for k, (_, s_k, _) in enumerate(tried) if s_k.success]
    pick = min(finished, key=lambda k: tried[k][1].objective) if finished else len(tried) - 1
    smooth0 = setup.problem.objective.smoothness * float(np.sum(np.diff(np.asarray(cold.q, float), axis=0) ** 2))

    def start_objective(s_k: Solution) -> float:  # the planner's objective at the cold start (trace + smoothness)
        return s_k.extras["initial_trace"] * (1 + smooth0)

    if warm is None and ((finished and tried[pick][1].objective > start_objective(tried[pick][1]))
                         or ((costly or limited) and not finished and tried)):
        # Every converged point is above the (cold) start: keep the start if it is a feasible plan, rather than
        # return a plan worse than the one we began from (step 4). Reported as its own attempt.
        # With enforced limits also when nothing converged and the start meets every limit (evaluation configurations
        # 0, 36, 45, 91 at step_s 0.2: the straight line is within the limits, IPOPT stops at its iteration caps).
        start = used[-1].start_solution(setup, init, method) if used else None  # same start point and bounds
        if start is not None:
            ran = sorted({s_k.extras["solver"] for _, s_k, _ in tried})
            start.extras["solver"] = f"none (the initial guess; {', '.join(ran)} did not end below it)"
            tried.append(("none: the feasible initial guess, below every converged point" if finished else
                          "none: the feasible initial guess (no attempt converged)", start, None))
            pick = len(tried) - 1
    sol, last = tried[pick][1], tried[pick][2]
    sol.extras["attempts"] = [{"hessian": name, "status": s_k.status, "iterations": s_k.iterations,
                               "solve_time_s": s_k.solve_time_s, "objective": s_k.objective, "kept": k == pick,
                               "compiled": s_k.extras["compiled"]}
                              for k, (name, s_k, _) in enumerate(tried)]
    sol.extras["hessian"] = " + ".join(name for name, _, _ in tried)
    sol.extras["initial_objective"] = start_objective(sol)
    sol.extras["worse_than_initial_guess"] = bool(sol.objective > sol.extras["initial_objective"])
    sol.extras["init"] = init.source if not warm_given else f"warm start ({init.source})"
    sol.solve_time_s = sum(s_k.solve_time_s for _, s_k, _ in tried)
    sol.iterations = sum(s_k.iterations for _, s_k, _ in tried)
    if pre is not None:  # the condensed solve that started the lifted one: reported, and counted in time
        sol.extras["condensed_start"] = {"status": pre.status, "iterations": pre.iterations, "solver":
                                         pre.extras.get("solver"), "solve_time_s": pre.solve_time_s,
                                         "objective": pre.objective}
        sol.extras["initial_trace"] = pre.extras["initial_trace"]
        sol.extras["initial_objective"] = pre.extras["initial_objective"]
        sol.extras["worse_than_initial_guess"] = bool(sol.objective > sol.extras["initial_objective"])
        sol.solve_time_s += pre.solve_time_s
        sol.iterations += pre.iterations
    if costly and form == "condensed" and warm is None and not limited and newton_fits and spec.name != "ipopt":
        sol, last = _second_start(setup, cold, sol, last, solver_options, method)
    if enforce_limits(setup, sol) and not sol.success:
        last = None  # no warm start from a plan that breaks a limit
    return sol, last


SECOND_START_ITER = 60
GATE_ITER = 100  # Newton iterations for the diagonal model's plan beyond EXACT_MAX_N joint variables
# IPOPT statuses that, from a feasible start, say more about the barrier's path than about the problem
FALSE_VERDICTS = ("Infeasible_Problem_Detected", "Restoration_Failed", "Error_In_Step_Computation")


def diagonal_model_setup(setup: Setup) -> Setup:
    """The same setup with every base covariance replaced by its diagonal and no joint-space motion noise: a scalar
    model, cheap to solve."""
    from dataclasses import replace

    n = setup.problem.noise
    diag = {k: np.diag(np.diag(np.asarray(getattr(n, k), float)))
            for k in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "V_min", "Sigma0")}
    return replace(setup, problem=replace(setup.problem, noise=replace(n, **diag, joint_sigma=None)))


def _objective_at(setup: Setup, sol: Solution, other: Solution) -> float:
    """The planner's objective (its model's Tr(Sigma_T) plus the smoothness term, scaled like `sol.objective`) at
    the joints of another plan."""
    q = np.asarray(other.q, float)
    sig, pred = setup.model.propagate(setup.poses_of(q), joint=setup.joint_noises(q))
    trace = float(np.trace(pred[-1] if setup.model.noise.objective == "predicted" else sig[-1]))
    smooth = setup.problem.objective.smoothness * float(np.sum(np.diff(np.asarray(other.q, float), axis=0) ** 2))
    return trace + smooth * sol.extras["initial_trace"]


def _second_start(setup: Setup, cold: InitialGuess, sol: Solution, last, solver_options, method: str):
    """A 6x6-recursion model also solves its diagonal approximation (a scalar model, a few ms); where that plan
    scores below the first one in this model, Newton starts from it too and the better converged plan is kept, so
    the plan is never above the diagonal model's. Measured on 100 evaluation configurations: from the straight
    line alone 1-4 % of the optima were above the paper plan evaluated in the same model."""
    diag = diagonal_model_setup(setup)
    if setup.robot.nq * (setup.problem.horizon + 1) <= EXACT_MAX_N:
        approx = solve_ocp_warm(diag, cold, solver_options, method, "condensed")[0]
    else:  # long horizons: the scalar recursion has no exact end-game there; a capped Newton run or no gate (its full
        # strategy took 9.8 s for configuration 9 at T = 80 with a correlated V_d0, where the plan itself took 0.4 s)
        spec = setup.problem.solver
        approx = newton_solver(diag).solve(diag, cold, method, tol=spec.tol, max_iter=min(GATE_ITER, spec.max_iter))
    record = {"status": approx.status, "iterations": approx.iterations, "solve_time_s": approx.solve_time_s}
    extra_time, extra_it = approx.solve_time_s, approx.iterations
    ahead = approx.success and approx.status != "Initial_Guess_Kept" and _objective_at(setup, sol, approx) < sol.objective
    record["ahead"] = bool(ahead)  # the diagonal plan itself scores below the first plan: worth a Newton run from it
    if ahead:
        spec = setup.problem.solver
        # a short Newton run (the surrogate converges linearly on the 6x6 recursion: 300 iterations cost about 2 s
        # on the default problem with a correlated V_d0), then IPOPT finishes it if it is the better point
        second = newton_solver(setup).solve(setup, InitialGuess(np.array(approx.q), "diagonal model's plan"),
                                            method, tol=spec.tol, max_iter=min(SECOND_START_ITER, spec.max_iter))
        record.update(newton_status=second.status, newton_iterations=second.iterations,
                      newton_objective=second.objective)
        extra_time += second.solve_time_s
        extra_it += second.iterations
        if not second.success and second.status == "Maximum_Iterations_Exceeded" and second.objective < sol.objective:
            # Newton's surrogate converges linearly on the 6x6 recursion; a better unfinished point is finished by
            # IPOPT (same surrogate Hessian, with the depth bound)
            tr = transcription(setup, "condensed", solver_options, hessian="surrogate")
            second, _ = tr.solve(setup, InitialGuess(np.array(second.q), "Newton from the diagonal model's plan"),
                                 method)
            record.update(ipopt_status=second.status, ipopt_iterations=second.iterations)
            extra_time += second.solve_time_s
            extra_it += second.iterations
        if second.success and (not sol.success or second.objective < sol.objective * (1 - 1e-9)):
            for key in ("attempts", "initial_trace", "initial_objective"):
                second.extras[key] = sol.extras[key]
            second.extras["attempts"] = [{**a, "kept": False} for a in sol.extras["attempts"]] + [
                {"hessian": f"{second.extras['solver']} from the diagonal model's plan", "status": second.status,
                 "iterations": second.iterations, "solve_time_s": second.solve_time_s,
                 "objective": second.objective, "kept": True, "compiled": second.extras["compiled"]}]
            second.extras["hessian"] = sol.extras["hessian"] + f" + {second.extras['solver']} from the diagonal model's plan"
            second.extras["init"] = sol.extras["init"]
            second.extras["worse_than_initial_guess"] = bool(second.objective > second.extras["initial_objective"])
            second.solve_time_s, second.iterations = sol.solve_time_s, sol.iterations
            sol, last = second, NewtonWarm(np.array(second.q)) if second.extras["solver"] == "newton" else None
    sol.extras["second_start"] = record
    sol.solve_time_s += extra_time
    sol.iterations += extra_it
    return sol, last
