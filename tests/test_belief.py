"""The CasADi belief model (surestep_ocp.model.belief) against a plain NumPy EKF
(tests/numpy_ekf.py).

The NumPy EKF is written from surestep_method.md sections 3-4 only; it shares no
code with the package (rotations from scipy, textbook EKF step).
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import casadi as ca
import numpy as np
import numpy_ekf as ref
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.model.belief import (
    COSINE_GUARD,
    COMPONENTS,
    NV,
    BeliefModel,
    NoiseParams,
    entropy,
    trace_vech,
    unvech,
    vech,
)
from surestep_ocp.model.camera import Intrinsics
from surestep_ocp.model.lie import np_means, pose_mean


def mean(x):
    """The model's mean (position, quaternion) of a pose (position, rotation vector)."""
    return np_means(x)[0]


CAMERA = Intrinsics(
    fx=768.98551924, fy=768.98551924, cx=292.8861567, cy=291.61479526, width=640, height=480
)
O_STAR = (0.40, 0.40, 1.53)
# [rad^2] the package's guard of |r| in the cosine formula (section 4: "guard it")
GUARD = COSINE_GUARD
REL = 1e-12
# Random non-identity H, F (condition numbers ~10) amplify either EKF's rounding (solve vs inv).
REL_JAC = 1e-11
T = 10


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """A tool pose in front of the camera, roughly inside the field of view, any orientation."""
    z = rng.uniform(0.05, 0.25)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return np.r_[
        rng.uniform(-0.4, 0.4) * z, rng.uniform(-0.3, 0.3) * z, z, rng.uniform(0.1, 3.0) * axis
    ]


def random_trajectory(rng: np.random.Generator, n: int = T + 1) -> np.ndarray:
    return np.array([random_pose(rng) for _ in range(n)])


def random_spd(rng: np.random.Generator, scale: float) -> np.ndarray:
    A = rng.normal(size=(6, 6))
    return scale * (A @ A.T / 6 + 0.1 * np.eye(6))


def random_noise(rng: np.random.Generator, formula: str = "cosine") -> NoiseParams:
    return NoiseParams(
        W_p0=random_spd(rng, 1e-3),
        W_o0=random_spd(rng, 1e-3),
        V_d0=random_spd(rng, 1e-1),
        V_f0=random_spd(rng, 1e-2),
        V_o0=random_spd(rng, 5e-3),
        Sigma0=random_spd(rng, 1e-2),
        o_star=O_STAR,
        orientation_formula=formula,
    )


def assert_matches(
    model: BeliefModel, poses: np.ndarray, components=COMPONENTS, jacobians=None, rel=REL
):
    sig, pred = model.propagate(poses)
    sig_ref, pred_ref = ref.propagate(
        poses, model.noise, CAMERA, components, jacobians=jacobians, guard=GUARD
    )
    assert sig.shape == (len(poses), 6, 6) and pred.shape == (len(poses) - 1, 6, 6)
    for t in range(len(poses)):
        assert ref.rel_err(sig[t], sig_ref[t]) < rel, f"Sigma_{t}|{t}"
    for t in range(len(poses) - 1):
        assert ref.rel_err(pred[t], pred_ref[t]) < rel, f"Sigma_{t + 1}|{t}"


# ------------------------------------------------------------------ noise models


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
def test_noise_models_match_numpy(formula):
    """W and V, the inputs of every EKF step, follow the formulas of section 4 term by term."""
    rng = np.random.default_rng(1)
    noise = random_noise(rng, formula)
    model = BeliefModel(noise, CAMERA)
    for _ in range(20):
        x0, x1 = random_pose(rng), random_pose(rng)
        W = np.asarray(model.motion_noise(mean(x0), mean(x1)))
        assert ref.rel_err(W, ref.motion_noise(x0, x1, noise)) < REL
        V = np.asarray(model.observation_noise(mean(x1)))
        assert (
            ref.rel_err(V, ref.observation_noise(x1, noise, CAMERA, COMPONENTS, formula, GUARD,
                                                 noise.cut_band))
            < REL
        )


