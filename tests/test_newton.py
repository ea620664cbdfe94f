"""The projected Newton solver (`solver.name: newton`): its gradient against finite differences, its
optima against IPOPT's (also on the non-diagonal models of test_lifted.py, against a NumPy EKF), its
barrier run where the depth bound is violated, its errors, and its secant end-game
(`newton._SecantCorrection`: the Woodbury step against a dense solve, the positive-definiteness test
against eigenvalues, a 6x6-recursion solve that uses it against IPOPT with the exact Hessian)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy_ekf import propagate
from scipy.linalg.lapack import dpbtrf
from test_lifted import MODELS, correlated_depth, problem

from surestep_ocp.model.belief import COSINE_GUARD, vech
from surestep_ocp.errors import SurestepError
from surestep_ocp.methods.registry import ocp_initial_guess
from surestep_ocp.solvers.nlp_cache import newton_solver
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.problem.solver_config import resolve_form
from surestep_ocp.solvers.newton import _SecantCorrection


DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"


def with_solver(setup, **kw):
    return setup.with_ocp(solver=replace(setup.ocp.solver, **kw))


@pytest.fixture(scope="module")
def short():
    return build_setup(replace(load_problem(DEFAULT), horizon=6))


def test_newton_gradient_matches_finite_differences(short):
    """The assembled joint-space gradient (stage blocks scattered) is the objective's, by central
    differences."""
    setup = short.with_ocp(smoothness=0.2)
    ns = newton_solver(setup)
    q = np.asarray(ocp_initial_guess(setup).q, float)
    rng = np.random.default_rng(1)
    x = (q + 0.02 * rng.normal(size=q.shape)).ravel()
    sigma0 = np.diag(setup.model.channel_variances(np.asarray(setup.ocp.noise.Sigma0, float)))
    P = np.concatenate([setup.camera_parameter(), [3e-5], vech(sigma0)])
    _, _, G, _, _ = (v.copy() for v in ns.step(x, P))
    g = np.bincount(ns.g_index, weights=G, minlength=ns.n)
    fd = np.zeros(ns.n)
    for i in range(ns.n):
        e = np.zeros(ns.n)
        e[i] = 1e-6
        fd[i] = (ns.f(x + e, P)[0][0] - ns.f(x - e, P)[0][0]) / 2e-6
    assert np.max(np.abs(g - fd)) <= 1e-6 * np.max(np.abs(fd))


@pytest.mark.parametrize("horizon", [6, 20])
def test_newton_reaches_ipopts_optimum(horizon):
    """Same plan as IPOPT (trace to 1e-6), terminal pose exact, start and goal joints kept, bounds
    met."""
    setup = build_setup(replace(load_problem(DEFAULT), horizon=horizon))
    init = ocp_initial_guess(setup)
    # another solver (auto would run Newton)
    ipopt = solve_ocp(with_solver(setup, name="ipopt"), init)
    assert ipopt.run.solver == "ipopt" and "newton" not in ipopt.run.hessian
    newton = solve_ocp(with_solver(setup, name="newton"), init)
    assert (newton.success and newton.status == "Solve_Succeeded"
            and newton.run.solver == "newton")
    assert [a.label for a in newton.attempts] == ["newton"]
    assert newton.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    assert newton.run.ocp_trace_final == pytest.approx(newton.trace_final, rel=1e-9)
    q = np.array(newton.q)
    np.testing.assert_array_equal(q[0], np.asarray(init.q)[0])
    np.testing.assert_array_equal(q[-1], np.asarray(init.q)[-1])
    assert np.all(q >= setup.robot.lower) and np.all(q <= setup.robot.upper)
    assert max(newton.terminal_error) <= 1e-9
    assert min(p[2] for p in newton.poses) >= setup.ocp.min_depth


def test_newton_keeps_the_depth_bound_with_its_barrier_run_when_violated():
    """Evaluation configuration 39 at T = 20: Newton's optimum goes below the minimum depth (a bound
    its box form does not have); Newton on IPOPT's barrier problem then solves it from the start,
    with the bound, and that is the plan: IPOPT's own optimum with the monotone barrier
    (trace to 1e-6), the bound met by Pinocchio's FK."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

    sampler = ConfigurationSampler(load_evaluation(DEFAULT.parent / "evaluations"
                                                   / "evaluation.yaml"))
    setup = with_solver(build_setup(sampler.problem(sampler.sample(0, 39))), name="newton")
    init = ocp_initial_guess(setup)
    sol = solve_ocp(setup, init)
    attempts = [(a.label, a.status, a.kept) for a in sol.attempts]
    assert attempts == [("newton", "Depth_Bound_Violated", False),
                        ("newton, depth barrier", "Solve_Succeeded", True)]
    assert sol.success and sol.run.solver == "newton"
    ipopt = solve_ocp(with_solver(setup, name="ipopt", options={"mu_strategy": "monotone"}), init)
    assert ipopt.success and ipopt.run.solver == "ipopt"
    assert sol.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    assert min(setup.pose_of(q)[2] for q in np.asarray(sol.q)) >= setup.ocp.min_depth
    assert max(sol.terminal_error) <= 1e-9


