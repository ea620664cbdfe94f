"""Hard motion limits (`limits.enforce: true`, issue 14 item 2): the OCP's plans meet them, checked
here by an independent computation (finite differences of the returned joints over `timing.step_s`,
against the URDF's velocity attributes read by this file, the dVRK's accelerations as written in the
reference, the tool's speed from the FK of the frame, the shaft end's distance from the RCM); a plan
that breaks one is no success.
"""

from __future__ import annotations

import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy_ekf as ref
import pytest

from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.errors import ProblemError
from surestep_ocp.methods.registry import ocp_initial_guess, run_method
from surestep_ocp.solvers.nlp_cache import transcription
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.spec import LimitsSpec
from surestep_ocp.problem.setup import build_setup

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "problems" / "needle_regrasp_paper_pace.yaml"
# The dVRK's move_jp accelerations (sawIntuitiveResearchKit mtsIntuitiveResearchKitPSM.cpp): 90
# deg/s^2 for yaw and pitch, 0.2 m/s^2 for the insertion, 720 deg/s^2 for the instrument's joints.
ACCEL = {"yaw": math.pi / 2, "pitch": math.pi / 2, "insertion": 0.2, "roll": 4 * math.pi,
         "wrist_pitch": 4 * math.pi, "wrist_yaw": 4 * math.pi, "jaw": 4 * math.pi}
TOL = 1e-6  # relative: IPOPT meets its bounds to about 1e-8


def urdf_velocities(path: Path) -> dict[str, float]:
    root = ET.parse(str(path)).getroot()
    return {j.get("name"): float(j.find("limit").get("velocity")) for j in root.iter("joint")
            if j.get("type") in ("revolute", "prismatic") and j.find("limit") is not None}


def check_plan(setup, sol, velocity=None, accel=None, tool_speed=0.1, tool_rotation=math.pi / 2,
               rcm=0.045):
    """Assert every limit independently; return the peak ratios."""
    dt = setup.ocp.timing.step_s
    names = sol.joint_names
    v_lim = {**urdf_velocities(setup.robot.urdf), **(velocity or {})}
    a_lim = {**ACCEL, **(accel or {})}
    q = np.array(sol.q, float)
    vel = np.diff(q, axis=0) / dt
    # rest to rest
    acc = np.diff(np.vstack([np.zeros(len(names)), vel, np.zeros(len(names))]), axis=0) / dt
    vr = np.abs(vel) / np.array([v_lim[n] for n in names])
    ar = np.abs(acc) / np.array([a_lim[n] for n in names])
    assert vr.max() <= 1 + TOL, (names[int(np.argmax(vr.max(axis=0)))], vr.max())
    assert ar.max() <= 1 + TOL, (names[int(np.argmax(ar.max(axis=0)))], ar.max())
    T_tool = [setup.robot.frame_pose(qi, setup.robot.frame) for qi in q]
    speed = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(T_tool, T_tool[1:])]) / dt
    rot = np.array([np.arccos(np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1))
                    for a, b in zip(T_tool, T_tool[1:])]) / dt
    assert speed.max() <= tool_speed * (1 + TOL)
    assert rot.max() <= tool_rotation * (1 + TOL)
    shaft_end = np.array([np.linalg.norm(setup.robot.frame_pose(qi, "roll_link")[:3, 3])
                          for qi in q])
    assert shaft_end.min() >= rcm * (1 - TOL)
    return vr.max(), ar.max(), speed.max() / tool_speed


# The curve `surestep export` plays at the planned times (model/limits/curve.py), written out here:
# per step the quintic Hermite polynomial with the waypoints' finite-difference velocities and
# accelerations at both ends.
HERMITE = np.array([[1, 0, 0, -10, 15, -6], [0, 1, 0, -6, 8, -3], [0, 0, 0.5, -1.5, 1.5, -0.5],
                    # p0, v0, a0, p1, v1, a1
                    [0, 0, 0, 10, -15, 6], [0, 0, 0, -4, 7, -3], [0, 0, 0, 0.5, -1, 0.5]])