def test_motion_noise_uses_geodesic_angle():
    """The orientation step is the geodesic angle, not |r1 - r0| (they differ past the pi wrap)."""
    noise = NoiseParams(W_p0=np.zeros((6, 6)), W_o0=np.eye(6))
    model = BeliefModel(noise, CAMERA)
    axis = np.array([0.0, 0.0, 1.0])
    x0, x1 = (
        np.r_[0, 0, 0.1, 3.0 * axis],
        np.r_[0, 0, 0.1, -3.0 * axis],
    )  # 2*pi - 6 rad apart, |dr| = 6
    W = np.asarray(model.motion_noise(mean(x0), mean(x1)))
    assert W[0, 0] == pytest.approx((2 * np.pi - 6.0) ** 2, rel=1e-12)


def test_fov_noise_is_zero_at_image_centre_and_depth_at_d_star():
    """The ideal pose (image centre, depth d*, r parallel to o*) has zero observation noise.

    Exactly zero with the geodesic orientation formula; with the paper's cosine formula zero
    up to its guard at r = 0, i.e. (1 - 1/sqrt(1 + g/|r|^2))^2 V_o0.
    """
    noise = NoiseParams(o_star=O_STAR, orientation_formula="geodesic")
    model = BeliefModel(noise, CAMERA)
    z = noise.depth_star
    p = np.array(
        [
            (CAMERA.width / 2 - CAMERA.cx) / CAMERA.fx * z,
            (CAMERA.height / 2 - CAMERA.cy) / CAMERA.fy * z,
            z,
        ]
    )
    x = np.r_[p, np.array(O_STAR)]
    assert np.abs(np.asarray(model.observation_noise(mean(x)))).max() < 1e-20
    cosine = BeliefModel(NoiseParams(o_star=O_STAR), CAMERA)
    r2 = float(np.dot(O_STAR, O_STAR))
    expected = (1 - 1 / np.sqrt(1 + COSINE_GUARD / r2)) ** 2 * cosine.noise.V_o0
    np.testing.assert_allclose(np.asarray(cosine.observation_noise(mean(x))), expected, rtol=1e-6,
                               atol=1e-30)


def test_cosine_formula_guarded_at_zero_rotation():
    """The paper's cosine is undefined at r = 0: the guarded value and its gradient are finite."""
    model = BeliefModel(NoiseParams(o_star=O_STAR), CAMERA)
    x = ca.SX.sym("x", 6)
    V = model.observation_noise(pose_mean(x))
    f = ca.Function("f", [x], [V[0, 0], ca.gradient(V[0, 0], x)])
    v, g = f(np.r_[0.01, 0.0, 0.15, 0.0, 0.0, 0.0])
    assert np.isfinite(float(v)) and np.all(np.isfinite(np.asarray(g)))
    # far from zero the guard is small: the paper's formula without any guard, within 0.5 %
    x1 = np.r_[0.01, 0.0, 0.15, 0.9, -0.6, 1.5]
    V_ref = ref.observation_noise(x1, model.noise, CAMERA, guard=0.0, band=model.noise.cut_band)
    assert ref.rel_err(np.asarray(model.observation_noise(mean(x1))), V_ref) < 5e-3


def test_tiny_rotation_along_o_star_does_not_zero_the_orientation_noise():
    """Near r = 0 the direction of r is free; the guard keeps a 1e-4 rad turn about o* from looking
    ideal."""
    model = BeliefModel(NoiseParams(o_star=O_STAR), CAMERA, components=("orientation",))
    axis = np.asarray(O_STAR) / np.linalg.norm(O_STAR)
    V_tiny = float(np.asarray(
        model.observation_noise(mean(np.r_[0.0, 0.0, 0.15, 1e-4 * axis])))[0, 0])
    assert V_tiny > 0.99 * model.noise.V_o0[0, 0]


