"""A 20 Hz re-planning loop within the motion limits (`Planner` with `solver.name: interior`): the
executed motion, stitched from the pieces of every plan that was current, keeps every limit and ends
at rest at the goal.

The check is independent of the planner's rows: the stitched joint curve is sampled every
millisecond, its velocities and accelerations taken by finite differences, the tool's speeds from
Pinocchio's kinematics of the samples, and compared with the limit values of the problem.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import surestep_ocp as ss
from surestep_ocp.model.limits import evaluate_curve, problem_limits
from surestep_ocp.model.limits.curve import TOOL_MARGIN

H = 1e-3  # [s] sampling of the executed curve


@pytest.fixture(scope="module")
def episode():
    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior",
                                                                          codegen=False)
    planner = ss.Planner(problem)
    tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=0)
    # (start step, joints, start state) of each plan
    pieces = [(0, np.array(planner.plan.q, float), None)]
    plans, k = [], 0
    while k + 1 < planner.horizon:
        k += 1
        mean, cov = tracker.move_to(planner.plan.poses[k - planner.step])
        plan = planner.replan(mean, cov, step=k)
        plans.append(plan)
        if plan.success:
            st = plan.extras["start_state"]
            pieces.append((k, np.array(plan.q, float),
                           (np.array(st["velocity"]), np.array(st["acceleration"]))))
    return planner, pieces, plans


def _stitched(pieces, dt):
    """Joint samples every H seconds of the executed motion: each plan from its start until the next
    one's."""
    out = []
    for i, (k, q, start) in enumerate(pieces):
        end = pieces[i + 1][0] if i + 1 < len(pieces) else k + len(q) - 1
        t = np.arange(round((end - k) * dt / H) + (i + 1 == len(pieces))) * H
        out.append(evaluate_curve(q, dt, t, start=start)[0])
    return np.vstack(out)


def test_every_replan_succeeds_from_the_moving_robot(episode):
    planner, pieces, plans = episode
    assert all(p.success for p in plans), [(p.extras["replan"]["step"], p.status) for p in plans
                                           if not p.success]
    assert all(p.extras["replan"]["kept_previous"] is False for p in plans)
    moving = [p for p in plans if np.abs(p.extras["start_state"]["velocity"]).max() > 1e-3]
    assert len(moving) > len(plans) // 2  # most re-plans start while the robot moves, not from rest


def test_executed_motion_keeps_every_limit(episode):
    planner, pieces, _ = episode
    setup = planner.setup
    dt, lim = setup.ocp.timing.step_s, problem_limits(setup)
    q = _stitched(pieces, dt)
    robot = setup.robot
    assert np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9)
    v = np.diff(q, axis=0) / H
    a = np.diff(q, n=2, axis=0) / H**2
    mov = robot.supporting_joints()
    # finite differences of a curve whose jerk is bounded: within 1 % of the limits plus the
    # differencing error
    assert np.all(np.abs(v[:, mov]) <= lim.velocity[mov] * 1.001 + 1e-6)
    assert np.all(np.abs(a[:, mov]) <= lim.acceleration[mov] * 1.01 + 1e-3)
    poses = np.array([robot.frame_pose(qi) for qi in q[::5]])  # every 5 ms
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / (5 * H)
    assert speed.max() <= lim.tool_speed * 1.001
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    angle = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)) / (5 * H)
    assert angle.max() <= lim.tool_rotation * 1.001
    # the rows keep the tool's speeds within (1 - TOOL_MARGIN) at their points; between them the
    # curve may rise a little, never past the limit itself (asserted above)
    assert speed.max() > 0.5 * (1 - TOOL_MARGIN) * lim.tool_speed  # the check sees a real motion


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
