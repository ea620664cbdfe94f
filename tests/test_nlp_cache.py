"""The NLP cache (surestep_ocp.solvers.nlp_cache): the enforced NLP's acceptable-level stop
(`ENFORCED_OPTIONS`) against independent checks: a tighter IPOPT solve of the same NLP without the
acceptable level, the plan's finite-difference limit report and the export's own dense check of the
played curve; and its key on the limit rows' kind."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_limits import DEFAULT, enforced

from surestep_ocp.model import limits as lm
from surestep_ocp.output.export import time_parametrise, within_position_limits
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.methods.registry import ocp_initial_guess, run_method
from surestep_ocp.solvers.nlp_cache import transcription

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def enforced_default():
    """The default problem at 40 steps of 0.05 s with the limits enforced (set here, whatever the
    file holds)."""
    prob = load_problem(ROOT / "problems" / "needle_regrasp.yaml")
    # IPOPT's (auto: interior first)
    prob = replace(prob, horizon=40, limits=replace(prob.limits, enforce=True),
                   timing=replace(prob.timing, step_s=0.05),
                   solver=replace(prob.solver, name="ipopt"))
    setup = build_setup(prob)
    return setup, run_method(setup, "ocp")


def test_acceptable_stop_is_reported_as_such(enforced_default):
    """The default problem's surrogate IPOPT ends in its linear tail: stopped there, and the status
    says so."""
    _, sol = enforced_default
    assert sol.success
    kept = [a for a in sol.attempts if a.kept]
    assert len(kept) == 1 and kept[0].label == "surrogate"
    assert sol.status == kept[0].status == "Solved_To_Acceptable_Level", sol.attempts


def test_acceptable_plan_equals_a_tight_solve(enforced_default):
    """Tr(Sigma_T) within 1e-6 of the same NLP solved to tol 1e-9 with the acceptable level off (at
    1e-10, with the joint bounds on the played curve as rows, IPOPT itself stops at an acceptable
    point: the same Tr(Sigma_T) to 1e-15 relative, measured)."""
    setup, sol = enforced_default
    tight_opts = {"ipopt.tol": 1e-9, "ipopt.acceptable_iter": 0, "ipopt.max_iter": 1000}
    tr = transcription(setup, "condensed", tight_opts, hessian="surrogate")
    tight, _ = tr.solve(setup, ocp_initial_guess(setup))
    assert tight.status == "Solve_Succeeded", tight.status
    assert abs(sol.trace_final / tight.trace_final - 1) < 1e-6, (sol.trace_final, tight.trace_final)
    assert tight.iterations > sol.attempts[-1].iterations  # the tail it did not run


def test_acceptable_plan_meets_every_limit(enforced_default):
    """The finite-difference report and the export's dense check of the played curve: within every
    limit, exported at its planned duration."""
    setup, sol = enforced_default
    report = lm.plan_report(setup.robot, np.array(sol.q, float), setup.ocp.timing.step_s,
                            lm.problem_limits(setup), tool_frame=setup.robot.frame)
    assert report.ok, report.violations[:3]
    q, _ = within_position_limits(np.array(sol.q, float), setup.robot)
    traj = time_parametrise(q, setup.ocp.timing.step_s, lm.problem_limits(setup),
                            robot=setup.robot, tool_frame=setup.robot.frame)
    assert traj.timing == "planned"
    assert traj.duration == pytest.approx(setup.ocp.horizon * setup.ocp.timing.step_s)


def test_transcription_cache_keys_on_the_row_kind(monkeypatch):
    """Switching `limits.CURVE_ROWS` gives another cached NLP, not the one built with the other
    rows."""
    from surestep_ocp.model import limits as lm
    from surestep_ocp.solvers import nlp_cache

    limits = nlp_cache.enforced_limits(build_setup(enforced(load_problem(DEFAULT))))
    curve = nlp_cache.limits_key(limits)
    monkeypatch.setattr(lm, "CURVE_ROWS", "steps")
    assert nlp_cache.limits_key(limits) != curve


def test_newton_solvers_are_kept_per_thread():
    """The Newton and interior-point solvers evaluate in place in their own buffers, so each thread
    has its own (an in-process Dask cluster's workers are threads): the same object within a
    thread, another in a second thread; and Newton solves run in two threads at once give the plans
    they give alone (checked joint by joint)."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    import surestep_ocp as ss
    from surestep_ocp.solvers.nlp_cache import interior_solver, newton_solver

    setup = build_setup(load_problem(ROOT / "problems" / "needle_regrasp.yaml"))
    here = (newton_solver(setup), interior_solver(setup))
    assert (newton_solver(setup), interior_solver(setup)) == here
    there = []
    t = threading.Thread(target=lambda: there.append((newton_solver(setup),
                                                      interior_solver(setup))))
    t.start()
    t.join()
    assert there[0][0] is not here[0] and there[0][1] is not here[1]

    paper = load_problem(ROOT / "problems" / "needle_regrasp_paper_pace.yaml").with_solver(
        codegen=False)
    goals = [paper.with_goal(position=[0.045 + 0.004 * k, 0.005, 0.115], axis_angle=[0.6, 0.1, 1.4])
             for k in range(4)]

    def plan(problem):
        return np.array(ss.solve(problem, method="ocp").joints)

    alone = [plan(p) for p in goals]
    with ThreadPoolExecutor(max_workers=2) as pool:
        together = list(pool.map(plan, goals * 2))
    for k, q in enumerate(together):
        np.testing.assert_array_equal(q, alone[k % 4])


def test_the_interior_solver_compiles_the_robots_ik_once(monkeypatch):
    """Building an interior-point solver with codegen compiles its robot's IK residual (the start's
    search and every re-plan's goal solve IK), once per robot model; the compiled IK's solutions are
    the interpreted one's, checked by Pinocchio's FK."""
    from surestep_ocp.model import robot as robot_module
    from surestep_ocp.solvers import nlp_cache
    from surestep_ocp.ocp.codegen import available

    if not available():
        pytest.skip("no C compiler")
    monkeypatch.setattr(robot_module, "_IK_FUNCS", {})  # the robot model's IK not compiled yet
    monkeypatch.setattr(nlp_cache, "_INTERIOR", {})
    prob = load_problem(ROOT / "problems" / "needle_regrasp.yaml").with_solver(name="interior",
                                                                               codegen=True)
    setup = build_setup(prob)
    robot = setup.robot
    target = robot.frame_pose(setup.q_goal)
    q_interpreted = robot.inverse_kinematics(target, setup.q_start)[0]
    assert robot._ik_funcs.class_name() == "SXFunction"
    solver = nlp_cache.interior_solver(setup)
    assert solver.codegen_note is None
    compiled = robot._ik_funcs
    assert compiled.class_name() == "External"
    nlp_cache.interior_solver(setup, moving=True)  # another structure: the same compiled IK
    assert robot._ik_funcs is compiled
    q_compiled = robot.inverse_kinematics(target, setup.q_start)[0]
    np.testing.assert_allclose(q_compiled, q_interpreted, atol=1e-10)
    np.testing.assert_allclose(robot.frame_pose(q_compiled), target, atol=1e-9)
