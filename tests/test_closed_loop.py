"""The closed loop (`ocp-mpc`, surestep_ocp/evaluation/closed_loop.py) in the rollouts.

- `rollout(policy=...)` against the independent one-rollout NumPy replay (tests/numpy_rollout.py)
  driven by the same closed-loop rule, rollouts ending at different steps included;
- the MPC's rollouts at the robot's pace: a re-plan at every step of every rollout, every executed
  motion within every limit (tests/limit_check.py: finite differences and Pinocchio, not the
  planner's rows), every rollout's last plan at rest at the goal, the rollout holding still after;
- `robot_pace`, the errors for a problem without enforced limits, `surestep evaluate` with ocp-mpc.
"""

import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import numpy_rollout
from limit_check import assert_within_limits, stitched
from surestep_ocp.errors import SurestepError
from surestep_ocp.evaluation.closed_loop import ClosedLoop, robot_pace
from surestep_ocp.evaluation.rollout import Detection, rollout
from surestep_ocp.model.limits import evaluate_curve
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.ocp.straight_line import straight_line
from surestep_ocp.methods.registry import run_method

T = 6


class KinematicSteps:
    """A closed loop in the MPC's form: at step t each rollout runs a fixed plan's step t -> t+1
    from its estimate (the plan's displacement and body-frame rotation); rollout k stops after
    `ends[k]` steps."""

    def __init__(self, plan, ends):
        self.plan, self.ends, self.steps = plan, np.asarray(ends), int(max(ends))

    def target(self, t, mean):
        R0, R1 = Rotation.from_rotvec(self.plan[t, 3:]), Rotation.from_rotvec(self.plan[t + 1, 3:])
        R = Rotation.from_rotvec(mean[3:]) * R0.inv() * R1
        return np.hstack([mean[:3] + self.plan[t + 1, :3] - self.plan[t, :3], R.as_rotvec()])

    def __call__(self, t, mean, cov):
        moving = t < self.ends
        targets = np.array(mean, float)
        targets[moving] = [self.target(t, m) for m in mean[moving]]
        return targets, moving


@pytest.mark.parametrize("mode", ["model", "true"])
def test_policy_rollouts_match_an_independent_numpy_replay(default_setup, mode):
    """Every rollout's true and estimated paths, its detection flags and its final covariance are
    the replay's of the same closed-loop rule from the same normal draws; a rollout past its end
    holds still and observes nothing."""
    model, cam = default_setup.eval_model, default_setup.eval_model.camera
    plan = straight_line(default_setup.x_start, default_setup.x_goal, T)
    plan[:, :3] += np.sin(np.linspace(0, np.pi, T + 1))[:, None] * np.array([0.01, -0.006, 0.004])
    n, det = 12, Detection()
    policy = KinematicSteps(plan, ends=[T - (k % 3) for k in range(n)])
    ro = rollout(model, plan[[0, -1]], plan[-1], n=n, rng=3, mode=mode, keep_paths=True,
                 detection=det, policy=policy)
    rng = np.random.default_rng(3)
    z = [rng.standard_normal((n, 6)) for _ in range(2 * T)]  # per step: w's n x 6, then v's
    for k in range(n):
        end = policy.ends[k]
        z_w = np.array([z[2 * t][k] for t in range(T)])
        z_v = np.array([z[2 * t + 1][k] for t in range(T)])
        rows = numpy_rollout.replay(plan, model.noise, cam, mode, z_w, z_v,
                                    (det.margin, det.min_depth, det.max_depth),
                                    target=policy.target, steps=end)
        for r in rows:
            t = r["t"]
            for path, ref in ((ro.true_path, r["true"]), (ro.estimate_path, r["est"])):
                np.testing.assert_allclose(path[k, t + 1, :3], ref[:3], rtol=0, atol=1e-12)
                angle = (Rotation.from_rotvec(path[k, t + 1, 3:]).inv()
                         * Rotation.from_rotvec(ref[3:])).magnitude()
                assert angle < 1e-10
            assert ro.detected[k, t] == r["seen"]
        # held after its end: the same pose, estimate and covariance, no observation
        np.testing.assert_array_equal(ro.true_path[k, end:], ro.true_path[k, end:end + 1].repeat(
            T + 1 - end, axis=0))
        assert not ro.detected[k, end:].any()
        np.testing.assert_allclose(ro.sigma_final[k], rows[-1]["sigma"], rtol=1e-10, atol=1e-16)
        np.testing.assert_allclose(ro.pos_err[k],
                                   np.linalg.norm(rows[-1]["true"][:3] - plan[-1, :3]),
                                   rtol=1e-12, atol=1e-15)
    assert 0 < ro.detected.sum() < ro.detected.size