# ------------------------------------------------------------------ EKF along trajectories


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_propagate_matches_numpy_ekf_paper_constants(seed, formula):
    """ML covariances along random trajectories equal the textbook EKF (paper's constants)."""
    rng = np.random.default_rng(100 + seed)
    noise = dataclasses.replace(NoiseParams(o_star=O_STAR), orientation_formula=formula)
    assert_matches(BeliefModel(noise, CAMERA), random_trajectory(rng))


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_propagate_matches_numpy_ekf_random_spd_constants(seed, formula):
    """Full (non-diagonal) SPD base covariances are carried correctly, not just multiples of I."""
    rng = np.random.default_rng(200 + seed)
    noise = random_noise(rng, formula)
    assert_matches(BeliefModel(noise, CAMERA), random_trajectory(rng))


@pytest.mark.parametrize("off", COMPONENTS)
def test_propagate_with_component_switched_off(off):
    """Ablations (section 4) drop exactly one observation term and nothing else."""
    rng = np.random.default_rng(300 + COMPONENTS.index(off))
    comps = tuple(c for c in COMPONENTS if c != off)
    for noise in (NoiseParams(o_star=O_STAR), random_noise(rng)):
        model = BeliefModel(noise, CAMERA).with_components(comps)
        assert model.components == comps
        assert_matches(model, random_trajectory(rng), components=comps)


@pytest.mark.parametrize("only", COMPONENTS)
def test_propagate_with_a_single_component(only):
    """Each observation term on its own also matches (no cross-talk between the terms)."""
    rng = np.random.default_rng(400 + COMPONENTS.index(only))
    model = BeliefModel(random_noise(rng), CAMERA, components=(only,))
    assert_matches(model, random_trajectory(rng), components=(only,))


def test_unknown_component_rejected():
    """A misspelt ablation must not silently become 'no component'."""
    with pytest.raises(ValueError, match="fov"):
        BeliefModel(NoiseParams(), CAMERA, components=("depth", "fovv"))


def _constant_jacobians(rng):
    F = np.eye(6) + 0.2 * rng.normal(size=(6, 6))
    Q = np.eye(6) + 0.2 * rng.normal(size=(6, 6))
    H = np.eye(6) + 0.2 * rng.normal(size=(6, 6))
    R = np.eye(6) + 0.2 * rng.normal(size=(6, 6))
    return F, Q, H, R


def test_propagate_with_constant_non_identity_jacobians():
    """Non-identity motion/observation maps (section 3) use F, Q, H, R correctly."""
    rng = np.random.default_rng(500)
    F, Q, H, R = _constant_jacobians(rng)
    x0, x1 = ca.SX.sym("m0", 7), ca.SX.sym("m1", 7)  # the step's means (position, quaternion)
    jac = ca.Function(
        "jacobians",
        [x0, x1],
        [ca.SX(F), ca.SX(Q), ca.SX(H), ca.SX(R)],
        ["x0", "x1"],
        ["F", "Q", "H", "R"],
    )
    for noise in (NoiseParams(o_star=O_STAR), random_noise(rng)):
        model = BeliefModel(noise, CAMERA, jacobians=jac)
        assert_matches(
            model, random_trajectory(rng), jacobians=lambda a, b: (F, Q, H, R), rel=REL_JAC
        )
        # with_components keeps the Jacobians
        sub = model.with_components(("depth",))
        assert_matches(
            sub,
            random_trajectory(rng),
            components=("depth",),
            jacobians=lambda a, b: (F, Q, H, R),
            rel=REL_JAC,
        )


