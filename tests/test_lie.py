"""The rotation helpers (surestep_ocp.model.lie: so3_exp / so3_log, the squared angle, slerp)
against scipy's Rotation and textbook NumPy formulas (split from the kinematics tests,
test_robot.py).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.model.lie import (angle_sq, np_angle, np_exp, np_exp_many, np_log, np_log_many,
                                    slerp, slerp_many, so3_exp,
                              so3_log)


def _vee(S: np.ndarray) -> np.ndarray:
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def _rand_rotvecs(rng, n, max_angle=np.pi - 1e-3):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


SMALL = [
    np.zeros(3),
    np.array([1e-9, 0, 0]),
    np.array([1e-7, -2e-7, 3e-7]),
    np.array([1e-5, 2e-5, -1e-5]),
    np.array([1e-3, 0.0, -1e-3]),
]


@pytest.fixture(scope="module")
def lie_functions():
    r = ca.SX.sym("r", 3)
    R = ca.SX.sym("R", 3, 3)
    a, b = ca.SX.sym("a", 3), ca.SX.sym("b", 3)
    return {
        "exp": ca.Function("exp", [r], [so3_exp(r)]),
        "log": ca.Function("log", [R], [so3_log(R)]),
        "angle_sq": ca.Function("angle_sq", [a, b], [angle_sq(so3_exp(a), so3_exp(b))]),
        "round_trip_jac": ca.Function("rtj", [r], [ca.jacobian(so3_log(so3_exp(r)), r)]),
        "exp_jac": ca.Function("ej", [r], [ca.jacobian(ca.vec(so3_exp(r)), r)]),
        "log_jac": ca.Function("lj", [R], [ca.jacobian(so3_log(R), ca.vec(R))]),
        "angle_sq_grad_hess": ca.Function(
            "ash",
            [a, b],
            [
                ca.gradient(angle_sq(so3_exp(a), so3_exp(b)), ca.vertcat(a, b)),
                ca.hessian(angle_sq(so3_exp(a), so3_exp(b)), ca.vertcat(a, b))[0],
            ],
        ),
    }


def test_so3_exp_matches_scipy_and_numpy(lie_functions):
    """The symbolic exponential (every orientation in the OCP) equals the textbook rotation."""
    rng = np.random.default_rng(11)
    for r in list(_rand_rotvecs(rng, 200, 2 * np.pi)) + SMALL:
        R_ref = Rotation.from_rotvec(r).as_matrix()
        np.testing.assert_allclose(np.asarray(lie_functions["exp"](r)), R_ref, rtol=0, atol=1e-14)
        np.testing.assert_allclose(np_exp(r), R_ref, rtol=0, atol=1e-14)


def test_so3_log_matches_scipy_and_numpy(lie_functions):
    """The symbolic logarithm equals scipy's rotation vector for angles in [0, pi)."""
    rng = np.random.default_rng(12)
    for r in list(_rand_rotvecs(rng, 200)) + SMALL:
        R = Rotation.from_rotvec(r).as_matrix()
        r_ref = Rotation.from_matrix(R).as_rotvec()
        np.testing.assert_allclose(
            np.asarray(lie_functions["log"](R)).ravel(), r_ref, rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(np_log(R), r_ref, rtol=0, atol=1e-9)


def test_np_log_near_pi():
    """The NumPy logarithm handles angles at and near pi (the axis-angle chart is singular)."""
    rng = np.random.default_rng(13)
    for axis in rng.normal(size=(20, 3)):
        axis /= np.linalg.norm(axis)
        for th in (np.pi, np.pi - 1e-6, np.pi - 1e-3):
            R = Rotation.from_rotvec(th * axis).as_matrix()
            r = np_log(R)
            assert np.linalg.norm(r) == pytest.approx(th, abs=1e-6)
            np.testing.assert_allclose(np_exp(r), R, atol=1e-6)


def test_so3_round_trip(lie_functions):
    """log(exp(r)) = r inside the principal ball and exp(log(R)) = R, symbolic and NumPy."""
    rng = np.random.default_rng(14)
    for r in list(_rand_rotvecs(rng, 200)) + SMALL:
        np.testing.assert_allclose(
            np.asarray(lie_functions["log"](lie_functions["exp"](r))).ravel(), r, rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(np_log(np_exp(r)), r, rtol=0, atol=1e-9)
    for R in Rotation.random(50, random_state=15).as_matrix():
        if Rotation.from_matrix(R).magnitude() < np.pi - 1e-3:
            np.testing.assert_allclose(
                np.asarray(lie_functions["exp"](lie_functions["log"](R))), R, atol=1e-12
            )


def test_derivatives_smooth_at_identity(lie_functions):
    """Derivatives at r = 0 are finite and correct (no NaN leaking from the unused branch)."""
    for r in SMALL[:3]:
        J = np.asarray(lie_functions["round_trip_jac"](r))
        assert np.all(np.isfinite(J))
        np.testing.assert_allclose(J, np.eye(3), atol=1e-6)
    # d exp(r)/dr at 0 is the basis of skew matrices; d log(R)/dR at I picks the antisymmetric part
    Je = np.asarray(lie_functions["exp_jac"](np.zeros(3)))
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1.0
        np.testing.assert_allclose(_vee(Je[:, i].reshape(3, 3, order="F")), e, atol=1e-15)
    Jl = np.asarray(lie_functions["log_jac"](np.eye(3)))
    assert np.all(np.isfinite(Jl))
    # directional derivative along skew(w) is w
    w = np.array([0.3, -0.2, 0.5])
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    np.testing.assert_allclose(Jl @ W.ravel(order="F"), w, atol=1e-12)
    # angle_sq: zero gradient and the Hessian [[2I, -2I], [-2I, 2I]] at a = b = 0
    g, H = (np.asarray(v) for v in lie_functions["angle_sq_grad_hess"](np.zeros(3), np.zeros(3)))
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(H))
    np.testing.assert_allclose(g.ravel(), 0, atol=1e-15)
    np.testing.assert_allclose(
        H, np.block([[2 * np.eye(3), -2 * np.eye(3)], [-2 * np.eye(3), 2 * np.eye(3)]]), atol=1e-9
    )
    # and at a = b away from zero the gradient vanishes too (angle 0 between equal rotations)
    a = np.array([0.4, -0.3, 1.2])
    g, H = (np.asarray(v) for v in lie_functions["angle_sq_grad_hess"](a, a))
    assert np.all(np.isfinite(g)) and np.all(np.isfinite(H))
    np.testing.assert_allclose(g.ravel(), 0, atol=1e-12)


def test_angle_sq_matches_numpy(lie_functions):
    """The squared geodesic angle (motion noise) equals scipy's relative-rotation angle squared."""
    rng = np.random.default_rng(16)
    A, B = _rand_rotvecs(rng, 200, 2.5), _rand_rotvecs(rng, 200, 2.5)
    for a, b in zip(A, B, strict=True):
        ang = (Rotation.from_rotvec(a).inv() * Rotation.from_rotvec(b)).magnitude()
        if ang > np.pi - 1e-3:
            continue
        assert float(lie_functions["angle_sq"](a, b)) == pytest.approx(ang**2, rel=1e-10, abs=1e-20)
        assert np_angle(a, b) == pytest.approx(ang, rel=1e-10, abs=1e-12)
    for a in SMALL:
        assert float(lie_functions["angle_sq"](a, 2 * a)) == pytest.approx(
            float(a @ a), rel=1e-9, abs=1e-30
        )


# Bug (surestep_ocp/model/lie.py, so3_log): the Taylor branch is selected by |sin(theta)|^2 < 1e-12,
# which holds near theta = 0 AND near theta = pi. For theta in (pi - 1e-6, pi) the symbolic log
# returns sin(theta) * axis (norm < 1e-6) instead of theta * axis (norm ~ pi), although its
# docstring promises angles in [0, pi). angle_sq inherits it: a rotation by pi - 1e-7 has
# squared angle ~1e-14, not ~9.87.
NEAR_PI = np.pi - 1e-7
NEAR_PI_AXIS = np.array([1.0, 2.0, 3.0]) / np.linalg.norm([1.0, 2.0, 3.0])


def test_so3_log_just_below_pi(lie_functions):
    """The symbolic log is right on all of [0, pi) as documented, including just below pi."""
    R = Rotation.from_rotvec(NEAR_PI * NEAR_PI_AXIS).as_matrix()
    r = np.asarray(lie_functions["log"](R)).ravel()
    np.testing.assert_allclose(r, NEAR_PI * NEAR_PI_AXIS, rtol=0, atol=1e-6)


def test_angle_sq_just_below_pi(lie_functions):
    """A step turning the tool by almost half a turn has a squared angle near pi^2, not 0."""
    assert float(lie_functions["angle_sq"](np.zeros(3), NEAR_PI * NEAR_PI_AXIS)) == pytest.approx(
        NEAR_PI**2, rel=1e-6
    )


def test_vectorised_exp_log_slerp_equal_the_scalar_ones():
    """np_exp_many / np_log_many / slerp_many equal the per-vector versions, including zero and
    near-pi angles.

    The slerps agree to the accuracy of the log they share, not to a fixed 1e-9: it takes the axis
    from the antisymmetric part of R, `sin(th) n`, so a rounding difference dR moves the vector by
    about `th / sin(th) * dR`, large near pi (below sin(th) = 1e-9 both use the symmetric part). The
    two paths round R differently by an ulp (np_exp scales k before `k @ k`, np_exp_many after), so
    a row's tolerance is `16 eps th / max(sin(th), 1e-9)` (a few ulp in R and in the log itself).
    """
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = np.concatenate([rng.uniform(0, np.pi, 34),
                             [0.0, 1e-10, np.pi - 1e-7, np.pi, np.pi, 2e-9]])
    r = axes * angles[:, None]
    R = np_exp_many(r)
    np.testing.assert_allclose(R, np.array([np_exp(v) for v in r]), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np_log_many(R), np.array([np_log(M) for M in R]), rtol=0, atol=1e-12)
    s = np.linspace(0, 1, 11)
    for a, b in zip(r[:-1], r[1:]):
        many, scalar = slerp_many(a, b, s), np.array([slerp(a, b, si) for si in s])
        th = np.linalg.norm(scalar, axis=1)
        cond = np.where(th < 1e-9, 1.0, th / np.maximum(np.sin(th), 1e-9))  # th / sin(th) -> 1 at 0
        tol = 16 * np.finfo(float).eps * cond
        err = np.abs(many - scalar).max(axis=1)
        assert np.all(err <= tol), (f"rows {np.flatnonzero(err > tol)}: error "
                                    f"{err.max():.1e}, tolerance {tol}")
