"""The projected Newton solver (`solver.name: newton`): its gradient against finite differences, its
optima against IPOPT's, its barrier run where the depth bound is violated, and its errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.model.belief import vech
from surestep_ocp.errors import SurestepError
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.solvers.nlp_cache import newton_solver
from surestep_ocp.solvers.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup

DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"


def with_solver(setup, **kw):
    return replace(setup, problem=replace(setup.problem, solver=replace(setup.problem.solver, **kw)))


@pytest.fixture(scope="module")
def short():
    return build_setup(replace(load_problem(DEFAULT), horizon=6))


def test_newton_gradient_matches_finite_differences(short):
    """The assembled joint-space gradient (stage blocks scattered) is the objective's, by central differences."""
    setup = replace(short, problem=replace(short.problem, objective=replace(short.problem.objective, smoothness=0.2)))
    ns = newton_solver(setup)
    q = np.asarray(ocp_initial_guess(setup).q, float)
    rng = np.random.default_rng(1)
    x = (q + 0.02 * rng.normal(size=q.shape)).ravel()
    sigma0 = np.diag(setup.model.channel_variances(np.asarray(setup.problem.noise.Sigma0, float)))
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
    """Same plan as IPOPT (trace to 1e-6), terminal pose exact, start and goal joints kept, bounds met."""
    setup = build_setup(replace(load_problem(DEFAULT), horizon=horizon))
    init = ocp_initial_guess(setup)
    ipopt = solve_ocp(with_solver(setup, name="ipopt"), init)  # another solver (auto would run Newton)
    assert ipopt.extras["solver"] == "ipopt" and "newton" not in ipopt.extras["hessian"]
    newton = solve_ocp(with_solver(setup, name="newton"), init)
    assert newton.success and newton.status == "Solve_Succeeded" and newton.extras["solver"] == "newton"
    assert [a.label for a in newton.attempts] == ["newton"]
    assert newton.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    assert newton.extras["ocp_trace_final"] == pytest.approx(newton.trace_final, rel=1e-9)
    q = np.array(newton.q)
    np.testing.assert_array_equal(q[0], np.asarray(init.q)[0])
    np.testing.assert_array_equal(q[-1], np.asarray(init.q)[-1])
    assert np.all(q >= setup.robot.lower) and np.all(q <= setup.robot.upper)
    assert max(newton.terminal_error) <= 1e-9
    assert min(p[2] for p in newton.poses) >= setup.problem.min_depth


def test_newton_keeps_the_depth_bound_with_its_barrier_run_when_violated():
    """Evaluation configuration 39 at T = 20: Newton's optimum goes below the minimum depth (a bound its box
    form does not have); Newton on IPOPT's barrier problem then solves it from the start, with the bound, and that
    is the plan: IPOPT's own optimum with the monotone barrier (trace to 1e-6), the bound met by Pinocchio's FK."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

    sampler = ConfigurationSampler(load_evaluation(DEFAULT.parent / "evaluations" / "evaluation.yaml"))
    setup = with_solver(build_setup(sampler.problem(sampler.sample(0, 39))), name="newton")
    init = ocp_initial_guess(setup)
    sol = solve_ocp(setup, init)
    attempts = [(a.label, a.status, a.kept) for a in sol.attempts]
    assert attempts == [("newton", "Depth_Bound_Violated", False), ("newton, depth barrier", "Solve_Succeeded", True)]
    assert sol.success and sol.extras["solver"] == "newton"
    ipopt = solve_ocp(with_solver(setup, name="ipopt", options={"mu_strategy": "monotone"}), init)
    assert ipopt.success and ipopt.extras["solver"] == "ipopt"
    assert sol.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    assert min(setup.pose_of(q)[2] for q in np.asarray(sol.q)) >= setup.problem.min_depth
    assert max(sol.terminal_error) <= 1e-9


def test_barrier_depth_derivatives_match_the_fk(short):
    """The barrier's per-node depth, its gradient and Hessian in the node's joints (`newton_depth`) against
    Pinocchio's FK and its central differences."""
    ns = newton_solver(short)
    q = np.asarray(ocp_initial_guess(short).q, float)
    rng = np.random.default_rng(2)
    q = q + 0.02 * rng.normal(size=q.shape)
    camera = short.camera_parameter()
    P = np.zeros(ns.depth.args[1].size)  # camera parameters first (the rest does not enter the depth)
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
    expected = replace(short, problem=replace(short.problem, noise=replace(short.problem.noise,
                                                                           observation_noise="expected")))
    with pytest.raises(SurestepError, match="newton"):
        solve_ocp(with_solver(expected, name="newton"), ocp_initial_guess(expected))


