"""Belief-aware observation noise (`observation_noise: expected`, method note section 8)."""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np
import pytest

from surestep_ocp.model.belief import BeliefModel, NoiseParams, vech
from surestep_ocp.model.camera import Intrinsics
from surestep_ocp.model.lie import np_means, pose_mean

CAMERA = Intrinsics(fx=768.98551924, fy=768.98551924, cx=292.8861567, cy=291.61479526, width=640, height=480)
X = np.array([0.03, -0.02, 0.12, 0.5, 0.3, 1.4])  # a tool pose off the ideal one [m, rad]
MX_ = np_means(X)[0]  # its mean (position, quaternion), what the model's Functions take


def model(form: str, components=("depth", "fov", "orientation")) -> BeliefModel:
    return BeliefModel(replace(NoiseParams(o_star=(0.4, 0.4, 1.53)), observation_noise=form), CAMERA, components)


def random_spd(rng, scale: float) -> np.ndarray:
    A = rng.normal(size=(6, 6))
    return scale * (A @ A.T / 6 + 0.1 * np.eye(6))


def test_zero_covariance_gives_the_papers_form():
    """With Sigma^- = 0 the expected form equals the paper's form exactly."""
    V_exp = np.asarray(model("expected").planning_noise(MX_, np.zeros(21)))
    V_mean = np.asarray(model("mean").observation_noise(MX_))
    assert np.array_equal(V_exp, V_mean)


def test_mean_form_ignores_the_belief():
    """The paper's form (default) does not depend on the predicted covariance."""
    rng = np.random.default_rng(1)
    P = random_spd(rng, 1e-4)
    m = model("mean")
    assert np.array_equal(np.asarray(m.planning_noise(MX_, vech(P))), np.asarray(m.observation_noise(MX_)))


def test_expected_depth_term_equals_monte_carlo():
    """E[(z - d*)^2] under N(mu, P) equals the Monte-Carlo average (closed form; 200k samples, 1 %)."""
    rng = np.random.default_rng(0)
    P = random_spd(rng, 4e-4)
    m = model("expected", components=("depth",))
    coef = float(np.asarray(m.planning_noise(MX_, vech(P)))[0, 0] / m.noise.V_d0[0, 0])
    z = rng.multivariate_normal(X, P, size=200_000)[:, 2]
    mc = float(np.mean((z - m.noise.depth_star) ** 2))
    assert coef == pytest.approx((X[2] - 0.15) ** 2 + P[2, 2], rel=1e-12)
    assert coef == pytest.approx(mc, rel=0.01)


def test_expected_fov_term_matches_monte_carlo_for_small_spread():
    """The first-order FOV expectation agrees with sampling when the spread is small (2 %)."""
    rng = np.random.default_rng(2)
    P = random_spd(rng, 2e-6)
    m = model("expected", components=("fov",))
    coef = float(np.asarray(m.planning_noise(MX_, vech(P)))[0, 0] / m.noise.V_f0[0, 0])
    s = rng.multivariate_normal(X, P, size=200_000)
    du = s[:, 0] / s[:, 2] + (CAMERA.cx - CAMERA.width / 2) / CAMERA.fx
    dv = s[:, 1] / s[:, 2] + (CAMERA.cy - CAMERA.height / 2) / CAMERA.fy
    assert coef == pytest.approx(float(np.mean(du**2 + dv**2)), rel=0.02)


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
def test_expected_orientation_term_is_taken_in_the_tangent(formula):
    """The orientation term's spread `tr(J P_rr J^T)` uses the Jacobian in the covariance's coordinates, the
    tangent of left perturbations `exp(e) R` (as the rollouts draw them): checked against central differences
    of the independent NumPy residual (tests/numpy_ekf.py) along scipy rotations, at a large angle (2.7 rad)
    where the axis-angle chart's Jacobian differs from the tangent's."""
    import numpy_ekf as ref
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    P = random_spd(rng, 1e-4)
    x = np.r_[X[:3], 2.7 * np.array([0.6, -0.48, 0.64])]
    m = BeliefModel(replace(NoiseParams(o_star=(0.4, 0.4, 1.53), orientation_formula=formula),
                            observation_noise="expected"), CAMERA, ("orientation",))
    spread = float(np.asarray(m.planning_noise(np_means(x)[0], vech(P)) - m.observation_noise(np_means(x)[0]))[0, 0])
    noise = replace(m.noise, V_o0=np.eye(6))

    def e(R):  # the residual 1 - cos (>= 0) of the NumPy formula
        V = ref.observation_noise(np.r_[x[:3], R.as_rotvec()], noise, CAMERA, ("orientation",), formula,
                                  guard=noise.cosine_guard**2, band=noise.cut_band)
        return float(np.sqrt(V[0, 0]))

    R, h = Rotation.from_rotvec(x[3:]), 1e-6
    J = np.array([(e(Rotation.from_rotvec(h * u) * R) - e(Rotation.from_rotvec(-h * u) * R)) / (2 * h)
                  for u in np.eye(3)])
    expected = float(J @ P[3:, 3:] @ J) * m.noise.V_o0[0, 0]
    assert spread == pytest.approx(expected, rel=1e-6)