def test_robot_pace_doubles_the_steps_keeps_the_camera_moves_times_and_enforces_the_limits():
    problem = load_problem("problems/type4_camera_moves.yaml")
    paced = robot_pace(problem)
    assert paced.horizon == 2 * problem.horizon and paced.limits.enforce
    assert paced.timing.step_s == problem.timing.step_s
    assert [m.step for m in paced.camera.moves] == [2 * m.step for m in problem.camera.moves]
    for a, b in zip(paced.camera.moves, problem.camera.moves):
        np.testing.assert_array_equal(a.ecm_joints, b.ecm_joints)
    changes = build_setup(paced).camera_changes()
    # a move "at step s" happens between waypoints s - 1 and s
    assert [t for t, c in enumerate(changes) if c is not None] == [2 * m.step - 1
                                                                   for m in problem.camera.moves]


@pytest.fixture(scope="module")
def mpc():
    problem = robot_pace(load_problem("problems/type1_medium.yaml")).with_solver(codegen=False)
    setup = build_setup(problem)
    policy = ClosedLoop(setup, keep_pieces=True)
    start, goal = policy.start_and_goal()
    ro = rollout(setup.eval_model, np.vstack([start, goal]), goal, n=3, rng=1, mode="true",
                 keep_paths=True, detection=Detection(), policy=policy)
    return setup, policy, ro


def test_every_rollout_replans_at_every_step(mpc):
    setup, policy, ro = mpc
    summary = policy.summary()
    steps = [p.horizon - 1 for p in policy.planners]  # re-plans at steps 1 .. horizon - 1
    assert summary["failed"] == 0, policy.failures
    assert summary["replans"] == sum(steps)
    assert all(len(pieces) == p.horizon for pieces, p in zip(policy.pieces, policy.planners))
    # most re-plans start while the robot moves (from the executed curve's state)
    moving = [np.abs(v).max() > 1e-3 for pieces in policy.pieces for _, _, (v, _) in pieces[1:]]
    assert np.mean(moving) > 0.5


def test_every_executed_motion_keeps_every_limit_and_ends_at_rest_at_the_goal(mpc):
    setup, policy, ro = mpc
    dt = setup.ocp.timing.step_s
    for pieces, planner in zip(policy.pieces, policy.planners):
        q = stitched(pieces, dt)
        assert_within_limits(planner.setup, q)
        # continuous where one plan hands over to the next (positions, velocities, accelerations)
        for (k, q1, s1), (k2, q2, s2) in zip(pieces, pieces[1:]):
            before = np.hstack(evaluate_curve(q1, dt, np.array([(k2 - k) * dt]), start=s1))
            after = np.hstack(evaluate_curve(q2, dt, np.zeros(1), start=s2))
            np.testing.assert_allclose(after, before, rtol=0, atol=1e-9)
        # the last plan ends at the goal (the camera frame's: each re-plan registers the camera to
        # the rollout's estimate, the goal stays where the camera sees it), at rest
        end = np.asarray(planner.plan.poses[-1])
        np.testing.assert_allclose(end[:3], setup.x_goal[:3], atol=1e-6)
        assert (Rotation.from_rotvec(end[3:]).inv()
                * Rotation.from_rotvec(setup.x_goal[3:])).magnitude() < 1e-5
        v_end = evaluate_curve(np.asarray(planner.plan.q), dt,
                               np.array([planner.plan.horizon * dt]), start=pieces[-1][2])[1]
        assert np.abs(v_end).max() < 1e-9
    assert policy.summary()["violations"] == 0


def test_the_rollouts_run_each_plan_then_hold_still(mpc):
    setup, policy, ro = mpc
    first = np.asarray(policy.first_plan.poses, float)
    # step 0 runs the first plan (no re-plan: the estimate is the start)
    np.testing.assert_allclose(ro.estimate_path[:, 0], np.broadcast_to(first[0], (3, 6)),
                               atol=1e-12)
    for i, planner in enumerate(policy.planners):
        h = planner.horizon
        assert setup.ocp.horizon <= h <= policy.steps
        assert np.all(np.diff(ro.true_path[i, :h + 1], axis=0) != 0)  # moved at every step
        np.testing.assert_array_equal(ro.true_path[i, h:], np.repeat(ro.true_path[i, h:h + 1],
                                                                     policy.steps + 1 - h, axis=0))
        assert not ro.detected[i, h:].any()