def test_newton_only_where_the_goal_fixes_the_last_joints(short):
    """Seven (redundant) or five moving joints: the terminal pose does not fix q_T, so auto keeps IPOPT and an
    explicit `newton` is an error."""
    from types import SimpleNamespace

    from surestep_ocp.problem.solver_config import resolve
    from surestep_ocp.solvers.ocp import resolved_solver

    assert resolved_solver(short).newton_fits
    spec = short.problem.solver
    assert not resolve(replace(spec, hessian="exact"), short.model, 6).newton_fits
    assert not resolve(replace(spec, hessian="surrogate"), short.model, 6).newton_fits
    for n in (5, 7):
        arm = SimpleNamespace(supporting_joints=lambda n=n: list(range(n)))
        assert not resolved_solver(replace(short, robot=arm)).newton_fits
        with pytest.raises(SurestepError, match="solver.name: newton needs"):
            resolve(replace(spec, name="newton"), short.model, n)


def test_newton_warm_resolve_after_a_camera_move(short):
    """A Newton solution returns its joints as the warm start; after a small camera move the warm Newton solve
    reaches the cold optimum, in fewer iterations."""
    from surestep_ocp.solvers.ocp import solve_ocp_warm

    setup = with_solver(short, name="auto")
    init = ocp_initial_guess(setup)
    first, warm = solve_ocp_warm(setup, init)
    assert first.extras["solver"] == "newton" and not warm.has_duals
    np.testing.assert_array_equal(warm.q, np.array(first.q))
    D = np.eye(4)
    D[:3, 3] = [0.002, -0.001, 0.001]
    moved = setup.seen_from(setup.camera_pose @ D)
    again, _ = solve_ocp_warm(moved, init, warm=warm)
    cold = solve_ocp(moved, ocp_initial_guess(moved))
    assert again.success and again.attempts[0].label == "newton, warm start"
    assert again.extras["init"].startswith("warm start")
    assert again.trace_final == pytest.approx(cold.trace_final, rel=1e-4)
    assert again.iterations < cold.iterations


def test_kept_start_names_the_solvers_that_ran_and_smoothness_counts():
    """With `objective.smoothness: 50` IPOPT's converged plan on the default problem is far below the start in the
    objective it minimises (trace plus smoothness): it is returned, not replaced by the straight line (the old
    check compared that objective with the bare trace). A kept start names the solvers that ran."""
    prob = load_problem(DEFAULT)
    setup = build_setup(replace(prob, objective=replace(prob.objective, smoothness=50.0),
                                solver=replace(prob.solver, name="ipopt")))
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    assert sol.success and sol.status != "Initial_Guess_Kept", sol.extras["hessian"]
    assert sol.objective < sol.extras["initial_objective"]
    assert not sol.extras["worse_than_initial_guess"]


def test_newton_stops_when_it_stalls(short):
    """From its own optimum with tol 0 (unreachable) Newton cannot decrease the objective: it stops as 'Stalled'
    after its window of iterations instead of running to max_iter, and hands over (not a success)."""
    from surestep_ocp.solvers.newton import STALL_WINDOW
    from surestep_ocp.solvers.nlp_cache import newton_solver
    from surestep_ocp.solvers.iterate import InitialGuess

    solver = newton_solver(short)
    opt = solver.run(short, ocp_initial_guess(short), tol=1e-6)
    assert opt.status == "Solve_Succeeded"
    stalled = solver.run(short, InitialGuess(opt.q, "its optimum"), tol=0.0, max_iter=300)
    assert stalled.status == "Stalled" and not stalled.success
    assert stalled.iterations <= STALL_WINDOW + 2
    assert stalled.trace == pytest.approx(opt.trace, rel=1e-9)