def test_barrier_depth_derivatives_match_the_fk(short):
    """The barrier's per-node depth, its gradient and Hessian in the node's joints (`newton_depth`)
    against Pinocchio's FK and its central differences."""
    ns = newton_solver(short)
    q = np.asarray(ocp_initial_guess(short).q, float)
    rng = np.random.default_rng(2)
    q = q + 0.02 * rng.normal(size=q.shape)
    camera = short.camera_parameter()
    # camera parameters first (the rest does not enter the depth)
    P = np.zeros(ns.depth.args[1].size)
    P[:camera.size] = camera
    z, dz, d2z = (v.copy() for v in ns.depth(q.ravel(), P))
    nq, t, h = short.robot.nq, 3, 1e-5
    assert z == pytest.approx([short.pose_of(qt)[2] for qt in q], abs=1e-12)

    def depth(qt):
        return short.pose_of(qt)[2]

    grad = np.zeros(nq)
    hess = np.zeros((nq, nq))
    for i in range(nq):
        e = np.zeros(nq)
        e[i] = h
        grad[i] = (depth(q[t] + e) - depth(q[t] - e)) / (2 * h)
        for j in range(nq):
            f = np.zeros(nq)
            f[j] = h
            hess[i, j] = (depth(q[t] + e + f) - depth(q[t] + e - f) - depth(q[t] - e + f)
                          + depth(q[t] - e - f)) / (4 * h * h)
    np.testing.assert_allclose(dz.reshape(-1, nq)[t], grad, atol=1e-8)
    np.testing.assert_allclose(d2z.reshape(-1, nq, nq)[t], hess, atol=1e-4)


def test_newton_needs_the_surrogate_model(short):
    expected = short.with_ocp(noise=replace(short.ocp.noise, observation_noise="expected"))
    with pytest.raises(SurestepError, match="newton"):
        solve_ocp(with_solver(expected, name="newton"), ocp_initial_guess(expected))


def test_newton_only_where_the_goal_fixes_the_last_joints(short):
    """Seven (redundant) or five moving joints: the terminal pose does not fix q_T, so auto keeps
    IPOPT and an explicit `newton` is an error."""
    from types import SimpleNamespace

    from surestep_ocp.problem.solver_config import resolve
    from surestep_ocp.methods.ocp import resolved_solver

    assert resolved_solver(short).newton_fits
    spec = short.ocp.solver
    assert not resolve(replace(spec, hessian="exact"), short.model, 6).newton_fits
    assert not resolve(replace(spec, hessian="surrogate"), short.model, 6).newton_fits
    for n in (5, 7):
        arm = SimpleNamespace(supporting_joints=lambda n=n: list(range(n)))
        assert not resolved_solver(replace(short, robot=arm)).newton_fits
        with pytest.raises(SurestepError, match="solver.name: newton needs"):
            resolve(replace(spec, name="newton"), short.model, n)


def test_newton_warm_resolve_after_a_camera_move(short):
    """A Newton solution returns its joints as the warm start; after a small camera move the warm
    Newton solve reaches the cold optimum, in fewer iterations."""
    from surestep_ocp.methods.ocp import solve_ocp_warm

    setup = with_solver(short, name="auto")
    init = ocp_initial_guess(setup)
    first, warm = solve_ocp_warm(setup, init)
    assert first.run.solver == "newton" and not warm.has_duals
    np.testing.assert_array_equal(warm.q, np.array(first.q))
    D = np.eye(4)
    D[:3, 3] = [0.002, -0.001, 0.001]
    moved = setup.seen_from(setup.camera_pose @ D)
    again, _ = solve_ocp_warm(moved, init, warm=warm)
    cold = solve_ocp(moved, ocp_initial_guess(moved))
    assert again.success and again.attempts[0].label == "newton, warm start"
    assert again.run.init.startswith("warm start")
    assert again.trace_final == pytest.approx(cold.trace_final, rel=1e-4)
    assert again.iterations < cold.iterations


