"""The interior-point Newton method within enforced motion limits (`solvers/interior.py`,
`solver.name: interior`) against IPOPT on the same NLP, its plan against the limits by the
independent plan report (finite differences of the waypoints) and by the dense check of the played
curve; a curve that starts in motion continues another."""

from __future__ import annotations

import numpy as np
import pytest

import surestep_ocp as ss
from surestep_ocp.errors import ProblemError
from surestep_ocp.model.limits import evaluate_curve, plan_report, problem_limits
from surestep_ocp.problem.setup import build_setup


@pytest.fixture(scope="module")
def plans():
    """The default problem (40 steps of 50 ms, limits enforced) by the interior-point method and by
    IPOPT."""
    problem = ss.load_problem("problems/needle_regrasp.yaml")
    return (build_setup(problem), ss.solve(problem.with_solver(name="interior"), "ocp"),
            ss.solve(problem.with_solver(name="ipopt"), "ocp"))


def test_interior_point_reaches_ipopts_optimum(plans):
    """Same NLP, same optimum: Tr(Sigma_T) within 1e-6 of IPOPT's (or lower), the same joints to
    1e-3 rad, the goal met, and the interior-point attempt is the one kept (no fallback)."""
    _, sol, ref = plans
    assert sol.success and ref.success
    assert ([a.label for a in sol.attempts] == ["interior point"]
            and sol.attempts[0].solver == "interior")
    assert sol.trace_final <= ref.trace_final * (1 + 1e-6)
    np.testing.assert_allclose(sol.joints, ref.joints, atol=1e-3)
    dist, angle = sol.terminal_error
    assert dist < 1e-9 and angle < 1e-9


def test_interior_point_plan_is_within_every_limit(plans):
    """The waypoints' finite differences (`plan_report`, not the solver's rows) and the played curve
    sampled densely (`enforce`'s check, recorded in the solution) are within every limit."""
    setup, sol, _ = plans
    report = plan_report(setup.robot, sol.joints, setup.problem.timing.step_s,
                         problem_limits(setup), setup.robot.frame)
    assert report["ok"], report.get("violations")
    assert sol.extras["motion_limits"]["ok"] and sol.extras["motion_limits"]["enforced"]


def test_interior_needs_enforced_limits():
    """`solver.name: interior` on a problem without enforced limits is a problem error naming the
    key."""
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml")
    with pytest.raises(ProblemError, match="solver.name: interior needs limits.enforce"):
        problem.with_solver(name="interior")


def test_a_curve_started_in_motion_continues_the_executed_one():
    """A re-plan at knot k from the executed curve's state (position, velocity, acceleration there)
    continues it twice continuously: the stitched curve's values at the switch equal the old
    curve's, and just before and just after it the two curves' accelerations differ by no more than
    their jerk allows (no jump)."""
    rng = np.random.default_rng(0)
    q, dt, k = np.cumsum(rng.normal(size=(12, 3)) * 0.05, axis=0), 0.05, 4
    p, v, a = evaluate_curve(q, dt, np.array([k * dt]))
    # another plan from waypoint k on
    new = q[k:] + np.linspace(0, 1, len(q) - k)[:, None] ** 3 * 0.02
    new[0] = q[k]
    p2, v2, a2 = evaluate_curve(new, dt, np.array([0.0]), start=(v[0], a[0]))
    np.testing.assert_allclose(np.hstack([p2, v2, a2]), np.hstack([p, v, a]), atol=1e-9)
    h = 1e-7
    left = evaluate_curve(q, dt, np.array([k * dt - h]))
    right = evaluate_curve(new, dt, np.array([h]), start=(v[0], a[0]))
    # [rad/s^3] far above either curve's jerk here (|q| steps of 0.05 rad in 0.05 s)
    jerk_bound = 1e4
    for order in range(3):
        assert np.abs(right[order] - left[order]).max() <= 2 * h * jerk_bound * (1 + dt) ** 3
