"""A 20 Hz re-planning loop within the motion limits (`Planner` with `solver.name: interior`): the
executed motion, stitched from the pieces of every plan that was current, keeps every limit and ends
at rest at the goal.

The check is independent of the planner's rows: the stitched joint curve is sampled every
millisecond, its velocities and accelerations taken by finite differences, the tool's speeds from
Pinocchio's kinematics of the samples, and compared with the limit values of the problem.
"""

import dataclasses

import numpy as np
import numpy_ekf as ref
import pytest
from scipy.spatial.transform import Rotation

import surestep_ocp as ss
from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.model.limits import evaluate_curve, problem_limits
from surestep_ocp.evaluation.tracker_loop import tracker_loop
from surestep_ocp.model.limits.curve import TOOL_MARGIN
from surestep_ocp.problem.setup import build_setup

from limit_check import H, assert_within_limits, stitched as _stitched


@pytest.fixture(scope="module")
def episode():
    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior",
                                                                          codegen=False)
    # the loop `surestep replan` runs (evaluation/tracker_loop.py); the checks below are this file's
    episode = tracker_loop(build_setup(problem), seed=0)
    return episode["planner"], episode["pieces"], episode["plans"]


def test_every_replan_succeeds_from_the_moving_robot(episode):
    planner, pieces, plans = episode
    assert all(p.success for p in plans), [(p.replan.step, p.status) for p in plans
                                           if not p.success]
    assert all(p.replan.kept_previous is False for p in plans)
    moving = [p for p in plans if np.abs(p.run.start_state.velocity).max() > 1e-3]
    assert len(moving) > len(plans) // 2  # most re-plans start while the robot moves, not from rest


@pytest.mark.parametrize("k", [0, 20, -1])
def test_replan_covariances_are_the_numpy_ekf(episode, k):
    """A re-plan's covariances (the planner evaluates its plan with a compiled EKF over its
    horizon) are a plain NumPy EKF's along its poses, from the tracker's covariance it was given
    (as its solution records it)."""
    _, _, plans = episode
    plan = plans[k]
    problem = ss.load_problem("problems/needle_regrasp.yaml")
    given = np.asarray(plan.noise["Sigma0"], float)
    sigma0 = given * np.eye(6) if given.ndim == 0 else given
    noise = dataclasses.replace(problem.noise, Sigma0=sigma0)
    sig, _ = ref.propagate(np.asarray(plan.poses), noise, problem.camera.intrinsics,
                           ref.ALL_COMPONENTS, guard=COSINE_GUARD)
    assert len(sig) == plan.horizon + 1
    assert ref.rel_err(plan.covariances, sig) < 1e-9


def test_executed_motion_keeps_every_limit(episode):
    planner, pieces, _ = episode
    setup = planner.setup
    dt, lim = setup.ocp.timing.step_s, problem_limits(setup)
    peak = assert_within_limits(setup, _stitched(pieces, dt))
    # the rows keep the tool's speeds within (1 - TOOL_MARGIN) at their points; between them the
    # curve may rise a little, never past the limit itself (asserted above)
    assert peak > 0.5 * (1 - TOOL_MARGIN) * lim.tool_speed  # the check sees a real motion


def test_executed_motion_is_continuous_and_ends_at_rest_at_the_goal(episode):
    planner, pieces, plans = episode
    dt = planner.setup.ocp.timing.step_s
    q = _stitched(pieces, dt)
    # where one plan hands over to the next
    for (k, q1, s1), (k2, q2, s2) in zip(pieces, pieces[1:]):
        t = np.array([(k2 - k) * dt])
        before = np.hstack(evaluate_curve(q1, dt, t, start=s1))
        after = np.hstack(evaluate_curve(q2, dt, np.zeros(1), start=s2))
        np.testing.assert_allclose(after, before, rtol=0, atol=1e-9, err_msg=f"switch at step {k2}")
    last = plans[-1]
    np.testing.assert_allclose(q[-1], np.array(last.q)[-1], atol=1e-12)
    lim = problem_limits(planner.setup)
    # at rest: no speed left at the end
    assert np.all(np.abs(q[-1] - q[-2]) / H <= lim.acceleration * H)
    # camera frame: each re-plan registers the camera to the tracker, the goal stays
    goal = planner.setup.x_goal
    end = np.array(last.poses[-1])
    np.testing.assert_allclose(end[:3], goal[:3], atol=1e-6)
    R = Rotation.from_rotvec(end[3:]).inv() * Rotation.from_rotvec(goal[3:])
    assert R.magnitude() < 1e-5
    # the end moves later only when a correction needs it
    assert planner.horizon >= planner.setup.ocp.horizon


def test_cli_replan_runs_the_tracker_loop_within_the_limits(tmp_path):
    """`surestep replan` on the default problem (a fixed camera): a re-plan per frame of a simulated
    tracker, each within the limits; loop.md and loop.json say how each went."""
    import json
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "replan",
                          "problems/needle_regrasp.yaml",
                          "--no-codegen", "--output-dir", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=600, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    record = json.loads((tmp_path / "out" / "loop.json").read_text())
    assert record["summary"]["replans"] == len(record["replans"]) >= 39
    assert record["summary"]["failed"] == sum(r["kept_previous"] == "yes"
                                              for r in record["replans"])
    assert "re-plans" in (tmp_path / "out" / "loop.md").read_text()


