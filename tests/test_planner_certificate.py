"""The Planner acts on each re-plan's certificate (methods/planner.py `_certified`,
docs/certificate.md "Re-plans"): every re-plan carries one, computed from the problem's own
functions with what a horizon fixes kept (the padded Function, the limit rows' structure; the
start state enters as values); a re-plan it finds infeasible is not run, and the closed loop
counts it.

The references are not the cached path: `certify` from scratch (every module cache cleared, the
horizon's own Function), the rows built again for the start state, the tool's speeds by central
differences of the kinematics along the played curve, the rows' gradients by central differences.
"""

from dataclasses import replace

import numpy as np
import pytest

import surestep_ocp as ss
from surestep_ocp.evaluation.closed_loop import ClosedLoop
from surestep_ocp.model import limits as lm
from surestep_ocp.model.limits import evaluate_curve
from surestep_ocp.output.certificate import INFEASIBLE
from surestep_ocp.ocp import certificate as cm
from surestep_ocp.methods import planner as pm
from surestep_ocp.ocp.certificate import NOT_CERTIFIED, certify

from limit_check import assert_tool_gradients_match

# the estimate at a waypoint: the plan's pose, off by millimetres and centiradians
OFFSET = np.array([1e-3, -5e-4, 5e-4, 0.01, 0.0, -0.01])
MEASURES = ("terminal_position_m", "terminal_angle_rad", "bound_violation", "depth_violation",
            "limit_violation", "stationarity", "complementarity", "dual_scale", "trace",
            "trace_error")


@pytest.fixture(scope="module")
def setup(interior_setup):
    return interior_setup


@pytest.fixture(scope="module")
def replans(setup):
    """Three re-plans of one Planner (prepared ahead, as the closed loop does), each with the
    setup it was certified for."""
    seen = []
    original = pm._certified

    def keep(sub, sol):
        certified, took = original(sub, sol)
        seen.append((sub, certified))
        return certified, took

    mp = pytest.MonkeyPatch()
    mp.setattr(pm, "_certified", keep)
    try:
        planner = ss.Planner(setup, prebuild=False)
        for step in (2, 3, 4):
            plan = planner.plan
            j = step - planner.step
            mean = np.asarray(plan.poses[j], float) + OFFSET
            planner.prepare(step)
            sol = planner.replan(mean, np.asarray(plan.covariances[j], float), step=step)
            assert sol.success and sol.replan.certificate_s > 0.0
            assert sol.replan.certificate_s <= sol.replan.time_s
            # by the clock, the verdict comes after the plan's joints and its certificate
            if sol.replan.verdict_s is not None:
                assert sol.replan.verdict_s >= sol.replan.feedback_s + sol.replan.certificate_s
    finally:
        mp.undo()
    assert len(seen) == 3
    return seen


def _clear_caches():
    for cache in (cm._FUNCTIONS, cm._ROWS, cm._RATES, cm._LAYOUTS, cm._LIMITS, cm._GOALS,
                  cm._MAPS):
        cache.clear()


def test_a_replans_certificate_is_certify_from_scratch(replans):
    for sub, sol in replans:
        c = sol.certificate
        assert c is not None and c.level != INFEASIBLE and c.limit_violation == 0.0
        assert sol.backend_success and sol.backend_status == sol.status
        _clear_caches()
        fresh = certify(sub, sol, padded=False)  # the horizon's own Function, built again
        assert fresh.level == c.level and fresh.active_rows == c.active_rows
        for name in MEASURES:
            a, b = getattr(c, name), getattr(fresh, name)
            assert abs(a - b) <= 1e-12 * max(abs(b), 1.0), name


