"""The paper's gradient-descent variant (surestep_ocp.gradient) on a short horizon of the default problem."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.baseline import solve_baseline, straight_line
from surestep_ocp.gradient import build_loss, solve_gradient
from surestep_ocp.problem import load_problem
from surestep_ocp.setup import build_setup

PROBLEM = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp.yaml"
HORIZON = 8


@pytest.fixture(scope="module")
def setup():
    return build_setup(dataclasses.replace(load_problem(PROBLEM), horizon=HORIZON))


@pytest.fixture(scope="module")
def baseline(setup):
    return solve_baseline(setup)


@pytest.fixture(scope="module")
def with_pose(setup):
    return solve_gradient(setup)


@pytest.fixture(scope="module")
def without_pose(setup):
    return solve_gradient(setup, pose_loss=False)


def test_lowers_trace_below_baseline(baseline, with_pose, without_pose):
    """The variant exists to shrink the final covariance: both losses must beat the straight line."""
    for sol in (with_pose, without_pose):
        assert sol.success, sol.status
        assert sol.status == f"completed {sol.iterations} iterations"
        assert sol.iterations == sol.extras["iterations_requested"] == 50
        assert sol.trace_final < 0.95 * baseline.trace_final
        assert not sol.extras["barely_moved"]
        assert sol.extras["loss_end"]["loss"] < sol.extras["loss_start"]["loss"]


def test_pose_loss_shrinks_final_step(with_pose, without_pose):
    """The pose loss is the paper's remedy for the large last step the clipping action leaves."""
    assert with_pose.extras["final_step_m"] < without_pose.extras["final_step_m"]
    assert with_pose.extras["final_step_rad"] < without_pose.extras["final_step_rad"]
    assert with_pose.method == "gradient" and without_pose.method == "gradient-no-pose-loss"


@pytest.mark.parametrize("pose_loss", [True, False])
def test_gradient_matches_finite_differences(setup, pose_loss):
    """A wrong CasADi gradient would make L-BFGS wander silently; check it against central differences."""
    _, loss_grad = build_loss(setup, setup.model, pose_loss, setup.problem.gradient.pose_loss_weight)
    rng = np.random.default_rng(0)
    d = np.diff(straight_line(setup.x_start, setup.x_goal, HORIZON), axis=0)
    d += rng.normal(scale=[5e-3] * 3 + [5e-2] * 3, size=d.shape)
    d = d.ravel()
    g = np.asarray(loss_grad(d)[1]).ravel()
    h = 1e-6
    fd = np.empty_like(d)
    for i in range(len(d)):
        e = np.zeros_like(d)
        e[i] = h
        fd[i] = (float(loss_grad(d + e)[0]) - float(loss_grad(d - e)[0])) / (2 * h)
    assert np.linalg.norm(g - fd) <= 1e-5 * np.linalg.norm(g)
    assert np.all(g[-6:] == 0)  # d_{T-1} is overwritten by the clipping action


def test_clipping_and_evaluation(setup, with_pose, without_pose):
    """E[x_T] = x^G must hold exactly, and the reported trace must be the common evaluation's."""
    for sol in (with_pose, without_pose):
        poses = np.asarray(sol.poses)
        assert poses.shape == (HORIZON + 1, 6)
        assert np.array_equal(poses[-1], setup.x_goal)
        assert np.array_equal(poses[0], setup.x_start)
        sig, _ = setup.eval_model.propagate(poses)
        assert np.allclose(sol.trace, [np.trace(s) for s in sig], rtol=1e-12, atol=0)
        assert sol.terminal_error == (0.0, 0.0)
        assert np.isclose(sol.objective, sol.extras["loss_end"]["loss"])
        info = sol.extras["reachability"]
        assert info["reachable"] + info["unreachable"] == HORIZON + 1
        assert len(sol.q) == HORIZON + 1


def test_ablation_without_orientation(setup):
    """Ablations switch components off in optimisation only; the reduced model must build and run."""
    comps = ("depth", "fov")
    sol = solve_gradient(setup, components=comps)
    assert sol.success, sol.status
    assert sol.extras["components"] == list(comps)
    assert sol.noise["components"] == list(comps)
    assert np.isfinite(sol.trace_final)
    # the evaluation still uses all components
    sig, _ = setup.eval_model.propagate(np.asarray(sol.poses))
    assert np.isclose(sol.trace_final, np.trace(sig[-1]), rtol=1e-12)
