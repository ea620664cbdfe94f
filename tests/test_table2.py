"""Type 4's per-rollout re-planning (surestep_ocp.evaluation.table2.RolloutReplanner) against
`surestep replan`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.evaluation.rollout import Detection, rollout
from surestep_ocp.evaluation.table2 import RolloutReplanner
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.methods.camera_move_replan import _belief_after_move, replan_after_camera_moves

TYPE4 = Path(__file__).resolve().parents[1] / "problems" / "type4_camera_moves.yaml"


@pytest.fixture(scope="module")
def type4():
    return build_setup(load_problem(TYPE4))


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (Rotation.from_rotvec(a[..., 3:].reshape(-1, 3)).inv()
            * Rotation.from_rotvec(b[..., 3:].reshape(-1, 3))
            ).magnitude()


def test_a_rollout_with_the_ml_belief_replans_as_surestep_replan(type4, tmp_path):
    """Fed the maximum-likelihood belief at every move (replan's own `_belief_after_move` along its
    executed joints), a rollout's re-plans give `surestep replan`'s executed trajectory (its frames:
    `Setup.pose_of` and `in_step_frames`); a second rollout with another belief re-plans on its own
    copy and leaves the first as is."""
    setup = type4
    executed = replan_after_camera_moves(setup, tmp_path)["executed"]
    expect = np.asarray(executed.poses, float)  # in each step's camera frame (Solution.poses)
    hook = RolloutReplanner(setup)
    waypoints = np.stack([hook.initial_poses()] * 2)
    q_exec = np.array(hook.planner.plan.q, float)
    moves = [t for t, c in enumerate(setup.camera_changes()) if c is not None]
    for t in moves:
        mean, cov = _belief_after_move(setup, q_exec, t + 1)
        other = mean + np.array([0.003, -0.002, 0.001, 0.0, 0.0, 0.0])
        waypoints = hook(t, np.stack([mean, other]), np.stack([cov, 2 * cov]), waypoints)
        q_exec[t:] = hook.planners[0].plan.q
    assert hook.failures == [] and len(hook.times) == 2 * len(moves)
    np.testing.assert_allclose(waypoints[0, :, :3], expect[:, :3], atol=1e-9)
    assert _angles(waypoints[0], expect).max() < 1e-8
    assert np.abs(waypoints[1, :, :3] - expect[:, :3]).max() > 1e-4  # its own plans
    # copies, shared solvers
    assert hook.planners[0].plan is not hook.planners[1].plan and hook.planner.step == 0
    # the same goal
    np.testing.assert_allclose(waypoints[:, -1, :3], np.stack([expect[-1, :3]] * 2), atol=1e-9)


def test_per_rollout_replanning_in_a_rollout(type4):
    """In `rollout`, every rollout re-plans at each of the 4 moves from its own belief: their plans
    differ, and the rollouts end near the goal."""
    setup = type4
    hook = RolloutReplanner(setup)
    poses = hook.initial_poses()
    ro = rollout(setup.eval_model, poses, poses[-1], 4, np.random.default_rng(0), "model",
                 keep_paths=True, detection=Detection(), changes=setup.camera_changes(),
                 replan=hook)
    assert len(hook.times) == 16 and hook.failures == []
    # each from its rollout's last move (step 15)
    final_plans = np.array([p.plan.poses for p in hook.planners])
    assert np.abs(final_plans[0] - final_plans[1]).max() > 1e-5  # each rollout's own belief
    assert ro.pos_err.max() < 0.1


def test_table2_rolls_out_each_plan_in_its_steps_camera_frames(type4):
    """The waypoints `plans` hands to the rollouts are the plan's joints seen from each step's
    camera (`Setup.seen_from(C_t).pose_of`), and the last one is the goal seen from the last camera:
    what the Table II of the previous release got wrong on Types 3 and 4 (the step frames
    re-expressed a second time)."""
    from surestep_ocp.evaluation.table2 import plans
    from surestep_ocp.methods.registry import run_method

    setup = type4
    C = setup.camera_poses()
    poses, ok = plans(setup, ("baseline",))["baseline"]
    q = np.asarray(run_method(setup, "baseline").q, float)
    seen = np.array([setup.seen_from(C[t]).pose_of(q[t]) for t in range(len(q))])
    np.testing.assert_allclose(poses[:, :3], seen[:, :3], atol=1e-12)
    assert _angles(poses, seen).max() < 1e-9
    np.testing.assert_allclose(poses[-1, :3], setup.seen_from(C[-1]).x_goal[:3], atol=1e-9)
    # the old reading differs
    assert np.abs(setup.in_step_frames(poses)[-1, :3] - poses[-1, :3]).max() > 1e-3