def test_propagate_with_pose_dependent_jacobians_from_casadi():
    """Jacobians from CasADi differentiation of nonlinear maps are evaluated at the right poses."""
    rng = np.random.default_rng(600)
    A, B = 0.3 * rng.normal(size=(6, 6)), rng.normal(size=(6, 7))
    m0, m1 = ca.SX.sym("m0", 7), ca.SX.sym("m1", 7)  # the step's means (position, unit quaternion)
    # maps that vary with the means
    F = ca.SX.eye(6) + 0.1 * ca.diag(ca.cos(ca.DM(B) @ m0)) @ ca.DM(A)
    H = ca.diag(1 + 0.1 * ca.tanh(ca.DM(B) @ m1) ** 2)
    jac = ca.Function("jacobians", [m0, m1], [F, ca.SX.eye(6), H, ca.SX.eye(6)], ["x0", "x1"],
                      ["F", "Q", "H", "R"])

    # scipy's quaternion of the pose's rotation, reordered (w, x, y, z), w >= 0 (principal poses)
    def means(x):
        qx, qy, qz, qw = Rotation.from_rotvec(x[3:]).as_quat(canonical=True)
        return np.r_[x[:3], qw, qx, qy, qz]

    def jac_np(a, b):
        ma, mb = means(a), means(b)
        F = np.eye(6) + 0.1 * np.cos(B @ ma)[:, None] * A
        H = np.diag(1 + 0.1 * np.tanh(B @ mb) ** 2)
        return F, np.eye(6), H, np.eye(6)

    model = BeliefModel(random_noise(rng), CAMERA, jacobians=jac)
    assert_matches(model, random_trajectory(rng), jacobians=jac_np, rel=REL_JAC)


# ------------------------------------------------------------------ vech, symmetry, definiteness


def test_vech_unvech_round_trip_numpy_and_casadi():
    """The 21-number covariance storage loses nothing; NumPy and CasADi agree."""
    rng = np.random.default_rng(700)
    M = random_spd(rng, 1.0)
    v = vech(M)
    assert v.shape == (NV,) and NV == 21
    np.testing.assert_array_equal(unvech(v), M)
    np.testing.assert_array_equal(vech(unvech(v)), v)
    assert sorted(v) == sorted(M[np.tril_indices(6)])
    assert trace_vech(v) == pytest.approx(np.trace(M), rel=1e-15)
    # CasADi: SX and MX round trips evaluate to the same numbers
    for sym in (ca.SX.sym("v", NV), ca.MX.sym("v", NV)):
        f = ca.Function("rt", [sym], [unvech(sym), vech(unvech(sym)), trace_vech(sym)])
        Mc, vc, tc = f(v)
        np.testing.assert_array_equal(np.asarray(Mc), M)
        np.testing.assert_array_equal(np.asarray(vc).ravel(), v)
        assert float(tc) == pytest.approx(np.trace(M), rel=1e-15)
    S = ca.SX.sym("S", 6, 6)
    fv = ca.Function("v", [S], [vech(S)])
    np.testing.assert_array_equal(np.asarray(fv(M)).ravel(), v)


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
def test_covariances_stay_symmetric_and_positive_definite(formula):
    """Posteriors and priors along long random paths are exactly symmetric and positive definite."""
    rng = np.random.default_rng(800 + len(formula))
    for noise in (
        dataclasses.replace(NoiseParams(o_star=O_STAR), orientation_formula=formula),
        random_noise(rng, formula),
    ):
        model = BeliefModel(noise, CAMERA)
        poses = random_trajectory(rng, 41)
        # visit near-ideal poses too (small V: the update nearly cancels the prior)
        z = noise.depth_star
        centre = np.array(
            [
                (CAMERA.width / 2 - CAMERA.cx) / CAMERA.fx,
                (CAMERA.height / 2 - CAMERA.cy) / CAMERA.fy,
                1,
            ]
        )
        for k in (10, 25):
            poses[k] = np.r_[
                centre * z + 1e-3 * rng.normal(size=3),
                1.1 * np.array(O_STAR) + 1e-3 * rng.normal(size=3),
            ]
        sig, pred = model.propagate(poses)
        for M in list(sig) + list(pred):
            np.testing.assert_array_equal(M, M.T)
            assert np.linalg.eigvalsh(M).min() > 0
            assert np.isfinite(entropy(M))
        sig_ref, _ = ref.propagate(poses, noise, CAMERA, guard=GUARD)
        for a, b in zip(sig, sig_ref, strict=True):
            assert ref.rel_err(a, b) < 1e-10