def played_curve(q, dt, per_step=200):
    """Times, positions, velocities and accelerations of the played curve, `per_step` samples per
    step."""
    T = len(q) - 1
    v = np.zeros_like(q)
    v[1:-1] = (q[2:] - q[:-2]) / (2 * dt)
    a = np.zeros_like(q)
    a[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) / dt**2
    a[0], a[-1] = (q[1] - q[0]) / dt**2, (q[-2] - q[-1]) / dt**2
    s = np.linspace(0, 1, per_step, endpoint=False)
    out = [[], [], [], []]
    for t in range(T):
        # (6, n)
        data = np.stack([q[t], dt * v[t], dt**2 * a[t], q[t + 1], dt * v[t + 1], dt**2 * a[t + 1]])
        coef = HERMITE.T @ data  # power coefficients in s, (6, n)
        for order in range(3):
            c = np.polynomial.polynomial.polyder(coef, order) / dt**order if order else coef
            out[order + 1].append(np.polynomial.polynomial.polyval(s, c).T)
        out[0].append((t + s) * dt)
    return [np.concatenate(x) for x in out]


def check_curve(setup, sol, velocity=None, accel=None, tool_speed=0.1, tool_rotation=math.pi / 2):
    """The played curve within the joint limits at every sample, and the tool's speed (chords of the
    FK over the samples); returns the peak ratios."""
    dt = setup.ocp.timing.step_s
    names = sol.joint_names
    v_lim = np.array([{**urdf_velocities(setup.robot.urdf), **(velocity or {})}[n] for n in names])
    a_lim = np.array([{**ACCEL, **(accel or {})}[n] for n in names])
    t, q, v, a = played_curve(np.array(sol.q, float), dt)
    # through the waypoints at their times
    np.testing.assert_allclose(q[::200], np.array(sol.q)[:-1], atol=1e-12)
    vr, ar = (np.abs(v) / v_lim).max(), (np.abs(a) / a_lim).max()
    assert vr <= 1 + TOL and ar <= 1 + TOL, (vr, ar)
    T_tool = [setup.robot.frame_pose(qi, setup.robot.frame) for qi in q]
    h = np.diff(t)
    speed = np.array([np.linalg.norm(b[:3, 3] - a_[:3, 3])
                      for a_, b in zip(T_tool, T_tool[1:])]) / h
    rot = np.array([np.arccos(np.clip((np.trace(a_[:3, :3].T @ b[:3, :3]) - 1) / 2, -1, 1))
                    for a_, b in zip(T_tool, T_tool[1:])]) / h
    assert (speed.max() <= tool_speed * (1 + TOL)
            and rot.max() <= tool_rotation * (1 + TOL)), (speed.max(), rot.max())
    return vr, ar, speed.max() / tool_speed, rot.max() / tool_rotation


def check_solution(setup, sol):
    """The trace by the exact EKF along the plan's poses; the terminal equality."""
    sig, _ = ref.propagate(np.asarray(sol.poses), setup.ocp.noise,
                           setup.ocp.intrinsics, guard=COSINE_GUARD)
    assert ref.rel_err(np.trace(sig[-1]), sol.trace_final) <= 1e-6
    assert np.abs(np.asarray(sol.poses[-1]) - setup.x_goal).max() <= 1e-6


def newton_attempt(setup) -> dict:
    """The same problem under `solver.name: newton`: its first attempt (Newton's unconstrained plan,
    then checked)."""
    newton = setup.with_ocp(solver=replace(setup.ocp.solver, name="newton"))
    first = solve_ocp(newton, ocp_initial_guess(setup)).attempts[0]
    assert first.label == "newton" and first.solver == "newton"
    return first


def enforced(problem, **kw):
    return replace(problem, limits=LimitsSpec(enforce=True, **kw))


@pytest.fixture(scope="module")
def default_enforced():
    """The default problem at 0.1 s per step (its 0.05 s x 20 steps is infeasible with the played
    curve's rows)."""
    prob = load_problem(DEFAULT)
    setup = build_setup(enforced(replace(prob, timing=replace(prob.timing, step_s=0.1))))
    return setup, run_method(setup, "ocp")


def test_default_problem_plan_meets_every_limit(default_enforced):
    setup, sol = default_enforced
    assert sol.success, sol.status
    ratios = check_plan(setup, sol)
    check_solution(setup, sol)
    curve = check_curve(setup, sol)  # and the curve the export plays at the planned pace
    # the limits are active (the unconstrained plan moves 31 mm in its first step)
    assert max(curve) > 0.9
    # the finite differences are averages of the curve's values
    assert max(ratios) <= max(curve) + 1e-9
    assert sol.motion_limits.ok and sol.motion_limits.enforced
    # the interior-point method, which carries them, solves it (projected Newton's unconstrained
    # plan would break them: not run under auto)
    assert sol.run.solver == "interior" and "newton" not in [a.solver for a in sol.attempts]
    first = newton_attempt(setup)
    assert first.status == "Motion_Limits_Violated" and first.objective < sol.objective


