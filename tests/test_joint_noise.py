"""Joint-space motion noise `W_q = J diag(sigma^2 dq^2) J^T` (noise.joint_motion_sigma).

References independent of the package's CasADi code: the Jacobian by central differences of
Pinocchio's forward kinematics (scipy's rotation vector), the EKF in plain NumPy
(tests/numpy_ekf.py); the Newton plan against IPOPT on the exact-Hessian NLP (another solver on
another derivative path).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from numpy_ekf import joint_motion_noise, propagate

from surestep_ocp.errors import ProblemError, SurestepError
from surestep_ocp.model.belief import COSINE_GUARD, unvech
from surestep_ocp.comparison import run_comparison
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.methods.registry import ocp_initial_guess, run_method
from surestep_ocp.methods.ocp import solve_ocp

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "problems" / "needle_regrasp_paper_pace.yaml"
SIGMA = (0.05, 0.05, 0.02, 0.05, 0.05, 0.05, 0.0)  # per joint; the jaw moves nothing


def problem(horizon: int, sigma=SIGMA, solver: str = "auto", hessian: str = "auto", **noise):
    prob = load_problem(DEFAULT)
    return replace(prob, horizon=horizon,
                   noise=replace(prob.noise, joint_sigma=tuple(sigma), **noise),
                   solver=replace(prob.solver, name=solver, hessian=hessian))


def numpy_reference(setup, q):
    """Posterior covariances of the NumPy EKF along the joints q, with the joint-space term by
    differences."""
    q = np.asarray(q, float)
    poses = np.array([setup.pose_of(qi) for qi in q])
    extra = [joint_motion_noise(setup.robot, setup.T_cam_base, q[t], q[t + 1],
                                setup.ocp.noise.joint_sigma)
             for t in range(len(q) - 1)]
    sig, _ = propagate(poses, setup.ocp.noise, setup.ocp.intrinsics,
                       guard=COSINE_GUARD, extra_W=extra)
    return sig


def test_joint_noise_matches_finite_differences_of_pinocchio():
    """W_q of the package (the tangent Jacobian of the NLP's mean, from the FK quaternion) equals J
    D J^T with J by central differences of Pinocchio's FK in the tangent (left perturbations), at
    random joint pairs over the whole joint box: rotations of any angle, pi and beyond included
    (no chart)."""
    setup = build_setup(problem(4))
    rng = np.random.default_rng(3)
    lo, hi = setup.robot.lower, setup.robot.upper
    q = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), (40, setup.robot.nq))
    W = setup.joint_noises(q)
    angles = np.linalg.norm(setup.poses_of(q)[:, 3:], axis=1)
    assert angles.max() > np.pi  # rotations past the cut are among them
    for t in range(len(q) - 1):
        ref = joint_motion_noise(setup.robot, setup.T_cam_base, q[t], q[t + 1],
                                 setup.ocp.noise.joint_sigma)
        got = unvech(W[t])
        assert np.max(np.abs(got - ref)) <= 1e-7 * np.max(np.abs(ref)), t
        assert np.min(np.linalg.eigvalsh(got)) >= -1e-15 * np.max(np.abs(ref))  # PSD
        # not diagonal in the camera frame
        assert abs(got[0, 1]) + abs(got[0, 2]) + abs(got[3, 4]) > 0


def test_propagate_with_joint_noise_equals_numpy_ekf_and_raises_the_trace():
    setup = build_setup(problem(10))
    q = setup.joint_line(10)
    poses = np.array([setup.pose_of(qi) for qi in q])
    sig, _ = setup.model.propagate(poses, joint=setup.joint_noises(q))
    ref = numpy_reference(setup, q)
    assert np.max(np.abs(sig - ref)) <= 1e-9 * np.max(np.abs(ref))
    plain = build_setup(problem(10, sigma=(0.0,) * 7))
    assert not plain.model.joint_noise
    sig0, _ = plain.model.propagate(poses)
    assert np.trace(sig[-1]) > np.trace(sig0[-1]) * (1 + 1e-6)
    with pytest.raises(ValueError):  # never dropped silently
        setup.model.propagate(poses)


@pytest.mark.parametrize("horizon", [6, 10])
def test_newton_plan_with_joint_noise_equals_ipopt_exact_and_the_numpy_ekf(horizon):
    """The default strategy (Newton on the surrogate with the matrix weight dS/dW_q) and IPOPT with
    the exact Hessian of the unrolled 6x6 EKF (no surrogate, no Newton) reach the same optimum; the
    solution's trace is the NumPy EKF's along the plan's joints."""
    setup = build_setup(problem(horizon))
    assert setup.model.structured and not setup.model.scalar
    init = ocp_initial_guess(setup)
    sol = solve_ocp(setup, init)
    assert sol.success and sol.run.solver == "newton", sol.run.hessian
    assert sol.trace_final == pytest.approx(np.trace(numpy_reference(setup, sol.q)[-1]), rel=1e-9)
    assert sol.trace_final < sol.run.initial_trace
    exact = build_setup(problem(horizon, solver="ipopt", hessian="exact"))
    ref = solve_ocp(exact, init)
    assert ref.success and ref.run.solver == "ipopt", ref.run.hessian
    assert sol.trace_final == pytest.approx(ref.trace_final, rel=1e-6)
    assert sol.noise["joint_motion_sigma"] == list(SIGMA)


def test_ipopt_gauss_newton_hessian_reaches_the_same_optimum():
    setup = build_setup(problem(6))
    init = ocp_initial_guess(setup)
    newton = solve_ocp(setup, init)
    gn = solve_ocp(build_setup(problem(6, solver="ipopt", hessian="gauss-newton")), init)
    assert gn.success and gn.run.hessian.startswith("gauss-newton"), gn.run.hessian
    assert gn.trace_final == pytest.approx(newton.trace_final, rel=1e-6)


def test_methods_without_joints_refuse_joint_noise():
    setup = build_setup(problem(4))
    with pytest.raises(SurestepError, match="joint_motion_sigma"):
        run_method(setup, "gradient")
    with pytest.raises(SurestepError, match="joint_motion_sigma"):
        run_comparison(setup, ("ocp", "gradient-no-pose-loss"))
    from surestep_ocp.evaluation.rollout import rollout

    with pytest.raises(SurestepError, match="joint_motion_sigma"):  # would sample without the term
        rollout(setup.eval_model, np.array([setup.x_start, setup.x_goal]), n=2)
    base = run_method(setup, "baseline")  # the straight line has joints: evaluated with the term
    assert base.trace_final == pytest.approx(np.trace(numpy_reference(setup, base.q)[-1]), rel=1e-9)


def test_bad_joint_motion_sigma_is_a_one_line_error(tmp_path):
    raw = yaml.safe_load(DEFAULT.read_text())
    cases = {"[0.1, 0.1]": "expected one number or 7", "-0.1": "noise.joint_motion_sigma",
             "[]": "empty", "[0.1, 0.1, 0.1, 0.1, 0.1, 0.1, x]": "noise.joint_motion_sigma[6]",
             "2.0": "noise.joint_motion_sigma"}
    for text, message in cases.items():
        raw["noise"] = {**raw.get("noise", {}), "joint_motion_sigma": yaml.safe_load(text)}
        f = tmp_path / "bad.yaml"
        f.write_text(yaml.safe_dump(raw))
        with pytest.raises(ProblemError, match=message.replace("[", r"\[").replace("]", r"\]")):
            build_setup(load_problem(f))
        r = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "validate", str(f)],
                           capture_output=True, text=True)
        assert (r.returncode == 2 and "Traceback" not in r.stderr
                and len(r.stderr.strip().splitlines()) == 1), r.stderr