def test_kept_start_names_the_solvers_that_ran_and_smoothness_counts():
    """With `objective.smoothness: 50` IPOPT's converged plan on the default problem is far below
    the start in the objective it minimises (trace plus smoothness): it is returned, not replaced by
    the straight line (the old check compared that objective with the bare trace). A kept start
    names the solvers that ran."""
    prob = load_problem(DEFAULT)
    setup = build_setup(replace(prob, objective=replace(prob.objective, smoothness=50.0),
                                solver=replace(prob.solver, name="ipopt")))
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    assert sol.success and sol.status != "Initial_Guess_Kept", sol.run.hessian
    assert sol.objective < sol.run.initial_objective
    assert not sol.run.worse_than_initial_guess


def test_newton_stops_when_it_stalls(short):
    """From its own optimum with tol 0 (unreachable) Newton cannot decrease the objective: it stops
    as 'Stalled' after its window of iterations instead of running to max_iter, and hands over (not
    a success)."""
    from surestep_ocp.solvers.newton import STALL_WINDOW
    from surestep_ocp.solvers.nlp_cache import newton_solver
    from surestep_ocp.ocp.iterate import InitialGuess

    solver = newton_solver(short)
    opt = solver.run(short, ocp_initial_guess(short), tol=1e-6)
    assert opt.status == "Solve_Succeeded"
    stalled = solver.run(short, InitialGuess(opt.q, "its optimum"), tol=0.0, max_iter=300)
    assert stalled.status == "Stalled" and not stalled.success
    assert stalled.iterations <= STALL_WINDOW + 2
    assert stalled.trace == pytest.approx(opt.trace, rel=1e-9)


@pytest.mark.parametrize("name", list(MODELS))
def test_newton_plans_non_diagonal_models_and_ipopt_agrees(name):
    """The default (auto: the condensed form, Newton) solves the non-diagonal models; its trace is
    the NumPy EKF's along its poses; IPOPT on the condensed form (another solver) reaches the same
    optimum."""
    newton = build_setup(problem(8, **MODELS[name]))
    assert resolve_form(newton.model, "auto") == "condensed"
    init = ocp_initial_guess(newton)
    sol = solve_ocp(newton, init)
    assert sol.success and sol.run.solver == "newton", (sol.status, sol.run.hessian)
    sig, _ = propagate(np.array(sol.poses), newton.ocp.noise, newton.ocp.intrinsics,
                       guard=COSINE_GUARD)
    assert sol.trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    assert sol.run.ocp_trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    ipopt = solve_ocp(build_setup(problem(8, solver="ipopt", **MODELS[name])), init)
    assert ipopt.success and ipopt.run.solver == "ipopt"
    assert ipopt.trace_final == pytest.approx(sol.trace_final, rel=1e-6)