@pytest.mark.parametrize("config", [3, 5])
def test_evaluation_configurations_meet_every_limit(config):
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations"
                                                   / "evaluation.yaml"))
    setup = build_setup(enforced(sampler.problem(sampler.sample(0, config))))
    sol = run_method(setup, "ocp")
    assert sol.success, sol.status
    check_plan(setup, sol)
    check_curve(setup, sol)
    check_solution(setup, sol)


def test_overrides_from_the_problem_file_are_honoured(write_problem):
    """Per-joint overrides and a slower tool from the YAML section; a longer step to leave room."""
    path = write_problem(lambda t: t.update(limits={"enforce": True, "joint_velocity": {"yaw": 0.3},
                                                     "joint_acceleration": {"wrist_pitch": 3.0},
                                                     "tool_speed": 0.05,
                                                    "tool_rotation_speed": 1.0},
                                            timing={"step_s": 0.1, "tracker_hz": 20}), "overrides")
    prob = load_problem(path)
    assert prob.limits.joint_velocity == (("yaw", 0.3),) and prob.limits.tool_speed == 0.05
    setup = build_setup(prob)
    sol = run_method(setup, "ocp")
    assert sol.success, sol.status
    check_plan(setup, sol, velocity={"yaw": 0.3}, accel={"wrist_pitch": 3.0}, tool_speed=0.05,
               tool_rotation=1.0)
    check_curve(setup, sol, velocity={"yaw": 0.3}, accel={"wrist_pitch": 3.0}, tool_speed=0.05,
                tool_rotation=1.0)
    check_solution(setup, sol)


def test_rcm_distance_is_a_bound_on_the_insertion():
    """The derived bound: the shaft's end is `q_insertion - 0.0156` m past the RCM (reference 1c),
    so 45 mm is q_insertion >= 0.0606 m; the enforced NLP's lower bound on every moving node's
    insertion."""
    setup = build_setup(enforced(load_problem(DEFAULT), rcm_distance=0.07))
    tr = transcription(setup, "condensed", hessian="surrogate")
    j, bound = tr.rcm_bound
    assert (setup.robot.joint_names[j] == "insertion"
            and bound == pytest.approx(0.07 + 0.0156, abs=1e-9))
    lbx, _ = tr.bounds(setup, np.ones(setup.ocp.horizon + 1))
    lo = tr.layout.split(lbx)
    assert all(lo[f"q{t}"][j] == pytest.approx(0.0856) for t in range(1, setup.ocp.horizon + 1))
    rng = np.random.default_rng(0)
    for _ in range(5):  # the distance does not depend on the other joints
        q = rng.uniform(setup.robot.lower, setup.robot.upper)
        q[j] = 0.0856
        assert (np.linalg.norm(setup.robot.frame_pose(q, "roll_link")[:3, 3])
                == pytest.approx(0.07, abs=1e-9))


@pytest.mark.parametrize("rows", ["curve", "steps"])
def test_limit_rows_staged_derivatives_equal_casadis_own(monkeypatch, rows):
    """The limit rows' stage-wise Jacobian and curvature (the tool rows are nonlinear) equal
    CasADi's AD of the whole NLP, at a perturbed point with random multipliers (T = 6), for the
    played curve's rows (the tool at 4 points of each step but the first's start, 2 rows each) and
    the finite differences'."""
    from surestep_ocp.model import limits
    from surestep_ocp.solvers import nlp_cache

    monkeypatch.setattr(limits, "CURVE_ROWS", rows)
    monkeypatch.setattr(nlp_cache, "_CACHE", {})
    setup = build_setup(enforced(replace(load_problem(DEFAULT), horizon=6)))
    staged, exact = transcription(setup, hessian="surrogate"), transcription(setup, hessian="exact")
    assert (staged.ng == exact.ng > staged.ng_eq
            and staged.n_tool == 2 * (4 * 6 - 1 if rows == "curve" else 6))
    x0, scale, _ = staged._condensed_start(setup, ocp_initial_guess(setup))
    rng = np.random.default_rng(5)
    x = x0 + 1e-2 * rng.normal(size=len(x0))
    p = staged._parameters(setup, scale, 2e-5)
    c_e, J_e = exact.solver.get_function("nlp_jac_g")(x, p)
    c_s, J_s = staged.solver.get_function("nlp_jac_g")(x, p)
    assert np.abs(np.asarray(c_s) - np.asarray(c_e)).max() <= 1e-10 * np.abs(np.asarray(c_e)).max()
    assert np.abs(J_s.full() - J_e.full()).max() <= 1e-9 * np.abs(J_e.full()).max()
    lam_g = rng.normal(size=staged.ng)
    H_s = staged.hess_lag(x, p, 0.0, lam_g).full()
    H_e = exact.solver.get_function("nlp_hess_l")(x, p, 0.0, lam_g).full()
    assert np.abs(H_s - np.triu(H_e)).max() <= 1e-9 * np.abs(H_e).max()


