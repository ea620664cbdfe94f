"""The re-planning handle: a warm re-plan equals an independent cold solve of the same state
(through the public API: a problem changed by with_* and read again, solved from the straight line),
its covariances are a plain NumPy EKF's, and the shrinking horizon builds nothing once the solvers
exist. Not timed."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy_ekf as ref
import pytest

import surestep_ocp as ss
from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.ocp.iterate import InitialGuess
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.setup import build_setup

T = 8


@pytest.fixture(scope="module")
def problem():
    return ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(T)


@pytest.fixture(scope="module")
def loop(problem):
    """A planner and two re-plans from a simulated tracker (a fixed camera, then a moved one)."""
    planner = ss.Planner(problem)
    builds = dict(planner.builds)
    tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=3)
    mean1, cov1 = tracker.move_to(planner.plan.poses[1])
    plan1 = planner.replan(mean1, cov1)
    mean2, cov2 = tracker.move_to(planner.plan.poses[1])
    moved = planner.setup.camera_pose.copy()
    # the endoscope moves 3.7 mm; the tracker reports in its frame
    moved[:3, 3] += [0.003, -0.002, 0.001]
    mean2 = mean2 + [0.001, 0.0, -0.001, 0.0, 0.0, 0.0]
    plan2 = planner.replan(mean2, cov2, camera_pose=moved)
    return planner, builds, [(plan1, mean1, cov1, None), (plan2, mean2, cov2, moved)]


def _cold_problem(problem, planner, mean, cov, camera, steps):
    """The same state given to a problem read again: start pose, Sigma_0, horizon and camera."""
    p = problem.with_start(pose=mean).with_noise(Sigma0=cov).with_horizon(steps)
    if camera is not None:  # the goal stays in the world: its pose in the moved camera's frame
        p = p.with_camera_pose(camera).with_goal(pose=planner.setup.seen_from(camera).x_goal)
    return p


@pytest.mark.parametrize("k", [0, 1])
def test_replan_equals_a_cold_solve(problem, loop, k):
    """IPOPT started cold from the plan the re-plan was warm-started from (the previous plan's rest)
    ends at the same point; and the re-plan is never worse than the cold solve from the straight
    line (a non-convex problem:
    that one may stop at another local optimum, as it does here: 1.8 times the trace)."""
    planner, _, plans = loop
    plan, mean, cov, camera = plans[k]
    assert plan.success and plan.replan.solver == "newton"
    assert plan.horizon == T - 1 - k
    np.testing.assert_allclose(plan.poses[0], mean, atol=1e-9)  # starts at the tracker's mean
    cold = _cold_problem(problem, planner, mean, cov, camera, T - 1 - k)
    setup = build_setup(cold.with_solver(name="ipopt"))
    guess = np.array(plan.run.warm_start_q)
    guess[0] = setup.q_start
    ipopt = solve_ocp(setup, InitialGuess(guess, "the re-plan's warm start"))
    assert ipopt.success and ipopt.run.solver == "ipopt"
    np.testing.assert_allclose(plan.positions, ipopt.positions, atol=1e-7)
    np.testing.assert_allclose(plan.orientations, ipopt.orientations, atol=1e-6)
    assert plan.objective == pytest.approx(ipopt.objective, rel=1e-7)
    assert plan.trace_final == pytest.approx(ipopt.trace_final, rel=1e-7)
    straight = ss.solve(cold, "ocp")
    assert straight.success and plan.objective <= straight.objective * (1 + 1e-9)


@pytest.mark.parametrize("k", [0, 1])
def test_replan_covariances_are_the_numpy_ekf(problem, loop, k):
    plan, _, cov, _ = loop[2][k]
    noise = dataclasses.replace(problem.noise, Sigma0=cov)
    sig, _ = ref.propagate(np.asarray(plan.poses), noise, problem.camera.intrinsics,
                           ref.ALL_COMPONENTS, guard=COSINE_GUARD)
    assert ref.rel_err(plan.covariances, sig) < 1e-9
    np.testing.assert_allclose(plan.covariances[0], cov, rtol=1e-12)


def test_shrinking_horizon_builds_nothing_new(loop):
    """One solver per horizon left, made before the first plan (the first compiled then, the others
    compiled in the background); a re-plan makes none, and what its horizon's solver cost at first
    use (waiting for its compile, loading it) is its build time, kept out of its own time."""
    planner, builds, plans = loop
    assert sorted(builds) == list(range(1, T + 1))
    assert sorted(planner.builds) == sorted(builds)
    for p, *_ in plans:
        n = p.horizon
        assert p.replan.build_time_s == pytest.approx(planner.builds[n] - builds[n],
                                                                   abs=1e-9)
        assert p.replan.build_time_s >= 0


def test_replan_rejects_bad_input(loop):
    planner = loop[0]
    with pytest.raises(ss.SurestepError, match="covariance must be positive definite"):
        planner.replan(planner.plan.poses[1], -np.eye(6))
    with pytest.raises(ss.SurestepError, match=r"mean must be 6 finite numbers.*got shape \(5,\)"):
        planner.replan([0.0] * 5, np.eye(6))
    # a non-finite value is said as such (not as a shape)
    nan_mean = np.array(planner.plan.poses[1], float)
    nan_mean[0] = np.nan
    with pytest.raises(ss.SurestepError, match=r"6 finite numbers.*got \[nan"):
        planner.replan(nan_mean, np.eye(6))
    with pytest.raises(ss.SurestepError, match="finite 6x6 matrix, got non-finite entries"):
        planner.replan(planner.plan.poses[1], np.full((6, 6), np.inf))
    with pytest.raises(ss.SurestepError, match="finite 4x4 matrix, got non-finite entries"):
        planner.replan(planner.plan.poses[1], np.eye(6) * 1e-4, camera_pose=np.full((4, 4), np.nan))
    with pytest.raises(ss.SurestepError, match="step 99"):
        planner.replan(planner.plan.poses[1], np.eye(6) * 1e-4, step=99)
