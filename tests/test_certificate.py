"""The optimality certificate (ocp/certificate.py, output/certificate.py) and `surestep check`:
its trace against the textbook NumPy EKF, its stationarity against finite differences, a perturbed
plan not certified, the one meaning of success, the solution file's record."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import numpy_ekf as ref
from limit_check import assert_tool_gradients_match
from surestep_ocp.cli import main
from surestep_ocp.output.certificate import FEASIBLE, INFEASIBLE, OPTIMAL
from surestep_ocp.output.solution import Solution
from surestep_ocp.ocp.certificate import NOT_CERTIFIED, certify, judge
from surestep_ocp.methods.registry import run_method


@pytest.fixture(scope="module")
def ocp(default_setup):
    return run_method(default_setup, "ocp")


def _moved(sol: Solution, t: int, j: int, by: float) -> Solution:
    """A copy of `sol` with joint j of waypoint t moved by `by` (no reported trace: it was the
    plan's before the move)."""
    d = Solution.from_dict(sol.to_dict())
    q = [list(qi) for qi in d.q]
    q[t][j] += by
    return replace(d, run=replace(d.run, ocp_trace_final=None), q=q)


def test_the_optimum_is_certified_and_its_trace_is_the_textbook_ekfs(default_setup, ocp):
    c = ocp.certificate
    assert ocp.success and c.level == OPTIMAL and not c.failures()
    assert ocp.backend_status == ocp.status == "Solve_Succeeded"
    # the planning model's trace by tests/numpy_ekf.py along the plan's poses
    sig, _ = ref.propagate(np.asarray(ocp.poses), default_setup.ocp.noise,
                           default_setup.ocp.intrinsics, default_setup.model.components,
                           guard=default_setup.ocp.noise.cosine_guard ** 2)
    assert ref.rel_err(c.trace, np.trace(sig[-1])) < 1e-9
    assert c.terminal_position_m < 1e-9 and c.terminal_angle_rad < 1e-9


def test_stationarity_agrees_with_finite_differences(default_setup, ocp):
    """The reverse-mode gradient's stationarity against central differences of the NumPy EKF, at
    the optimum and at a point off it."""
    for sol in (ocp, _moved(ocp, 7, 1, 2e-3)):
        a = certify(default_setup, sol)
        b = certify(default_setup, sol, fd_step=1e-6)
        assert abs(a.stationarity - b.stationarity) <= 1e-7 + 1e-5 * b.stationarity
        assert a.level == b.level


def test_a_plan_off_the_optimum_is_not_certified(default_setup, ocp):
    off = certify(default_setup, _moved(ocp, 7, 1, 2e-3))
    assert off.level == FEASIBLE and off.stationarity > 1e-3
    assert [line.split(":")[0] for line in off.failures()] == ["stationarity"]
    # the last waypoint moved: the terminal pose is missed
    miss = certify(default_setup, _moved(ocp, ocp.horizon, 0, 1e-3))
    assert miss.level == INFEASIBLE
    assert "terminal position" in [line.split(":")[0] for line in miss.failures()]
    # a reported trace that is not the plan's
    wrong = _moved(ocp, 7, 1, 0.0)
    wrong = replace(wrong, run=replace(wrong.run,
                                       ocp_trace_final=ocp.run.ocp_trace_final * (1 + 1e-4)))
    lines = certify(default_setup, wrong).failures()
    assert [line.split(":")[0] for line in lines] == ["trace"]


def test_a_backend_success_without_a_certificate_is_not_a_success(default_setup, ocp):
    claimed = _moved(ocp, 7, 1, 2e-3)
    claimed = judge(default_setup, claimed)
    assert not claimed.success and claimed.status == NOT_CERTIFIED
    assert claimed.backend_status == "Solve_Succeeded" and claimed.backend_success
    # the gradient variant claims a completed run, not an optimum: its success stays its own
    grad = run_method(default_setup, "gradient")
    assert grad.success and grad.status.startswith("completed")
    assert grad.certificate.level == FEASIBLE


def test_the_certificate_is_in_the_solution_file(ocp, tmp_path):
    path = ocp.save(tmp_path / "ocp.json")
    back = Solution.load(path)
    assert back.certificate == ocp.certificate and back.backend_status == ocp.backend_status
    # a file written before certificates loads, without one
    d = ocp.to_dict()
    for key in ("certificate", "backend_status", "backend_success"):
        d.pop(key)
    old = Solution.from_dict(d)
    assert old.certificate is None and old.backend_status is None
    assert "certificate" not in old.extras


def test_check_command(ocp, tmp_path, capsys):
    good = ocp.save(tmp_path / "ocp.json")
    assert main(["check", str(good)]) == 0
    assert "certified optimal (recomputed from" in capsys.readouterr().out
    bad = _moved(ocp, 7, 1, 2e-3)
    bad.save(tmp_path / "moved.json")
    assert main(["check", str(tmp_path / "moved.json")]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith("not certified (feasible; recomputed from "
                           f"{ocp.problem}):")
    assert [line.strip().split(":")[0] for line in out[1:]] == ["stationarity", "success"]
    # the recorded certificate when the problem file is gone
    d = ocp.to_dict()
    d["problem"] = str(tmp_path / "gone.yaml")
    d["certificate"] = replace(ocp.certificate, stationarity=0.5).to_json()
    Solution.from_dict(d).save(tmp_path / "recorded.json")
    assert main(["check", str(tmp_path / "recorded.json")]) == 1
    out = capsys.readouterr().out
    assert "the recorded certificate" in out and "stationarity: 0.5" in out
    (tmp_path / "not.json").write_text('{"q": 1}')
    assert main(["check", str(tmp_path / "not.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "not.json" in err and "Traceback" not in err


# What makes the certificate cheap (docs/certificate.md, "What it costs") changes none of its
# measures: the compiled Function against the interpreted one and central differences, the
# non-diagonal EKF against the textbook one, the multipliers' NNLS against a bounded least squares
# over all of them, the tool rows' gradients against differences of their values.


def test_the_compiled_certificate_is_the_interpreted_ones_and_the_differences(default_setup, ocp):
    from surestep_ocp.ocp import certificate as cm
    from surestep_ocp.ocp.codegen import available

    # a structure of its own (smoothness is in its key): interpreted at first, compiled at its
    # COMPILE_AFTER-th certificate
    setup = default_setup.with_ocp(smoothness=default_setup.ocp.smoothness + 1e-3)
    holder = cm._function(setup, [0.0])
    assert holder.uses == 0 and cm.COMPILE_AFTER > 1
    sol = _moved(ocp, 7, 1, 2e-3)
    first = certify(setup, sol)
    while holder.uses < cm.COMPILE_AFTER - 1:
        assert not holder.compiled
        certify(setup, sol)
    assert not holder.compiled
    second = certify(setup, sol)
    if available() and holder.note is None:
        assert holder.compiled
    fd = certify(setup, sol, fd_step=1e-6)
    for c in (first, second):
        assert abs(c.stationarity - fd.stationarity) <= 1e-7 + 1e-5 * fd.stationarity
        assert c.level == fd.level == FEASIBLE
    for name in ("terminal_position_m", "terminal_angle_rad", "stationarity", "trace",
                 "trace_error", "complementarity"):
        a, b = getattr(first, name), getattr(second, name)
        assert abs(a - b) <= 1e-12 * max(abs(a), 1e-12), name


@pytest.mark.parametrize("family", ["correlated", "joint-space"])
def test_a_non_diagonal_models_trace_is_the_textbook_ekfs(default_setup, ocp, family):
    """The Joseph-form 6x6 pass (not the six scalar filters) against tests/numpy_ekf.py, the
    joint-space term by its central-difference Jacobian; stationarity against differences."""
    noise = default_setup.ocp.noise
    if family == "correlated":
        V = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
        V[0, 2] = V[2, 0] = 2e-2
        noise = replace(noise, V_d0=V)
    else:
        noise = replace(noise, joint_sigma=(0.05, 0.05, 0.02, 0.05, 0.05, 0.05, 0.0))
    setup = default_setup.with_ocp(noise=noise)
    sol = _moved(ocp, 7, 1, 2e-3)
    c = certify(setup, sol)
    q = np.asarray(sol.q, float)
    extra = None
    if family == "joint-space":
        extra = [ref.joint_motion_noise(setup.robot, setup.T_cam_base, q[t], q[t + 1],
                                        noise.joint_sigma) for t in range(len(q) - 1)]
    sig, pred = ref.propagate(setup.poses_of(q), setup.ocp.noise, setup.ocp.intrinsics,
                              setup.model.components, guard=noise.cosine_guard ** 2,
                              extra_W=extra)
    last = pred[-1] if setup.model.noise.objective == "predicted" else sig[-1]
    assert ref.rel_err(c.trace, np.trace(last)) < (1e-9 if extra is None else 1e-8)
    fd = certify(setup, sol, fd_step=1e-6)
    assert abs(c.stationarity - fd.stationarity) <= 1e-7 + 1e-5 * fd.stationarity


def test_the_multipliers_are_the_bounded_least_squares_over_all_of_them():
    """`_multipliers` (NNLS on what the terminal rows' span leaves, over the touched rows, with the
    complementarity rows `slack * nu`) against scipy's BVLS over (lam free, nu >= 0) at once on
    the stacked KKT residual: the same residual (unique) and minimum, with duplicated and
    rank-deficient columns, rows at their bound (slack 0) and rows away from it."""
    from scipy.optimize import lsq_linear

    from surestep_ocp.ocp.certificate import _multipliers

    rng = np.random.default_rng(3)
    for trial in range(20):
        n, k, m, start = 60, 6, 25, 54
        B_E = rng.normal(size=(k, 7))
        if trial % 3 == 0:
            B_E[:, 6] = B_E[:, 5]  # rank-deficient terminal rows
        B_A = rng.normal(size=(n, m)) * (rng.random((n, m)) < 0.1)
        B_A[:, 1] = B_A[:, 0]  # a duplicated active row
        B_A[start:, 2] = rng.normal(size=k)  # one acting on the last node
        slack = np.where(rng.random(m) < 0.5, 0.0, 10.0 ** rng.uniform(-4, 0, m))
        g = rng.normal(size=n)
        lam, nu, r = _multipliers(g, B_A, B_E, start, slack)
        full = np.hstack([np.vstack([np.zeros((start, 7)), B_E]), B_A])
        assert np.all(nu >= 0)
        np.testing.assert_allclose(r, g + full @ np.concatenate([lam, nu]), atol=1e-12)
        lb = np.concatenate([np.full(7, -np.inf), np.zeros(m)])
        stacked = np.vstack([full, np.hstack([np.zeros((m, 7)), np.diag(slack)])])
        x = lsq_linear(stacked, np.concatenate([-g, np.zeros(m)]), bounds=(lb, np.inf),
                       method="bvls", tol=1e-14).x
        np.testing.assert_allclose(r, g + full @ x, atol=1e-8)
        np.testing.assert_allclose(slack * nu, slack * x[7:], atol=1e-8)


def test_the_tool_rows_gradients_are_their_differences(default_setup, ocp):
    """Within enforced limits at a pace the plan breaks (many rows active): the tool rows'
    gradients (assembled over all points at once) against central differences of their values,
    and the certificate's stationarity against differences of the NumPy EKF."""
    from surestep_ocp.problem.spec import LimitsSpec
    from surestep_ocp.ocp.certificate import _Rows

    setup = default_setup.with_ocp(limits=LimitsSpec(enforce=True),
                                   timing=replace(default_setup.ocp.timing, step_s=0.05))
    sol = _moved(ocp, 7, 1, 0.0)
    c = certify(setup, sol)
    assert c.level == INFEASIBLE and c.limit_violation > 0 and c.active_rows > 10
    fd = certify(setup, sol, fd_step=1e-6)
    assert abs(c.stationarity - fd.stationarity) <= 1e-7 + 1e-5 * fd.stationarity
    rows = _Rows(setup)
    q = np.asarray(sol.q, float)
    lin, tool, Jz = rows.values(q, False, [0.0])
    np.testing.assert_allclose(lin, rows.A @ q.ravel() + rows.a, atol=1e-12)
    assert_tool_gradients_match(rows, q)


@pytest.fixture(scope="module")
def near_rows_plan():
    """IPOPT's plan of the evaluation's configuration 2 within the default limits enforced at
    0.05 s per step over 40 steps (benchmarks/certificate.py's `limits` family), interpreted: IPOPT
    says Solve_Succeeded with limit rows 1e-4 to 1e-2 from their bound carrying multipliers."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
    from surestep_ocp.problem.setup import build_setup
    from surestep_ocp.problem.spec import LimitsSpec, TimingSpec

    smp = ConfigurationSampler(load_evaluation("problems/evaluations/evaluation.yaml"))
    p = smp.problem(smp.sample(0, 2))
    p = replace(p, horizon=40, limits=LimitsSpec(enforce=True),
                timing=TimingSpec(step_s=0.05, tracker_hz=20.0))
    setup = build_setup(replace(p, solver=replace(p.solver, name="ipopt", codegen=False)))
    return setup, run_method(setup, "ocp")


def _descent(setup, sol) -> float:
    """How much the interior-point method (not the certificate's code) lowers the objective
    (1 at the start, plus the smoothness term; the trace by the certificate's NumPy EKF) from the
    plan's joints."""
    from surestep_ocp.methods.ocp import solve_ocp
    from surestep_ocp.ocp.iterate import InitialGuess

    setup = setup.with_ocp(solver=replace(setup.ocp.solver, name="interior"))
    out = solve_ocp(setup, InitialGuess(np.asarray(sol.q, float), "the plan"))
    assert out.success

    def f(plan):
        q = np.asarray(plan.q, float)
        return (certify(setup, plan).trace / sol.run.initial_trace
                + setup.ocp.smoothness * float(np.sum(np.diff(q, axis=0) ** 2)))

    return f(sol) - f(out)


def test_rows_near_their_bound_carry_multipliers_by_complementarity(near_rows_plan, monkeypatch):
    """The active set chosen by complementarity: IPOPT's plan with rows 1e-4 to 1e-2 from their
    bound is certified (by the rows within 1e-4 alone it was only feasible), as the interior-point
    method from it confirms (no lower objective beyond solver.tol), its stationarity the same with
    the gradient by finite differences of the NumPy EKF. The same plan under another objective
    (a smoothness term) is feasible, not certified, and the interior-point method lowers it."""
    import surestep_ocp.ocp.certificate as cert_module

    setup, sol = near_rows_plan
    tol = setup.ocp.solver.tol
    c = certify(setup, sol)
    assert sol.backend_status == "Solve_Succeeded" and c.certified, c
    assert c.complementarity <= c.tolerances.complementarity
    fd = certify(setup, sol, fd_step=1e-6)
    assert fd.level == c.level
    assert abs(c.stationarity - fd.stationarity) <= 1e-7 + 1e-4 * fd.stationarity
    assert _descent(setup, sol) <= tol
    with monkeypatch.context() as m:  # the rows that decide it are beyond 1e-4
        m.setattr(cert_module, "WINDOW", 1e-4)
        assert certify(setup, sol).level == FEASIBLE
    smooth = setup.with_ocp(smoothness=0.1)
    c_off = certify(smooth, sol)
    assert c_off.level == FEASIBLE and certify(smooth, sol, fd_step=1e-6).level == FEASIBLE
    assert _descent(smooth, sol) > 100 * tol