def test_a_plan_over_a_limit_is_not_a_success():
    """The gradient variant's plan breaks the yaw's acceleration limit: with the limits enforced it
    is no success, status Motion_Limits_Violated, the optimiser's own status kept; reported (not a
    failure) when not."""
    prob = load_problem(DEFAULT)
    sol = run_method(build_setup(enforced(prob)), "gradient")
    assert not sol.success and sol.status == "Motion_Limits_Violated"
    assert sol.run.solver_status == "completed 50 iterations"
    kinds = {v.kind for v in sol.motion_limits.violations}
    assert "joint_acceleration" in kinds
    assert run_method(build_setup(prob), "gradient").success


def test_cli_exits_1_with_the_status(write_problem):
    path = write_problem(lambda t: t.update(limits={"enforce": True}), "enforced")
    res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "solve", str(path), "--method",
                          "gradient"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert res.returncode == 1, res.stderr
    assert "Motion_Limits_Violated" in res.stderr + res.stdout


@pytest.mark.parametrize("section, key", [({"enforce": "yes"}, "limits.enforce"),
                                          ({"joint_velocity": {"elbow": 1.0}},
                                           "limits.joint_velocity.elbow"),
                                          ({"tool_speed": -1}, "limits.tool_speed"),
                                          ({"rcm": 0.04}, "limits.rcm")])
def test_bad_limits_sections_are_named_errors(write_problem, section, key):
    path = write_problem(lambda t: t.update(limits=section), "bad_limits")
    with pytest.raises(ProblemError, match=key.replace(".", r"\.")):
        load_problem(path)


@pytest.mark.parametrize("moving", [False, True])
def test_position_rows_are_the_curves_control_points_and_bound_it(moving):
    """`curve_position_rows` are the quintic's interior Bernstein control points (against the power
    coefficients of `curve_coefficients`), and the played curve (`evaluate_curve`, sampled densely)
    stays between each piece's smallest and largest control point; centred and normalised, a curve
    passing a bound between two waypoints breaks a row."""
    from surestep_ocp.model.limits import curve_position_rows, evaluate_curve
    from surestep_ocp.model.limits.curve import _to_bernstein, curve_coefficients

    T, dt = 8, 0.05
    rows, which, off = curve_position_rows(T, dt, [-0.5], [0.5], [0], moving)
    assert rows.shape == (4 * T, T + 3 if moving else T + 1) and np.all(which == 0)
    C, B = curve_coefficients(T, dt, moving), _to_bernstein(5)
    for t in range(T):
        np.testing.assert_allclose(rows[4 * t:4 * t + 4] * 0.5, (B @ C[t])[1:5], atol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = np.cumsum(rng.normal(size=T + 1)) * 0.02
        ext = np.r_[x, rng.normal(size=2) * 0.1] if moving else x
        start = (np.array([ext[-2]]), np.array([ext[-1]])) if moving else None
        tt = np.linspace(0, T * dt, 4001)
        p = evaluate_curve(x[:, None], dt, tt, start=start)[0][:, 0]
        ctrl = rows @ ext * 0.5  # the control points themselves (centre 0, half-range 0.5)
        for t in range(T):
            seg = p[(tt >= t * dt - 1e-12) & (tt <= (t + 1) * dt + 1e-12)]
            hull = np.r_[x[t], ctrl[4 * t:4 * t + 4], x[t + 1]]
            assert hull.min() - 1e-12 <= seg.min() and seg.max() <= hull.max() + 1e-12
    # a joint at its upper bound at waypoints 4.. after rising: the curve passes the bound, a row
    # says so
    x = np.minimum(np.linspace(0, 0.9, T + 1), 0.5)
    p = evaluate_curve(x[:, None], dt, np.linspace(0, T * dt, 4001))[0][:, 0]
    rows, _, off = curve_position_rows(T, dt, [-0.5], [0.5], [0])
    assert p.max() > 0.5 and np.max(np.abs(rows @ x + off)) > 1