def test_step_function_equals_propagate():
    """The named CasADi step (used inside the OCP) is the function propagate iterates."""
    rng = np.random.default_rng(900)
    model = BeliefModel(random_noise(rng), CAMERA)
    poses = random_trajectory(rng, 4)
    sig, pred = model.propagate(poses)
    s = vech(np.asarray(model.noise.Sigma0))
    for t in range(3):
        np.testing.assert_allclose(
            unvech(np.asarray(model.predict(mean(poses[t]), mean(poses[t + 1]), s)).ravel()),
            pred[t],
            rtol=0,
            atol=1e-15,
        )
        s = np.asarray(model.step(mean(poses[t]), mean(poses[t + 1]), s)).ravel()
        np.testing.assert_array_equal(unvech(s), sig[t + 1])


# Belief-aware observation noise (`observation_noise: expected`, method note section 8).


EXPECTED_CAMERA = Intrinsics(fx=768.98551924, fy=768.98551924, cx=292.8861567, cy=291.61479526,
                             width=640, height=480)
X = np.array([0.03, -0.02, 0.12, 0.5, 0.3, 1.4])  # a tool pose off the ideal one [m, rad]
MX_ = np_means(X)[0]  # its mean (position, quaternion), what the model's Functions take


def model(form: str, components=("depth", "fov", "orientation")) -> BeliefModel:
    return BeliefModel(replace(NoiseParams(o_star=(0.4, 0.4, 1.53)), observation_noise=form),
                       EXPECTED_CAMERA, components)


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
    assert np.array_equal(np.asarray(m.planning_noise(MX_, vech(P))),
                          np.asarray(m.observation_noise(MX_)))


def test_expected_depth_term_equals_monte_carlo():
    """E[(z - d*)^2] under N(mu, P) equals the Monte-Carlo average (closed form; 200k samples,
    1 %)."""
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
    du = s[:, 0] / s[:, 2] + (EXPECTED_CAMERA.cx - EXPECTED_CAMERA.width / 2) / EXPECTED_CAMERA.fx
    dv = s[:, 1] / s[:, 2] + (EXPECTED_CAMERA.cy - EXPECTED_CAMERA.height / 2) / EXPECTED_CAMERA.fy
    assert coef == pytest.approx(float(np.mean(du**2 + dv**2)), rel=0.02)


@pytest.mark.parametrize("formula", ["cosine", "geodesic"])
def test_expected_orientation_term_is_taken_in_the_tangent(formula):
    """The orientation term's spread `tr(J P_rr J^T)` uses the Jacobian in the covariance's
    coordinates, the tangent of left perturbations `exp(e) R` (as the rollouts draw them): checked
    against central differences of the independent NumPy residual (tests/numpy_ekf.py) along scipy
    rotations, at a large angle (2.7 rad) where the axis-angle chart's Jacobian differs from the
    tangent's."""
    import numpy_ekf as ref
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    P = random_spd(rng, 1e-4)
    x = np.r_[X[:3], 2.7 * np.array([0.6, -0.48, 0.64])]
    m = BeliefModel(replace(NoiseParams(o_star=(0.4, 0.4, 1.53), orientation_formula=formula),
                            observation_noise="expected"), EXPECTED_CAMERA, ("orientation",))
    spread = float(np.asarray(m.planning_noise(np_means(x)[0], vech(P))
                              - m.observation_noise(np_means(x)[0]))[0, 0])
    noise = replace(m.noise, V_o0=np.eye(6))

    def e(R):  # the residual 1 - cos (>= 0) of the NumPy formula
        V = ref.observation_noise(np.r_[x[:3], R.as_rotvec()], noise, EXPECTED_CAMERA,
                                  ("orientation",), formula, guard=noise.cosine_guard**2,
                                  band=noise.cut_band)
        return float(np.sqrt(V[0, 0]))

    R, h = Rotation.from_rotvec(x[3:]), 1e-6
    J = np.array([(e(Rotation.from_rotvec(h * u) * R) - e(Rotation.from_rotvec(-h * u) * R))
                  / (2 * h)
                  for u in np.eye(3)])
    expected = float(J @ P[3:, 3:] @ J) * m.noise.V_o0[0, 0]
    assert spread == pytest.approx(expected, rel=1e-6)


