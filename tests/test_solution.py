"""The Solution's typed records (how the solve went, the problem's record, a re-plan's, the
motion-limit report) written to the solution file and read back: equal records, the file's keys
those of the untyped format before them, and a file in that format read into the same records; the
limit report's numbers against finite differences of a plan computed here."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

import surestep_ocp as ss
from surestep_ocp.model.limits import (
    LimitsReport,
    MotionLimits,
    PlayedCurve,
    SkippedReport,
    Violation,
    plan_report,
)
from surestep_ocp.output.attempt_record import AttemptRecord
from surestep_ocp.output.solution import Solution
from surestep_ocp.output.solution_records import (
    CondensedStart,
    LimitsRecord,
    Needle,
    Placement,
    ProblemRecord,
    ReplanAttempt,
    ReplanRecord,
    SecondStart,
    SolveRecord,
    StartState,
    Timing,
)

EYE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
SIGMA = [[1e-6 if i == j else 0.0 for j in range(6)] for i in range(6)]
CORE = {"method": "ocp-replan", "problem": "problems/x.yaml", "success": True,
        "status": "Solve_Succeeded", "solve_time_s": 0.01, "iterations": 7, "horizon": 1,
        "joint_names": ["a", "b"], "q": [[0.0, 0.1], [0.2, 0.3]],
        "poses": [[0.0, 0.0, 0.1, 0.0, 0.0, 0.0], [0.01, 0.0, 0.1, 0.0, 0.0, 0.1]],
        "goal": [0.01, 0.0, 0.1, 0.0, 0.0, 0.1], "camera": {"fx": 1.0}, "camera_pose": EYE,
        "robot": {"urdf": "r.urdf", "frame": "tool", "base_pose": EYE}, "noise": {"W_p0": 1e-6},
        "trace": [6e-6, 5e-6], "sigma": [SIGMA, SIGMA], "sigma_final": SIGMA, "objective": 5e-6}
ATTEMPT = {"label": "newton", "solver": "newton", "hessian": None, "status": "Solve_Succeeded",
           "iterations": 7, "solve_time_s": 0.01, "objective": 5e-6, "kept": True,
           "compiled": True}
# the untyped format: every record's field a top-level key (a re-plan's under `replan`), as
# `Solution.to_dict` wrote it before the records were typed
OLD = {**CORE, "attempts": [ATTEMPT],
       "init": "warm start (previous plan)", "solver": "newton", "covariance_form": "condensed",
       "exact_steps": 3, "secant_steps": 1, "build_time_s": 0.5, "compiled": True,
       "codegen_note": "cc failed\nmore", "ocp_trace_final": 5e-6, "initial_trace": 6e-6,
       "constraint_violation": 1e-12,
       "timing": {"step_s": 0.05, "tracker_hz": 20.0, "frames_per_step": 1},
       "limits": {"enforce": True, "joint_names": ["a", "b"], "velocity": [1.0, 2.0],
                  "acceleration": [3.0, 4.0], "tool_speed_m_s": 0.1, "tool_rotation_rad_s": 1.5,
                  "rcm_min_distance_m": 0.045, "sources": {"velocity": "urdf"}},
       "other_arms": [{"urdf": "o.urdf", "frame": "tool", "base_pose": EYE, "q": [0.0, 1.0],
                       "needle": {"radius": 0.012, "grasp": EYE}}],
       "camera_poses": [EYE, EYE],
       "ecm": {"urdf": "e.urdf", "frame": "camera", "q": [0.1, 0.2], "base_pose": EYE},
       "hessian": "newton", "initial_objective": 6.1e-6, "worse_than_initial_guess": False,
       "condensed_start": {"status": "Solve_Succeeded", "iterations": 4, "solver": "ipopt",
                           "solve_time_s": 0.02, "objective": 5.5e-6},
       "second_start": {"status": "Solve_Succeeded", "iterations": 5, "solve_time_s": 0.003,
                        "ahead": True, "newton_status": "Maximum_Iterations_Exceeded",
                        "newton_iterations": 60, "newton_objective": 5.2e-6,
                        "ipopt_status": "Solve_Succeeded", "ipopt_iterations": 9},
       "lifted": "not run", "solver_status": "Solve_Succeeded",
       "start_state": {"velocity": [0.0, 0.1], "acceleration": [0.0, -0.1]},
       "warm_start_q": [[0.0, 0.1], [0.2, 0.3]], "reserve": 0.1, "extended_steps": 0,
       "replan": {"step": 3, "time_s": 0.004, "solver": "interior", "build_time_s": 0.0,
                  "kept_previous": False,
                  "attempts": [{"reserve": 0.1, "steps_added": 0, "status": "Solve_Succeeded",
                                "iterations": 7, "relaxed_iterations": 2}]}}
RUN = SolveRecord(
    solver="newton", init="warm start (previous plan)", hessian="newton",
    covariance_form="condensed", build_time_s=0.5, compiled=True, codegen_note="cc failed\nmore",
    initial_trace=6e-6, initial_objective=6.1e-6, worse_than_initial_guess=False,
    ocp_trace_final=5e-6, constraint_violation=1e-12, solver_status="Solve_Succeeded",
    warm_start_q=[[0.0, 0.1], [0.2, 0.3]], start_state=StartState([0.0, 0.1], [0.0, -0.1]),
    lifted="not run", condensed_start=CondensedStart("Solve_Succeeded", 4, "ipopt", 0.02, 5.5e-6),
    second_start=SecondStart("Solve_Succeeded", 5, 0.003, True, "Maximum_Iterations_Exceeded",
                             60, 5.2e-6, "Solve_Succeeded", 9))
PROBLEM = ProblemRecord(
    timing=Timing(0.05, 20.0, 1),
    limits=LimitsRecord(True, ["a", "b"], [1.0, 2.0], [3.0, 4.0], 0.1, 1.5, 0.045,
                        {"velocity": "urdf"}),
    other_arms=[Placement("o.urdf", "tool", EYE, [0.0, 1.0], Needle(0.012, EYE))],
    camera_poses=[EYE, EYE], ecm=Placement("e.urdf", "camera", EYE, [0.1, 0.2]))
REPLAN = ReplanRecord(3, 0.004, "interior", 0.0, False,
                      [ReplanAttempt(0.1, 0, "Solve_Succeeded", 7, 2)])


# a limit report as `surestep compare` wrote it with `limits.enforce: true` before it was typed
LIMITS = {"joint_names": ["a", "b"], "velocity": [1.0, 2.0], "acceleration": [3.0, 4.0],
          "tool_speed_m_s": 0.1, "tool_rotation_rad_s": 1.5, "rcm_min_distance_m": 0.045,
          "sources": {"velocity": {"a": "problem file"}, "tool_speed": "override"}}
OLD_REPORT = {
    "step_s": 0.05, "duration_s": 0.1, "limits": LIMITS,
    "peak_joint_velocity": [4.0, 0.5], "peak_joint_acceleration": [80.0, 10.0],
    "velocity_ratio": [4.0, 0.25], "acceleration_ratio": [80.0 / 3, 2.5],
    "peak_tool_speed_m_s": 0.2, "peak_tool_rotation_rad_s": 0.3, "min_rcm_distance_m": None,
    "tool_speed_per_step_m_s": [0.2, 0.1], "tool_rotation_per_step_rad_s": [0.3, 0.1],
    "violations": [{"kind": "joint_velocity", "step": 0, "joint": "a", "value": -4.0,
                    "limit": 1.0},
                   {"kind": "tool_speed", "step": 0, "value": 0.2, "limit": 0.1}],
    "ok": False, "enforced": True,
    "played_curve": {"curve": "quintic Hermite",
                     "peak_ratios": {"joint_velocity": 5.1, "joint_acceleration": 90.0,
                                     "tool_speed": None, "tool_rotation": None},
                     "within": False}}
REPORT = LimitsReport(
    step_s=0.05, duration_s=0.1,
    limits=MotionLimits(("a", "b"), np.array([1.0, 2.0]), np.array([3.0, 4.0]), 0.1, 1.5, 0.045,
                        sources={"velocity": {"a": "problem file"}, "tool_speed": "override"}),
    peak_joint_velocity=[4.0, 0.5], peak_joint_acceleration=[80.0, 10.0],
    velocity_ratio=[4.0, 0.25], acceleration_ratio=[80.0 / 3, 2.5], peak_tool_speed_m_s=0.2,
    peak_tool_rotation_rad_s=0.3, min_rcm_distance_m=None, tool_speed_per_step_m_s=[0.2, 0.1],
    tool_rotation_per_step_rad_s=[0.3, 0.1],
    violations=[Violation(kind="joint_velocity", step=0, joint="a", value=-4.0, limit=1.0),
                Violation(kind="tool_speed", step=0, value=0.2, limit=0.1)],
    ok=False, enforced=True,
    played_curve=PlayedCurve("quintic Hermite", {"joint_velocity": 5.1, "joint_acceleration": 90.0,
                                                 "tool_speed": None, "tool_rotation": None},
                             False))


def test_a_file_in_the_untyped_format_reads_into_the_typed_records(tmp_path):
    path = tmp_path / "old.json"
    path.write_text(json.dumps(OLD))
    sol = Solution.load(path)
    assert sol.run == RUN and sol.problem_record == PROBLEM and sol.replan == REPLAN
    assert sol.attempts == [AttemptRecord(**ATTEMPT)]
    # only the backend's and the method's own keys stay extras
    assert sol.extras == {"exact_steps": 3, "secant_steps": 1, "reserve": 0.1,
                          "extended_steps": 0}
    assert sol.times.tolist() == [0.0, 0.05]
    # written again: the same keys, the same values
    assert sol.to_dict() == OLD


def test_typed_records_written_and_read_back_are_equal(tmp_path):
    sol = Solution(**CORE, attempts=[AttemptRecord(**ATTEMPT)], run=RUN, problem_record=PROBLEM,
                   replan=REPLAN, extras={"exact_steps": 3, "secant_steps": 1, "reserve": 0.1,
                                          "extended_steps": 0})
    back = Solution.load(sol.save(tmp_path / "new.json"))
    assert back == sol
    assert json.loads((tmp_path / "new.json").read_text()) == OLD


def test_unset_fields_write_no_key():
    """An optional field left at None is no key of the file (as an absent extra was)."""
    d = Solution(**CORE, run=SolveRecord(solver="ipopt")).to_dict()
    assert set(d) == {*CORE, "attempts", "solver"}
    assert Solution.from_dict(d).run == SolveRecord(solver="ipopt")
    assert Solution.from_dict(d).replan is None


@pytest.mark.parametrize("key, value", [("timing", {"step_s": 0.05}),
                                        ("replan", {"step": 3, "seconds": 0.1}),
                                        ("second_start", [1, 2]),
                                        ("motion_limits", {"step_s": 0.05, "ok": True}),
                                        ("motion_limits", "not checked"),
                                        ("motion_limits", {**OLD_REPORT,
                                                           "limits": {**LIMITS, "jerk": [1.0]}})])
def test_a_value_of_another_shape_stays_an_extra(key, value):
    """A recorded value that does not read as its record (e.g. an older shape) is kept unread in
    `extras` and written back unchanged."""
    d = {**CORE, "attempts": [], key: value}
    sol = Solution.from_dict(d)
    assert sol.extras == {key: value}
    assert sol.to_dict() == d


def test_a_solved_plan_round_trips(tmp_path):
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(6)
    sol = ss.solve(problem, "ocp")
    assert sol.run.solver in ("newton", "ipopt") and sol.run.initial_trace > 0
    assert sol.problem_record.timing.step_s > 0 and sol.problem_record.limits is not None
    back = Solution.load(sol.save(tmp_path / "ocp.json"))
    assert back.run == sol.run and back.problem_record == sol.problem_record
    assert back.attempts == sol.attempts and back.to_dict() == sol.to_dict()
    # frozen: a changed copy, the plan as it was
    with pytest.raises(dataclasses.FrozenInstanceError):
        sol.success = False
    failed = sol.replaced(success=False, status="Not_Certified")
    assert failed == dataclasses.replace(sol, success=False, status="Not_Certified")
    assert sol.success and failed.to_dict() == {**sol.to_dict(), "success": False,
                                                "status": "Not_Certified"}
    with pytest.raises(TypeError, match="no field succes"):
        sol.replaced(succes=False)


@pytest.mark.parametrize("old, typed", [
    (OLD_REPORT, REPORT),
    # a report from before `duration_s` was recorded, not enforced, without a played curve
    ({k: v for k, v in OLD_REPORT.items() if k not in ("duration_s", "enforced", "played_curve")},
     LimitsReport(**{**REPORT.__dict__, "duration_s": None, "enforced": None,
                     "played_curve": None})),
    ({"skipped": "a waypoint has no IK solution (see reachability)"},
     SkippedReport("a waypoint has no IK solution (see reachability)")),
    ({"skipped": "a waypoint has no IK solution (see reachability)", "ok": False,
      "enforced": True},
     SkippedReport("a waypoint has no IK solution (see reachability)", False, True))])
def test_an_untyped_limit_report_reads_into_the_typed_one(old, typed):
    """The file's `motion_limits` as written when it was a dict of the extras: read into the typed
    report, not left in the extras, written back as it was (the same keys in the same order)."""
    d = {**CORE, "attempts": [], "motion_limits": old}
    sol = Solution.from_dict(json.loads(json.dumps(d)))
    assert sol.motion_limits == typed and sol.extras == {}
    assert json.dumps(sol.to_dict()) == json.dumps(d)


def test_a_plans_limit_report_round_trips_and_matches_finite_differences(default_setup, tmp_path):
    """A plan's report against limits set here: its per-joint ratios and violations equal finite
    differences of the joints computed here (at rest before and after), and the report reads back
    from the solution file equal."""
    sol = ss.solve(ss.load_problem("problems/needle_regrasp_paper_pace.yaml"), "baseline")
    q, dt = sol.joints, 0.05
    v = np.diff(q, axis=0) / dt
    a = np.diff(np.vstack([np.zeros((1, q.shape[1])), v, np.zeros((1, q.shape[1]))]), axis=0) / dt
    # limits below some joints' peaks: violations to count
    vmax = 0.6 * np.abs(v).max(axis=0) + 1e-3
    amax = 2.0 * np.abs(a).max(axis=0) + 1e-3
    limits = MotionLimits(tuple(sol.joint_names), vmax, amax)
    rep = plan_report(default_setup.robot, q, dt, limits, tool_frame=default_setup.robot.frame)
    np.testing.assert_allclose(rep.velocity_ratio, np.abs(v).max(axis=0) / vmax, rtol=1e-12)
    np.testing.assert_allclose(rep.acceleration_ratio, np.abs(a).max(axis=0) / amax, rtol=1e-12)
    over = [(t, sol.joint_names[j]) for t, j in np.argwhere(np.abs(v) > vmax * (1 + 1e-6))]
    assert over and [(x.step, x.joint) for x in rep.violations
                     if x.kind == "joint_velocity"] == over
    assert not any(x.kind == "joint_acceleration" for x in rep.violations) and not rep.ok
    assert rep.duration_s == pytest.approx(dt * sol.horizon)
    sol = replace(sol, motion_limits=rep)
    back = Solution.load(sol.save(tmp_path / "baseline.json"))
    assert back.motion_limits == rep and "motion_limits" not in back.extras
    assert back.to_dict() == sol.to_dict()
