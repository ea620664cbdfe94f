"""`Planner.replan` checks its inputs as the problem-file reader checks a file (issue 30's
reproducers): each bad input is a SurestepError naming the argument, never a plan, and a rejected
call changes nothing (the next valid call plans exactly as a planner that never saw the bad one).
`ss.solve` names a bad method argument."""

from __future__ import annotations

import numpy as np
import pytest

import surestep_ocp as ss

T = 6


@pytest.fixture(scope="module")
def problem():
    return ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(T)


@pytest.fixture(scope="module")
def state(problem):
    """A planner and a valid tracker estimate for step 1."""
    planner = ss.Planner(problem)
    tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=5)
    mean, cov = tracker.move_to(planner.plan.poses[1])
    return planner, mean, cov


def _shear():
    C = np.eye(4)
    C[0, 1] = 0.3
    return C


def _reflection():
    C = np.eye(4)
    C[2, 2] = -1.0
    return C


BAD = {
    "huge covariance": (lambda m, c: (m, 1e12 * np.eye(6)), {},
                        "covariance entries must be at most"),
    "zero covariance": (lambda m, c: (m, np.zeros((6, 6))), {}, "positive definite"),
    "non-symmetric covariance": (lambda m, c: (m, c + np.triu(np.full((6, 6), 1e-3), 1)), {},
                                 "symmetric"),
    "complex mean": (lambda m, c: (m + 1j, c), {}, "real numbers"),
    "mean at depth 0": (lambda m, c: (np.r_[m[:2], 0.0, m[3:]], c), {}, "below the minimum depth"),
    "NaN mean": (lambda m, c: (np.r_[np.nan, m[1:]], c), {}, "finite"),
    "sheared camera": (lambda m, c: (m, c), {"camera_pose": _shear()}, "rigid transform"),
    "reflection camera": (lambda m, c: (m, c), {"camera_pose": _reflection()}, "rigid transform"),
    "fractional step": (lambda m, c: (m, c), {"step": 1.7}, "whole number"),
    "infinite step": (lambda m, c: (m, c), {"step": float("inf")}, "whole number"),
    "list step": (lambda m, c: (m, c), {"step": [1]}, "whole number"),
    "bool step": (lambda m, c: (m, c), {"step": True}, "whole number"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_a_named_error_and_changes_nothing(problem, state, case):
    planner, mean, cov = state
    make, kwargs, message = BAD[case]
    before = (planner.step, np.array(planner.plan.q), planner._camera[0])
    m, c = make(mean, cov)
    with pytest.raises(ss.SurestepError, match=message):
        planner.replan(m, c, **kwargs)
    assert (planner.step, planner._camera[0]) == (before[0], before[2])
    np.testing.assert_array_equal(np.array(planner.plan.q), before[1])


def test_a_valid_call_after_rejected_ones_plans_as_a_fresh_planner(problem, state):
    """After every rejected call above (a camera among them), the valid re-plan equals a fresh
    planner's."""
    planner, mean, cov = state
    for make, kwargs, _ in BAD.values():
        with pytest.raises(ss.SurestepError):
            planner.replan(*make(mean, cov), **kwargs)
    plan = planner.replan(mean, cov, step=1)
    fresh = ss.Planner(problem).replan(mean, cov, step=1)
    assert plan.success and fresh.success
    np.testing.assert_allclose(np.array(plan.q), np.array(fresh.q), atol=1e-12)


@pytest.mark.parametrize("method", [None, 3, ["ocp"]])
def test_solve_names_a_bad_method_argument(problem, method):
    with pytest.raises(ss.SurestepError, match="method must be a method name"):
        ss.solve(problem, method)