def test_expected_step_gradient_matches_finite_differences():
    """The planner's EKF step with expected noise has correct derivatives (central differences, 1e-6)."""
    m = model("expected")
    x0 = ca.SX.sym("x0", 6)
    x1 = ca.SX.sym("x1", 6)
    s = ca.SX.sym("s", 21)
    out = ca.sum1(m.step_expr(pose_mean(x0), pose_mean(x1), s)[[0, 6, 11, 15, 18, 20]])  # trace of the posterior
    f = ca.Function("f", [x0, x1, s], [out])
    g = ca.Function("g", [x0, x1, s], [ca.gradient(out, x1)])
    rng = np.random.default_rng(3)
    a = X - np.array([0.01, 0.0, 0.01, 0.1, 0.0, 0.0])
    S0 = vech(random_spd(rng, 1e-4))
    grad = np.asarray(g(a, X, S0)).ravel()
    h = 1e-6
    fd = np.array([(float(f(a, X + h * e, S0)) - float(f(a, X - h * e, S0))) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-12 * np.abs(fd).max())


def test_expected_noise_never_vanishes_while_uncertain():
    """At the ideal pose the paper's V is zero; the expected V is not, while the belief is uncertain."""
    ideal = np.array([-(CAMERA.cx - 320) / CAMERA.fx * 0.15, -(CAMERA.cy - 240) / CAMERA.fy * 0.15, 0.15,
                      0.4, 0.4, 1.53])
    P = 1e-4 * np.eye(6)
    ideal = np_means(ideal)[0]
    v_mean = np.trace(np.asarray(model("mean").observation_noise(ideal)))
    assert v_mean < 1e-8  # zero up to the cosine formula's guard at r = 0
    assert np.trace(np.asarray(model("expected").planning_noise(ideal, vech(P)))) > 1e3 * v_mean


@pytest.fixture(scope="module")
def predicted_setup():
    from pathlib import Path

    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    p = load_problem(Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml")
    return build_setup(replace(p, horizon=6, noise=replace(p.noise, objective="predicted")))


@pytest.mark.parametrize("method", ["gradient-no-pose-loss", "ocp"])
def test_predicted_objective_is_the_covariance_before_the_last_update(predicted_setup, method):
    """`objective.covariance: predicted` minimises Tr(Sigma_T|T-1), as the exact EKF computes it."""
    from surestep_ocp.solvers.methods import run_method

    sol = run_method(predicted_setup, method)
    _, pred = predicted_setup.eval_model.propagate(np.array(sol.poses))
    assert sol.objective == pytest.approx(np.trace(pred[-1]), rel=1e-6)


def test_unknown_objective_is_a_problem_error(tmp_path):
    """objective.covariance only takes posterior or predicted; anything else names the key."""
    from pathlib import Path

    from surestep_ocp.errors import ProblemError
    from surestep_ocp.problem.load import load_problem

    text = (Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml").read_text()
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace("  smoothness: 0.0", "  smoothness: 0.0\n  covariance: prior"))
    with pytest.raises(ProblemError, match="objective.covariance"):
        load_problem(path)
