"""Orientations near and across a rotation of pi (the cut of the principal rotation vector).

References: Pinocchio's numeric FK for rotations, scipy's `Rotation` and the plain NumPy EKF
(tests/numpy_ekf.py, principal vectors and the documented fade) for every covariance.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import numpy_ekf as ref
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.methods.baseline import solve_baseline
from surestep_ocp.model.belief import BeliefModel, NoiseParams
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.errors import ProblemError
from surestep_ocp.methods.registry import ocp_initial_guess, run_method
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.evaluation.rollout import rollout
from surestep_ocp.model.lie import np_means, pose_mean
from surestep_ocp.problem.setup import build_setup

DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"
EVALUATION = DEFAULT.parent / "evaluations" / "evaluation.yaml"
CROSSING = (0, 36)  # evaluation configurations whose straight line passes through a rotation of pi


@pytest.fixture(scope="module")
def sampler():
    return ConfigurationSampler(load_evaluation(EVALUATION))


def _setup(sampler, c):
    return build_setup(sampler.problem(sampler.sample(0, c)))


def _ekf_trace(setup, poses) -> float:
    n = setup.ocp.noise
    return float(np.trace(ref.propagate(np.asarray(poses), n, setup.ocp.intrinsics,
                                        guard=n.cosine_guard**2)[0][-1]))


def _other_side(r):
    """The other rotation vector of the same rotation: r (1 - 2 pi / |r|)."""
    r = np.asarray(r, float)
    return r * (1 - 2 * np.pi / np.linalg.norm(r))


def _angles(n, rng, low=3.0, high=np.pi):
    a = rng.normal(size=(n, 3))
    return (a / np.linalg.norm(a, axis=1, keepdims=True)) * rng.uniform(low, high, size=(n, 1))


def test_means_are_continued_along_the_joints_through_pi(sampler):
    """The straight line of configuration 0 crosses pi: its principal vectors jump by about 2 pi,
    the means of `Setup.poses_of` (the FK quaternion's log) do not, and exp(r) is Pinocchio's
    rotation at every waypoint."""
    setup = _setup(sampler, 0)
    q = np.asarray(ocp_initial_guess(setup).q, float)
    means = setup.poses_of(q)
    principal = np.array([Rotation.from_matrix(
        (setup.T_cam_base @ setup.robot.frame_pose(qi))[:3, :3]).as_rotvec() for qi in q])
    assert np.max(np.linalg.norm(np.diff(principal, axis=0), axis=1)) > 5.0  # the jump at the cut
    assert np.max(np.linalg.norm(np.diff(means[:, 3:], axis=0), axis=1)) < 0.2
    assert np.max(np.linalg.norm(means[:, 3:], axis=1)) > np.pi
    np.testing.assert_allclose(means[0], setup.x_start, atol=1e-9)  # the start's principal vector
    for qi, x in zip(q, means):
        T = setup.T_cam_base @ setup.robot.frame_pose(qi)
        np.testing.assert_allclose(Rotation.from_rotvec(x[3:]).as_matrix(), T[:3, :3], atol=1e-12)
        np.testing.assert_allclose(x[:3], T[:3, 3], atol=1e-12)


def test_nlp_means_are_pinocchios_rotations_and_continuous_through_pi(sampler):
    """The NLP's means `(p, Q)` (`Setup.means_of`, `Robot.camera_pose`): unit quaternions of
    Pinocchio's rotation (up to the double cover's sign) along configuration 0's straight line,
    which crosses pi, with no jump (each step's quaternion change is its half-angle step), and over
    random joints in the whole box."""
    setup = _setup(sampler, 0)
    q = np.asarray(ocp_initial_guess(setup).q, float)
    rng = np.random.default_rng(6)
    lo, hi = setup.robot.lower, setup.robot.upper
    for joints, path in ((q, True), (lo + (hi - lo) * rng.random((200, setup.robot.nq)), False)):
        m = setup.means_of(joints)
        assert m.shape == (len(joints), 7)
        np.testing.assert_allclose(np.linalg.norm(m[:, 3:], axis=1), 1.0, atol=1e-12)
        for qi, mi in zip(joints, m):
            T = setup.T_cam_base @ setup.robot.frame_pose(qi)
            x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
            assert abs(abs(mi[3:] @ np.array([w, x, y, z])) - 1) < 1e-12
            np.testing.assert_allclose(mi[:3], T[:3, 3], atol=1e-12)
        if path:
            assert np.max(np.linalg.norm(np.diff(m[:, 3:], axis=0), axis=1)) < 0.1
    np.testing.assert_allclose(setup.m_start[3:], setup.means_of(setup.q_start)[0, 3:], atol=1e-9)
    np.testing.assert_allclose(setup.m_goal[3:], setup.means_of(setup.q_goal)[0, 3:], atol=1e-6)


def test_means_are_finite_and_pinocchios_over_the_whole_joint_box(sampler):
    """Random joints in the limits (the roll joint turns 9 rad): every mean is finite, its rotation
    Pinocchio's, its angle at most 2 acos(-0.9) (past it the other vector of the rotation: no log at
    a full turn)."""
    setup = _setup(sampler, 0)
    rng = np.random.default_rng(5)
    lo, hi = setup.robot.lower, setup.robot.upper
    q = lo + (hi - lo) * rng.random((400, setup.robot.nq))
    means = setup.poses_of(q)
    assert np.all(np.isfinite(means))
    assert np.max(np.linalg.norm(means[:, 3:], axis=1)) <= 2 * np.arccos(-0.9) + 1e-9
    assert np.max(np.linalg.norm(means[:, 3:], axis=1)) > np.pi + 1.0  # the continued sheet is used
    for qi, x in zip(q[:50], means[:50]):
        R = (setup.T_cam_base @ setup.robot.frame_pose(qi))[:3, :3]
        np.testing.assert_allclose(Rotation.from_rotvec(x[3:]).as_matrix(), R, atol=1e-10)


def test_the_cosine_term_is_a_function_of_the_rotation():
    """Angles in [3.0, pi]: both vectors of one rotation give one V, that of the NumPy EKF
    (principal vector, the fade over the last `cut_band` rad); V is continuous across pi, and its
    derivative matches central differences on both sides (smooth in the vector, so in the
    joints)."""
    rng = np.random.default_rng(3)
    noise = NoiseParams(o_star=(0.3, -0.2, 0.9))
    model = BeliefModel(noise, ref_camera())
    for r in _angles(40, rng):
        x = np.r_[0.01, -0.02, 0.12, r]
        V = np.asarray(model.observation_noise(np_means(x)[0]))
        V_other = np.asarray(model.observation_noise(np_means(np.r_[x[:3], _other_side(r)])[0]))
        V_ref = ref.observation_noise(x, noise, model.camera, guard=noise.cosine_guard**2,
                                      band=noise.cut_band)
        assert ref.rel_err(V, V_ref) < 1e-12 and ref.rel_err(V_other, V_ref) < 1e-12
    axis = np.array([0.6, 0.3, 0.74]) / np.linalg.norm([0.6, 0.3, 0.74])
    v = lambda th: float(np.asarray(
        model.observation_noise(np_means(np.r_[0.01, -0.02, 0.12, th * axis])[0]))[5, 5])
    # its slope times 2e-7; the paper's jump is ~1e-2
    assert abs(v(np.pi - 1e-7) - v(np.pi + 1e-7)) < 1e-7
    xs = ca.SX.sym("x", 6)
    # along the rotation vector
    V_of = ca.Function("V", [xs], [model.observation_noise(pose_mean(xs))[5, 5]])
    grad = ca.Function("g", [xs], [ca.gradient(V_of(xs), xs)])
    for th in (np.pi - 0.15, np.pi - 1e-3, np.pi + 1e-3, np.pi + 0.15):
        x, h = np.r_[0.01, -0.02, 0.12, th * axis], 1e-6
        fd = [(float(V_of(x + h * e)) - float(V_of(x - h * e))) / (2 * h) for e in np.eye(6)]
        np.testing.assert_allclose(np.asarray(grad(x)).ravel(), fd, rtol=1e-5, atol=1e-9)
    # cut_band 0 and cosine_guard 0: the paper's own formula, with its jump at pi
    paper = BeliefModel(replace(noise, cosine_guard=0.0, cut_band=0.0), ref_camera(),
                        components=("orientation",))
    vp = lambda th: float(np.asarray(
        paper.observation_noise(np_means(np.r_[0.01, -0.02, 0.12, th * axis])[0]))[5, 5])
    cos = float(axis @ np.asarray(noise.o_star)) / np.linalg.norm(noise.o_star)
    assert vp(np.pi - 1e-3) == pytest.approx((1 - cos) ** 2 * noise.V_o0[5, 5], rel=1e-12)
    assert vp(np.pi + 1e-3) == pytest.approx((1 + cos) ** 2 * noise.V_o0[5, 5], rel=1e-12)


def ref_camera():
    return load_problem(DEFAULT).camera.intrinsics


def test_belief_propagation_near_pi_matches_numpy():
    """A path whose angles run through [3.0, pi] and beyond (continued vectors): the package's EKF
    equals the NumPy EKF on the principal vectors."""
    noise = NoiseParams()
    model = BeliefModel(noise, ref_camera())
    axis = np.array([0.2, -0.5, 0.84]) / np.linalg.norm([0.2, -0.5, 0.84])
    th = np.linspace(2.9, 3.4, 11)
    poses = np.column_stack([np.linspace(0.0, 0.02, 11), np.zeros(11), np.linspace(0.1, 0.15, 11),
                             th[:, None] * axis])
    principal = poses.copy()
    principal[:, 3:] = Rotation.from_rotvec(poses[:, 3:]).as_rotvec()
    sig, pred = model.propagate(poses)
    sig_ref, pred_ref = ref.propagate(principal, noise, model.camera, guard=noise.cosine_guard**2)
    assert ref.rel_err(sig, sig_ref) < 1e-10 and ref.rel_err(pred, pred_ref) < 1e-10


@pytest.mark.parametrize("c", CROSSING)
def test_ocp_converges_where_the_straight_line_crosses_pi(sampler, c):
    """Start and goal on opposite sides of the cut (the shortest rotation between them passes
    through pi):
    the OCP converges (the start is not kept), below the straight line, and its trace is the NumPy
    EKF's on its (principal) poses, whose rotations are Pinocchio's at its joints."""
    setup = _setup(sampler, c)
    base = solve_baseline(setup)
    assert np.max(np.linalg.norm(setup.poses_of(np.asarray(ocp_initial_guess(setup).q))[:, 3:],
                                 axis=1)) > np.pi
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    assert sol.status == "Solve_Succeeded", sol.attempts
    assert sol.trace_final < base.trace_final
    poses = np.asarray(sol.poses)
    assert np.all(np.linalg.norm(poses[:, 3:], axis=1) <= np.pi + 1e-12)
    assert _ekf_trace(setup, poses) == pytest.approx(sol.trace_final, rel=1e-9)
    assert base.trace_final == pytest.approx(_ekf_trace(setup, base.poses), rel=1e-9)
    for qi, x in zip(sol.q, poses):
        R = (setup.T_cam_base @ setup.robot.frame_pose(qi))[:3, :3]
        np.testing.assert_allclose(Rotation.from_rotvec(x[3:]).as_matrix(), R, atol=1e-9)
    # planner = evaluation
    assert sol.run.ocp_trace_final == pytest.approx(sol.trace_final, rel=1e-6)
    goal = np.asarray(sol.to_dict()["goal"])  # the file's goal: principal, the setup's rotation
    assert np.linalg.norm(goal[3:]) <= np.pi
    np.testing.assert_allclose(Rotation.from_rotvec(goal[3:]).as_matrix(),
                               Rotation.from_rotvec(setup.x_goal[3:]).as_matrix(), atol=1e-12)


def test_gradient_variant_near_pi(sampler):
    """The gradient variant on configuration 0: its reported trace is the NumPy EKF's on its
    poses."""
    setup = _setup(sampler, 0)
    sol = run_method(setup, "gradient")
    assert np.isfinite(sol.trace_final)
    assert _ekf_trace(setup, sol.poses) == pytest.approx(sol.trace_final, rel=1e-9)


def test_rollouts_near_pi_see_the_plans_noise(sampler):
    """Configuration 0's straight line runs through pi; with every noise scaled by 1e-10 the
    rollouts' EKF stays on the waypoints, so its final covariance is the plan's (a sign flip of the
    cosine at the cut would change the orientation noise by (1 + cos)^2 / (1 - cos)^2)."""
    setup = _setup(sampler, 0)
    base = solve_baseline(setup)
    n = setup.eval_model.noise
    tiny = replace(n, **{k: 1e-10 * np.asarray(getattr(n, k))
                         for k in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0",
                                    "Sigma0")})
    model = BeliefModel(tiny, setup.eval_model.camera)
    poses = np.asarray(base.poses)
    assert np.max(np.linalg.norm(poses[:, 3:], axis=1)) > 3.0
    out = rollout(model, poses, n=8, rng=0, mode="model")
    expected = model.propagate(poses)[0][-1]
    assert ref.rel_err(out.sigma_final.mean(axis=0), expected) < 1e-3


def test_solutions_record_the_cosine_parameters(tmp_path, sampler):
    """`cosine_guard` and `cut_band` are read from the problem file, checked, and recorded in the
    solution."""
    text = DEFAULT.read_text()
    good = tmp_path / "p.yaml"
    good.write_text(text.replace("\nnoise:", "\nnoise:\n  cosine_guard: 0.0\n  cut_band: 0.1\n ",
                                 1))
    prob = load_problem(good)
    assert (prob.noise.cosine_guard, prob.noise.cut_band) == (0.0, 0.1)
    setup = build_setup(replace(prob, horizon=4))
    sol = solve_baseline(setup)
    d = sol.to_dict()
    assert d["noise"]["cosine_guard"] == 0.0 and d["noise"]["cut_band"] == 0.1
    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text().replace("cut_band: 0.1", "cut_band: -0.1"))
    with pytest.raises(ProblemError, match="noise.cut_band"):
        load_problem(bad)