def test_a_correction_that_does_not_fit_is_bounded_work_and_keeps_the_previous_plan(monkeypatch):
    """A 2.3 cm correction six steps before the end: the re-plan's attempts (reserve, then later
    goals) share one iteration budget (without it they take 77 iterations here), and when none
    fits the previous plan stays current."""
    from surestep_ocp.methods import planner as planner_module

    budget = 12
    monkeypatch.setattr(planner_module, "REPLAN_BUDGET", budget)
    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior")
    planner = ss.Planner(problem, prebuild=False)
    plan, k = planner.plan, planner.horizon - 6
    mean = np.array(plan.poses[k], float)
    mean[:3] += 0.02 * np.array([1.0, -0.7, 0.4])
    sol = planner.replan(mean, 1e-6 * np.eye(6), step=k)
    attempts = sol.replan.attempts
    assert len(attempts) > 1  # the first did not fit
    assert sum(a.iterations for a in attempts) <= budget + planner_module.REPLAN_ITERATIONS
    if not sol.success:
        assert planner.plan is plan and planner.step == 0
        assert sol.replan.kept_previous


def test_an_estimate_that_puts_the_goal_out_of_reach_registers_the_nearest_within_reach():
    """The tracker's mean 5 cm nearer the camera at the first frame, 1 mm sure: the camera
    registered to it puts the goal beyond the arm's reach (checked apart: IK with 50 random
    restarts ends over a millimetre from it) and every estimate that reaches it is one the belief
    rules out (methods/registration.py: beyond the 99 % gate), so the re-plan registers the nearest
    of them, says so, and ends within the joint limits; the next frame's consistent estimate
    registers as it is."""
    from dataclasses import replace

    from surestep_ocp.model.lie import pose_to_matrix

    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior")
    planner = ss.Planner(problem, prebuild=False)
    first = np.array(planner.plan.q, float)
    mean = np.array(planner.plan.poses[1], float)
    mean[2] -= 0.05
    # the registration the tracker's mean asks for, and its goal: out of reach
    setup = planner.setup
    q1 = planner.executed_state(1)[0]
    world_tool = setup.camera_pose @ pose_to_matrix(setup.pose_of(q1))
    registered = replace(setup, camera_pose=world_tool @ np.linalg.inv(pose_to_matrix(mean)))
    _, res_m, _ = registered.joints_for(setup.x_goal, setup.q_goal, raise_on_fail=False,
                                        restarts=50)
    assert res_m > 1e-3

    sol = planner.replan(mean, 1e-6 * np.eye(6), step=1)
    assert sol.success and not sol.replan.registration_held and not sol.replan.kept_previous
    assert sol.replan.registration_constrained > 16.8
    assert sol.extras["goal_ik_residual"]["m"] > 1e-3
    q_goal, robot = np.array(sol.q)[-1], planner.setup.robot
    assert np.all(q_goal >= robot.lower) and np.all(q_goal <= robot.upper)
    assert not np.allclose(q_goal, first[-1], atol=1e-6)
    assert planner.plan is sol

    again = planner.replan(np.array(sol.poses[1], float), 1e-4 * np.eye(6), step=2)
    assert again.success and again.replan.registration_held is False
    assert again.replan.registration_constrained is None
    assert "goal_ik_residual" not in again.extras


def test_restart_plans_a_new_motion_from_rest_to_a_new_goal():
    """After re-plans in motion, `restart` (a fault cleared, or a new goal) plans from rest at the
    joints given: the plan starts there at rest, ends at the new goal pose (Pinocchio's kinematics
    of its last joints), keeps every limit (the divided-difference check), and re-plans go on from
    it; bad joints or an unreachable goal are one error each, the Planner unchanged."""
    import pinocchio as pin

    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior")
    planner = ss.Planner(problem, prebuild=False)
    for k in (1, 2):
        assert planner.replan(np.array(planner.plan.poses[1], float), 1e-6 * np.eye(6),
                              step=k).success
    setup = planner.setup
    rest = np.array(planner.plan.q[10], float)
    goal = setup.pose_of(np.array(planner.plan.q[-12], float))
    current = planner.plan
    for bad, why in (((rest + 10.0), "outside their bounds"), (rest[:3], "finite numbers")):
        with pytest.raises(ss.SurestepError, match=why):
            planner.restart(bad)
    far = goal.copy()
    far[:3] += [0.0, 0.0, 1.0]
    with pytest.raises(ss.SurestepError, match="not reachable"):
        planner.restart(rest, goal=far)
    assert planner.plan is current

    plan = planner.restart(rest, goal=goal)
    assert plan.success and planner.plan is plan and planner.step == 0
    q = np.array(plan.q, float)
    np.testing.assert_allclose(q[0], rest, atol=1e-12)
    # the new goal, by Pinocchio's forward kinematics in the camera frame
    model = pin.buildModelFromUrdf(str(problem.robot.urdf))
    data = model.createData()
    pin.framesForwardKinematics(model, data, q[-1])
    tool = (np.linalg.inv(setup.camera_pose) @ problem.robot.base_pose
            @ data.oMf[model.getFrameId("tool")].homogeneous)
    np.testing.assert_allclose(tool[:3, 3], goal[:3], atol=1e-6)
    assert_within_limits(setup, _stitched([(0, q, None)], setup.ocp.timing.step_s))
    nxt = planner.replan(np.array(plan.poses[1], float), 1e-6 * np.eye(6), step=1)
    assert nxt.success and np.abs(np.array(nxt.q)[-1] - q[-1]).max() < 1e-6