def test_expected_step_gradient_matches_finite_differences():
    """The planner's EKF step with expected noise has correct derivatives (central differences,
    1e-6)."""
    m = model("expected")
    x0 = ca.SX.sym("x0", 6)
    x1 = ca.SX.sym("x1", 6)
    s = ca.SX.sym("s", 21)
    # trace of the posterior
    out = ca.sum1(m.step_expr(pose_mean(x0), pose_mean(x1), s)[[0, 6, 11, 15, 18, 20]])
    f = ca.Function("f", [x0, x1, s], [out])
    g = ca.Function("g", [x0, x1, s], [ca.gradient(out, x1)])
    rng = np.random.default_rng(3)
    a = X - np.array([0.01, 0.0, 0.01, 0.1, 0.0, 0.0])
    S0 = vech(random_spd(rng, 1e-4))
    grad = np.asarray(g(a, X, S0)).ravel()
    h = 1e-6
    fd = np.array([(float(f(a, X + h * e, S0)) - float(f(a, X - h * e, S0))) / (2 * h)
                   for e in np.eye(6)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-12 * np.abs(fd).max())


def test_expected_noise_never_vanishes_while_uncertain():
    """At the ideal pose the paper's V is zero; the expected V is not, while the belief is
    uncertain."""
    ideal = np.array([-(EXPECTED_CAMERA.cx - 320) / EXPECTED_CAMERA.fx * 0.15,
                      -(EXPECTED_CAMERA.cy - 240) / EXPECTED_CAMERA.fy * 0.15, 0.15, 0.4, 0.4,
                      1.53])
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

    p = load_problem(Path(__file__).resolve().parents[1] / "problems"
                     / "needle_regrasp_paper_pace.yaml")
    return build_setup(replace(p, horizon=6, noise=replace(p.noise, objective="predicted")))


@pytest.mark.parametrize("method", ["gradient-no-pose-loss", "ocp"])
def test_predicted_objective_is_the_covariance_before_the_last_update(predicted_setup, method):
    """`objective.covariance: predicted` minimises Tr(Sigma_T|T-1), as the exact EKF computes it."""
    from surestep_ocp.methods.registry import run_method

    sol = run_method(predicted_setup, method)
    _, pred = predicted_setup.eval_model.propagate(np.array(sol.poses))
    assert sol.objective == pytest.approx(np.trace(pred[-1]), rel=1e-6)


def test_unknown_objective_is_a_problem_error(tmp_path):
    """objective.covariance only takes posterior or predicted; anything else names the key."""
    from pathlib import Path

    from surestep_ocp.errors import ProblemError
    from surestep_ocp.problem.load import load_problem

    text = (Path(__file__).resolve().parents[1] / "problems"
            / "needle_regrasp_paper_pace.yaml").read_text()
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace("  smoothness: 0.0", "  smoothness: 0.0\n  covariance: prior"))
    with pytest.raises(ProblemError, match="objective.covariance"):
        load_problem(path)