def test_after_a_camera_move_the_replan_aims_at_the_goal_as_the_moved_camera_sees_it():
    """Type 4 at the robot's pace: every re-plan ends at the goal (fixed in the world) expressed in
    the camera the rollout's estimate is in, the moved one right after a move."""
    problem = robot_pace(load_problem("problems/type4_camera_moves.yaml")).with_solver(
        codegen=False)
    setup = build_setup(problem)
    policy = ClosedLoop(setup)
    goals = []  # (step, the plan's last pose) of each successful re-plan
    replan = policy._replan

    def spy(i, planner, t, mean, cov, camera):
        planner = replan(i, planner, t, mean, cov, camera)
        if planner.step == t:
            goals.append((t, np.asarray(planner.plan.poses[-1], float)))
        return planner

    policy._replan = spy
    start, goal = policy.start_and_goal()
    rollout(setup.eval_model, np.vstack([start, goal]), goal, n=1, rng=0, mode="model",
            changes=setup.camera_changes(), policy=policy)
    cameras = setup.camera_poses()
    moves = [t for t, c in enumerate(setup.camera_changes()) if c is not None]
    assert {t for t, _ in goals} >= set(moves)  # re-planned right after every move
    for t, end in goals:
        want = setup.seen_from(cameras[min(t + 1, len(cameras) - 1)]).x_goal
        np.testing.assert_allclose(end[:3], want[:3], atol=1e-6, err_msg=f"step {t}")


def test_a_late_replan_keeps_the_previous_plan():
    """With a deadline no re-plan meets (0 s), every rollout runs its first plan to the end: its
    executed motion is that plan's, and every successful re-plan is counted as late."""
    problem = robot_pace(load_problem("problems/type1_medium.yaml")).with_solver(codegen=False)
    setup = build_setup(problem)
    policy = ClosedLoop(setup, keep_pieces=True, deadline_s=0.0)
    start, goal = policy.start_and_goal()
    rollout(setup.eval_model, np.vstack([start, goal]), goal, n=2, rng=0, mode="model",
            policy=policy)
    summary = policy.summary()
    T = setup.ocp.horizon
    assert summary["replans"] == summary["failed"] == 2 * (T - 1)
    # (a re-plan from a stale plan may also fail outright: kept previous all the same)
    assert sum(why.startswith("late") for _, _, why in policy.failures) > T
    assert all(len(pieces) == 1 for pieces in policy.pieces)
    assert [(p.plan is policy.first_plan, p.horizon) for p in policy.planners] == [(True, T)] * 2


def test_a_closed_loop_needs_enforced_limits(tmp_path):
    with pytest.raises(SurestepError, match="limits: {enforce: true}"):
        ClosedLoop(build_setup(load_problem("problems/type1_medium.yaml")))
    paced = build_setup(robot_pace(load_problem("problems/type1_medium.yaml")))
    with pytest.raises(SurestepError, match="observation_noise: mean"):
        run_method(paced, "ocp-mpc-expected")
    res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "evaluate",
                          "problems/evaluations/evaluation.yaml", "--methods", "ocp-mpc",
                          "--configs", "1", "--rollouts", "2", "--output-dir",
                          str(tmp_path / "ev")], capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    assert "ocp-mpc" in res.stderr and "robot_pace.yaml" in res.stderr
    assert "Traceback" not in res.stderr


def test_evaluate_runs_the_closed_loop_beside_the_open_loop(tmp_path, monkeypatch):
    import json

    from surestep_ocp.evaluation.evaluation import run_evaluation
    from surestep_ocp.solvers import nlp_cache

    monkeypatch.setattr(nlp_cache, "compiler_available", lambda: False)  # no C builds in the test
    table = run_evaluation("problems/evaluations/robot_pace.yaml", tmp_path / "ev", configs=1,
                           rollouts=2, methods=("ocp", "ocp-mpc"), modes=("model",),
                           progress=False)
    rec = json.loads((tmp_path / "ev" / "progress.jsonl").read_text().splitlines()[0])
    solve = rec["solves"]["ocp-mpc"]
    assert solve["success"] and solve["evaluated"], solve
    rp = solve["replans"]["model"]
    assert rp["replans"] >= 2 * 39 - rp["failed"] and rp["violations"] == 0
    assert len(rec["pos_errors"]["model"]["ocp-mpc"]) == 2
    assert "| ocp-mpc |" in table
    # the closed loop's re-plans in the table, from the record
    row = next(line for line in table.splitlines() if line.startswith("| ocp-mpc | `model` |"))
    assert row.split(" | ")[2] == str(rp["replans"])
