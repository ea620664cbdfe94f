"""The Python API: problems changed with errors that name the key, solve by method name, arrays with
units."""

from __future__ import annotations

import numpy as np
import pytest

import surestep_ocp as ss

GOAL = [0.045, 0.005, 0.115, 0.60, 0.10, 1.40]


@pytest.fixture(scope="module")
def problem():
    return ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(6)


@pytest.mark.parametrize(("change", "key"), [
    (lambda p: p.with_goal(pose=[0.04, 0.0, "x", 0.0, 0.0, 1.0]), "goal.pose.position[2]"),
    (lambda p: p.with_goal(pose=GOAL[:5]), "goal.pose"),
    (lambda p: p.with_start(joints=[0.1] * 3), "start.joints"),
    (lambda p: p.with_noise(Sigma0=-1.0), "noise.Sigma0"),
    (lambda p: p.with_noise(V_dd=1.0), "noise.V_dd"),
    (lambda p: p.with_camera_pose(np.eye(3)), "camera.pose.matrix"),
    (lambda p: p.with_horizon(0), "horizon"),
    (lambda p: p.with_solver(name="fast"), "solver.name"),
])
def test_bad_changes_name_the_key(problem, change, key):
    with pytest.raises(ss.ProblemError) as info:
        ss.solve(change(problem), "baseline")
    assert f": {key}:" in str(info.value)


def test_unreachable_goal_names_the_key(problem):
    with pytest.raises(ss.ProblemError, match=r"goal\.pose: .*not reachable"):
        ss.solve(problem.with_goal(pose=[0.045, 0.005, 0.6, 0.6, 0.1, 1.4]), "ocp")


def test_solve_and_read_the_arrays(problem):
    sol = ss.solve(problem.with_goal(pose=np.array(GOAL)).with_noise(Sigma0=2e-2), "ocp")
    assert sol.success and sol.horizon == 6
    assert sol.joints.shape == (7, len(sol.joint_names)) and sol.covariances.shape == (7, 6, 6)
    np.testing.assert_allclose(sol.positions[-1], GOAL[:3], atol=1e-9)
    np.testing.assert_allclose(sol.covariances[0], 2e-2 * np.eye(6))
    np.testing.assert_allclose(sol.pose_matrices[:, :3, 3], sol.positions)
    np.testing.assert_allclose(sol.times, np.arange(7) * problem.timing.step_s)
    assert sol.trace_final == pytest.approx(np.trace(sol.covariances[-1]))


def test_a_problem_built_in_python_equals_the_file(problem):
    tree = dict(problem.source, horizon=6)
    built = ss.problem_from_dict(tree)
    a, b = ss.solve(built, "baseline"), ss.solve(problem, "baseline")
    np.testing.assert_allclose(a.poses, b.poses)
    with pytest.raises(ss.ProblemError, match=r"^<python>: horizon:"):
        ss.problem_from_dict(dict(tree, horizon="many"))
