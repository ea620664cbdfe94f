"""Grasping on evidence in the rollouts (issue 43): the predicted success is what the world then
gives (model mode, a consistent tracker), a rollout grasps only when sure or at the cap, holds
still after it, and dwelling at the goal buys confidence.

The reference is the simulated world itself (the rollouts' true poses, sampled independently of
the tracker's covariance), and a direct recount of the rule from the kept paths.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.evaluation.grasp_rule import GraspRule
from surestep_ocp.evaluation.rollout import rollout
from surestep_ocp.model.grasp import within
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.methods.registry import run_method

REPO = Path(__file__).resolve().parents[1]
N = 400


@pytest.fixture(scope="module")
def plan():
    """The baseline of Type 1 easy (always in view) and its evaluation model."""
    setup = build_setup(load_problem(REPO / "problems" / "type1_easy.yaml"))
    return setup, np.asarray(run_method(setup, "baseline").poses, float)


def test_the_prediction_at_a_clock_grasp_is_the_measured_success(plan):
    setup, poses = plan
    # a 4 mm / 0.1 rad tolerance puts the prediction mid-range, where miscalibration would show
    rule = GraspRule(0.004, 0.1, None, None)
    ro = rollout(setup.eval_model, poses, poses[-1], N, 11, "model", grasp=rule)
    hit = within(ro.pos_err, ro.ori_err, 0.004, 0.1)
    assert np.all(ro.grasp_step == len(poses) - 1) and not ro.capped.any()
    assert 0.2 < ro.predicted.mean() < 0.9
    se = np.sqrt(ro.predicted.mean() * (1 - ro.predicted.mean()) / N)
    assert abs(hit.mean() - ro.predicted.mean()) < 4 * se + 0.02


def test_a_rollout_grasps_only_when_sure_or_at_the_cap_and_then_holds(plan):
    setup, poses = plan
    T = len(poses) - 1
    rule = GraspRule(0.004, 0.1, 0.9, 3 * T)
    ro = rollout(setup.eval_model, poses, poses[-1], N, 12, "model", grasp=rule, keep_paths=True)
    assert np.all(ro.grasp_step >= T) and np.all(ro.grasp_step <= 3 * T)
    sure = ~ro.capped
    assert sure.any() and np.all(ro.predicted[sure] >= 0.9)
    assert np.all(ro.grasp_step[ro.capped] == 3 * T)
    # after its grasp a rollout holds still (the true path ends where the grasp was)
    for i in range(0, N, 37):
        s = ro.grasp_step[i]
        tail = ro.true_path[i, s:]
        np.testing.assert_array_equal(tail, np.broadcast_to(tail[0], tail.shape))
        np.testing.assert_allclose(ro.true_path[i, -1], ro.final_true[i], atol=0)
    # the sure ones are as sure as they said (within sampling error)
    hit = within(ro.pos_err, ro.ori_err, 0.004, 0.1)
    assert hit[sure].mean() > 0.9 - 4 * np.sqrt(0.09 / sure.sum()) - 0.02


def test_dwelling_until_sure_beats_the_clock(plan):
    setup, poses = plan
    T = len(poses) - 1
    clock = rollout(setup.eval_model, poses, poses[-1], N, 13, "model",
                    grasp=GraspRule(0.004, 0.1, None, None))
    sure = rollout(setup.eval_model, poses, poses[-1], N, 13, "model",
                   grasp=GraspRule(0.004, 0.1, 0.95, 4 * T))
    ok = [within(r.pos_err, r.ori_err, 0.004, 0.1).mean() for r in (clock, sure)]
    assert ok[1] > ok[0] + 0.1
    assert np.median(sure.grasp_step) > T  # it waited for it


def test_unknown_tracker_noise_is_refused(plan):
    setup, poses = plan
    with pytest.raises(ValueError, match="tracker_noise"):
        rollout(setup.eval_model, poses, poses[-1], 2, 0, "model", tracker_noise="median")