def test_second_start_never_ends_above_the_diagonal_models_plan():
    """A 6x6-recursion model also starts Newton from the plan of its diagonal approximation (the
    fast scalar path): the returned plan's trace, by the NumPy EKF, is at most that plan's evaluated
    in the same model. Evaluation configurations 9 and 38 with the correlated depth noise, where
    Newton from the straight line alone ended above the paper plan (docs/general_models.md)."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
    from surestep_ocp.methods.ocp import diagonal_model_setup

    sampler = ConfigurationSampler(load_evaluation(DEFAULT.parent / "evaluations"
                                                   / "evaluation.yaml"))
    for c in (9, 38):
        base = sampler.problem(sampler.sample(0, c))
        corr = build_setup(replace(base, noise=replace(base.noise, V_d0=correlated_depth())))
        approx = diagonal_model_setup(corr)
        assert approx.model.scalar and not corr.model.scalar
        plan = solve_ocp(approx, ocp_initial_guess(approx))
        sol = solve_ocp(corr, ocp_initial_guess(corr))
        assert sol.success and sol.run.second_start is not None
        cam, noise = corr.ocp.intrinsics, corr.ocp.noise
        ref = np.trace(propagate(np.array(plan.poses), noise, cam, guard=COSINE_GUARD)[0][-1])
        own = np.trace(propagate(np.array(sol.poses), noise, cam, guard=COSINE_GUARD)[0][-1])
        assert own <= ref * (1 + 1e-6), c
        assert sol.trace_final == pytest.approx(own, rel=1e-9)


# Newton's secant end-game (`newton._SecantCorrection`): its Woodbury step against a dense solve,
# its positive-definiteness test against eigenvalues, and a 6x6-recursion solve that uses it
# against IPOPT with the exact Hessian.


def banded_spd(n: int, band: int, rng) -> np.ndarray:
    """A random SPD matrix of half-bandwidth band - 1."""
    B = rng.standard_normal((n, n)) * (np.abs(np.subtract.outer(np.arange(n), np.arange(n))) < band)
    # banded lower factor: the same half-bandwidth
    return np.tril(B) @ np.tril(B).T + n * np.eye(n) * 0.1


@pytest.mark.parametrize("seed", range(6))
def test_woodbury_step_equals_a_dense_solve_and_refuses_an_indefinite_correction(seed):
    rng = np.random.default_rng(seed)
    n, band = 40, 6
    H = banded_spd(n, band, rng)
    fixed = np.zeros(n, bool)
    fixed[rng.choice(n, 5, replace=False)] = True
    sec = _SecantCorrection(n)
    # SR1 terms from random secant pairs (y - H s of a "true" Hessian H + N, N indefinite)
    for _ in range(4):
        s = rng.standard_normal(n)
        N = rng.standard_normal((n, 3))
        sec.update(s, (N @ (rng.choice([-1.0, 1.0], 3) * (N.T @ s))) * 0.3)
    assert sec.w.size == 4
    A = sec.U @ np.diag(sec.w) @ sec.U.T
    g = rng.standard_normal(n)
    # the reduced system: free rows and columns of H + A, identity for the held variables (their
    # step is 0)
    M = np.where(np.outer(~fixed, ~fixed), H + A, 0.0) + np.diag(fixed.astype(float))
    rhs = np.where(fixed, 0.0, -g)
    Hred = np.where(np.outer(~fixed, ~fixed), H, 0.0) + np.diag(fixed.astype(float))
    abr = np.zeros((band, n))
    for k in range(band):
        abr[k, : n - k] = np.diag(Hred, -k)
    factor, info = dpbtrf(abr, lower=1)
    assert info == 0
    d = sec.step(factor, fixed, np.linalg.solve(Hred, rhs))
    positive = np.linalg.eigvalsh(M[np.ix_(~fixed, ~fixed)]).min() > 0
    if positive:
        assert d is not None
        np.testing.assert_allclose(d, np.linalg.solve(M, rhs), rtol=1e-9, atol=1e-12)
        assert np.all(d[fixed] == 0)
    else:
        assert d is None
    # a correction that makes H + A indefinite on the free set is refused
    big = _SecantCorrection(n)
    v = np.where(fixed, 0.0, rng.standard_normal(n))
    big.U, big.w = v[:, None], np.array([-10.0 * np.linalg.norm(H, 2) / (v @ v)])
    assert big.step(factor, fixed, np.linalg.solve(Hred, rhs)) is None


def test_sr1_update_meets_the_secant_condition():
    """After an update with step s, (H + A) s equals y: A s = y - H s."""
    rng = np.random.default_rng(3)
    n = 12
    sec = _SecantCorrection(n)
    for _ in range(3):
        s, r = rng.standard_normal(n), rng.standard_normal(n)
        sec.update(s, r)
        np.testing.assert_allclose(sec.U @ (sec.w * (sec.U.T @ s)), r, rtol=1e-10, atol=1e-12)


def test_a_correlated_model_solve_uses_the_end_game_and_matches_ipopt_exact(default_problem):
    """The 6x6 recursion (a correlated depth noise): Newton's plan, with secant steps at its end,
    against IPOPT with the exact Hessian of the unrolled EKF from Newton's plan (a different solver
    and Hessian)."""
    V = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
    V[0, 2] = V[2, 0] = 2e-2
    prob = replace(default_problem, horizon=10, noise=replace(default_problem.noise, V_d0=V))
    setup = build_setup(prob)
    assert not setup.model.scalar
    init = ocp_initial_guess(setup)
    run = newton_solver(setup).run(setup, init, tol=1e-6, max_iter=300)  # the default tol
    assert run.success and run.secant_steps > 0 and run.exact_steps == 0
    exact = replace(prob, solver=replace(prob.solver, name="ipopt", hessian="exact", tol=1e-10))
    ref = solve_ocp(build_setup(exact), init)  # from the same straight line
    assert ref.success, ref.status
    assert abs(run.trace - ref.trace_final) <= 1e-6 * ref.trace_final
    np.testing.assert_allclose(run.q, np.asarray(ref.q), atol=1e-4)
