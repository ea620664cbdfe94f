"""The solve strategy picks its fallback by what failed (ocp.solve_ocp_warm)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import numpy_ekf as ref
from surestep_ocp.solvers.baseline import solve_baseline
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.solvers.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup

DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"
EVALUATION = DEFAULT.parent / "evaluations" / "evaluation.yaml"


def _configuration_73(solver: str):
    sampler = ConfigurationSampler(load_evaluation(EVALUATION))
    prob = replace(sampler.problem(sampler.sample(0, 73)), horizon=40)
    return build_setup(replace(prob, solver=replace(prob.solver, codegen=False, name=solver)))


def test_a_false_infeasibility_verdict_is_retried_with_the_monotone_barrier(monkeypatch):
    """IPOPT alone on the default problem (T = 6), its first attempt made to end "infeasible" (as the adaptive barrier
    did on evaluation configuration 73 at T = 40, compiled): the monotone barrier with the same Hessian runs next,
    and no exact-Hessian attempt; its plan is IPOPT's own optimum, below the straight line."""
    import surestep_ocp.solvers.transcription as tr

    setup = build_setup(replace(load_problem(DEFAULT), horizon=6))
    setup = replace(setup, problem=replace(setup.problem, solver=replace(setup.problem.solver, name="ipopt")))
    plain = solve_ocp(setup, ocp_initial_guess(setup))
    real, calls = tr.Transcription.solve, []

    def first_infeasible(self, *args, **kw):
        sol, reached = real(self, *args, **kw)
        calls.append(sol.status)
        if len(calls) == 1:
            sol.status, sol.success = "Infeasible_Problem_Detected", False
        return sol, reached

    monkeypatch.setattr(tr.Transcription, "solve", first_infeasible)
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("surrogate", "Infeasible_Problem_Detected"), ("surrogate, monotone barrier", "Solve_Succeeded")]
    assert sol.trace_final == pytest.approx(plain.trace_final, rel=1e-5)
    assert sol.trace_final < solve_baseline(setup).trace_final


def _ipopt_monotone(setup):
    """IPOPT alone with its monotone barrier update: the central path Newton's barrier run follows."""
    spec = setup.problem.solver
    return replace(setup, problem=replace(setup.problem, solver=replace(
        spec, name="ipopt", options={**spec.options, "mu_strategy": "monotone"})))


def test_a_depth_violation_by_newton_goes_to_newton_on_the_barrier_problem():
    """The same configuration with the default solver: Newton's plan goes below the depth bound, Newton on IPOPT's
    barrier problem runs next and is the plan. It is IPOPT's own (monotone barrier) optimum, meets the bound by
    Pinocchio's FK, and its trace is the NumPy EKF's and below the straight line's."""
    setup = _configuration_73("auto")
    init = ocp_initial_guess(setup)
    sol = solve_ocp(setup, init)
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("newton", "Depth_Bound_Violated"), ("newton, depth barrier", "Solve_Succeeded")]
    assert sol.extras["solver"] == "newton"
    ipopt = solve_ocp(_ipopt_monotone(setup), init)
    assert ipopt.extras["solver"] == "ipopt" and ipopt.success
    assert sol.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    depths = [setup.pose_of(q)[2] for q in np.asarray(sol.q)]
    assert min(depths) >= setup.problem.min_depth
    poses = np.asarray(sol.poses)
    n = setup.problem.noise
    ekf = np.trace(ref.propagate(poses, n, setup.problem.camera.intrinsics, guard=n.cosine_guard**2)[0][-1])
    assert ekf == pytest.approx(sol.trace_final, rel=1e-9)
    assert sol.trace_final < solve_baseline(setup).trace_final


def test_a_failed_barrier_run_goes_to_ipopts_monotone_barrier(monkeypatch):
    """Where Newton's barrier run does not converge (here: cut to one iteration), IPOPT with the monotone barrier
    follows from the straight line, and its plan meets the bound."""
    from surestep_ocp.solvers.newton import NewtonSolver

    real = NewtonSolver.run_barrier
    monkeypatch.setattr(NewtonSolver, "run_barrier", lambda self, setup, init, tol=1e-6, max_iter=300,
                        verbose=False: real(self, setup, init, tol, 1, verbose))
    setup = _configuration_73("auto")
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("newton", "Depth_Bound_Violated"), ("newton, depth barrier", "Maximum_Iterations_Exceeded"),
                     ("surrogate, monotone barrier", "Solve_Succeeded")]
    assert sol.extras["solver"] == "ipopt"
    assert np.asarray(sol.poses)[:, 2].min() >= setup.problem.min_depth - 1e-8


def test_newton_stops_early_below_the_depth_bound_and_the_fallback_meets_it(monkeypatch):
    """Configuration 73 at T = 40: Newton's iterates go below the minimum depth in its end phase and stay there; it
    stops there (fewer iterations than without the check, same verdict), and the returned plan meets the bound by
    Pinocchio's FK of its joints."""
    import surestep_ocp.solvers.newton as newton
    from surestep_ocp.solvers.nlp_cache import newton_solver

    setup = _configuration_73("auto")
    init = ocp_initial_guess(setup)
    early = newton_solver(setup).run(setup, init)
    monkeypatch.setattr(newton, "DEPTH_CHECK_BELOW", -1.0)  # never checked before the end
    late = newton_solver(setup).run(setup, init)
    monkeypatch.undo()
    assert early.status == late.status == "Depth_Bound_Violated"
    assert early.iterations < late.iterations
    sol = solve_ocp(setup, init)
    assert sol.success and sol.attempts[0].status == "Depth_Bound_Violated"
    depths = [setup.pose_of(q)[2] for q in np.asarray(sol.q)]
    assert min(depths) >= setup.problem.min_depth - 1e-7