def test_the_start_states_rows_are_the_rows_built_for_it(replans):
    """The rows kept per horizon with the start state's values (`_Rows.at`) against rows built for
    that state, and against the curve's rows applied to (waypoints, v0, a0) directly."""
    sub, sol = replans[-1]
    state = sol.run.start_state
    q = np.asarray(sol.q, float)
    T, dt, nq = sub.ocp.horizon, float(sub.ocp.timing.step_s), sub.robot.nq
    _clear_caches()
    other = replace(state, velocity=[0.0] * nq, acceleration=[0.0] * nq)
    kept = cm._Rows(sub, other).at(state)  # built for another state, moved to this one
    built = cm._Rows(sub, state)
    a, b = kept.values(q, False, [0.0]), built.values(q, False, [0.0])
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12)
    # the linear rows: the curve's rows times (the joint's waypoints, v0, a0), each row's joint
    lim, mov = cm._limits(sub), sub.robot.supporting_joints()
    R, J = lm.curve_limit_rows(T, dt, lim, mov, True)
    lower, upper = lm.joint_bounds(sub.robot, lim.rcm_min_distance)
    Rp, Jp, off = lm.curve_position_rows(T, dt, lower, upper, mov, True)
    v0, a0 = np.asarray(state.velocity), np.asarray(state.acceleration)
    every = np.vstack([R, Rp])
    direct = np.array([row @ np.r_[q[:, j], v0[j], a0[j]] for row, j in
                       zip(every, np.concatenate([J, Jp]))]) + np.r_[np.zeros(len(R)), off]
    # (a row without a waypoint is not kept: the start state alone decides it)
    on_waypoints = np.any(np.abs(every[:, :T + 1]) > 1e-12 * np.abs(every[:, :T + 1]).max(),
                          axis=1)
    np.testing.assert_allclose(a[0], direct[on_waypoints], rtol=0, atol=1e-12)


def test_the_tool_rows_at_a_moving_start_are_the_kinematics_differences(replans):
    """The tool rows (the padded map, the start's offsets) against the tool's speed and rotation
    rate by central differences of the kinematics along the played curve at each point's time,
    and their gradients against central differences of their values."""
    sub, sol = replans[0]
    state = sol.run.start_state
    q = np.asarray(sol.q, float)
    T, dt = sub.ocp.horizon, float(sub.ocp.timing.step_s)
    rows = cm._Rows(sub, state)
    assert rows.mapped > len(rows.windows)  # padded
    _, tool, Jz = rows.values(q, False, [0.0])
    start = (np.asarray(state.velocity), np.asarray(state.acceleration))
    times = [(t + s) * dt for t in range(T) for s in lm.TOOL_POINTS if t or s]
    assert len(times) == len(tool) // 2
    lim, robot, k = cm._limits(sub), sub.robot, 1 - lm.TOOL_MARGIN
    h = 1e-6
    for i, t in enumerate(times):
        a, b = (robot.frame_pose(p, robot.frame) for p in
                evaluate_curve(q, dt, np.array([t - h, t + h]), start=start)[0])
        speed2 = np.sum(((b[:3, 3] - a[:3, 3]) / (2 * h)) ** 2)
        turn2 = 0.5 * np.sum(((b[:3, :3] - a[:3, :3]) / (2 * h)) ** 2)
        np.testing.assert_allclose(tool[2 * i], speed2 / (k * lim.tool_speed) ** 2,
                                   rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(tool[2 * i + 1], turn2 / (k * lim.tool_rotation) ** 2,
                                   rtol=1e-5, atol=1e-9)
    assert_tool_gradients_match(rows, q)


def test_a_replan_the_certificate_finds_infeasible_is_not_run_and_is_counted(setup, monkeypatch):
    """The feedback's plan (every row checked by the solver's own rows) moved off the goal after
    that check: only the certificate sees it. Not run (the previous plan stays), `Not_Certified`,
    the solver's own words kept; the closed loop counts it among its failures."""
    original = pm.Planner._feedback

    def off_goal(self, *args, **kw):
        sol, x = original(self, *args, **kw)
        if sol is not None:
            q = np.array(sol.q, float)
            q[-1, 0] += 2e-3  # the last waypoint 2 mrad off on the first joint
            sol = replace(sol, q=q.tolist())
        return sol, x

    monkeypatch.setattr(pm.Planner, "_feedback", off_goal)
    planner = ss.Planner(setup, prebuild=False)
    loop = ClosedLoop(setup, planner=planner)
    before, step = planner.plan, 2
    mean = np.asarray(before.poses[step], float) + OFFSET
    cov = np.asarray(before.covariances[step], float)
    loop._prepared_s = [planner.prepare(step)]  # (as its rollout call keeps them)
    kept = loop._replan(0, planner, step, mean, cov, None)
    assert kept is planner and planner.plan is before and planner.step == 0
    assert loop.failures == [(step, 0, NOT_CERTIFIED)]
    assert loop.summary()["not_certified"] == 1
    # the same re-plan seen directly
    planner.prepare(step)
    sol = planner.replan(mean, cov, step=step)
    assert sol.replan.rti == "feedback" and sol.backend_success
    assert not sol.success and sol.status == NOT_CERTIFIED and sol.replan.kept_previous
    c = sol.certificate
    assert c.level == INFEASIBLE and c.terminal_position_m > 1e-4
    assert any(line.startswith("terminal position") for line in c.failures())
    assert planner.plan is before and planner.step == 0
