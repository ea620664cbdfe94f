"""Noisy closed-loop rollouts (surestep_ocp.evaluation.rollout): exactness without noise, EKF
consistency with noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import numpy_rollout
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.ocp.straight_line import straight_line
from surestep_ocp.model.belief import BeliefModel
from surestep_ocp.model.lie import np_means
from surestep_ocp.evaluation.rollout import METRICS, BatchedNoise, Detection, plan_metrics, rollout


T = 6


@pytest.fixture(scope="module")
def plan(default_setup) -> np.ndarray:
    """A bent 6-step path of the default problem (positions and orientations off the straight
    line)."""
    poses = straight_line(default_setup.x_start, default_setup.x_goal, T)
    bump = np.sin(np.linspace(0, np.pi, T + 1))[:, None]
    return poses + bump * np.array([0.01, -0.008, 0.006, 0.2, -0.1, 0.15])


def test_zero_noise_reproduces_the_plan(default_setup, plan):
    """With every noise constant 0 (Sigma0 kept), true and estimated paths are the plan, in both
    modes."""
    z = np.zeros((6, 6))
    noise = dataclasses.replace(default_setup.ocp.noise, W_p0=z, W_o0=z, V_d0=z, V_f0=z, V_o0=z)
    model = BeliefModel(noise, default_setup.ocp.intrinsics)
    for mode in ("model", "true"):
        ro = rollout(model, plan, default_setup.x_goal, n=7, rng=3, mode=mode, keep_paths=True)
        for path in (ro.true_path, ro.estimate_path):
            assert np.abs(path[:, :, :3] - plan[:, :3]).max() < 1e-12
            angles = (Rotation.from_rotvec(path[:, :, 3:].reshape(-1, 3)).inv()
                      * Rotation.from_rotvec(np.tile(plan[:, 3:], (7, 1)))).magnitude()
            assert angles.max() < 1e-12
        assert ro.pos_err.max() < 1e-12 and ro.ori_err.max() < 1e-12  # the plan ends at the goal


def test_batched_noise_matches_the_model_functions(default_setup, plan):
    """The mapped noise Functions give, pose by pose, what the model's own Functions give."""
    model = default_setup.eval_model
    rng = np.random.default_rng(1)
    x0 = plan[rng.integers(0, T + 1, 5)] + 0.01 * rng.normal(size=(5, 6))
    x1 = plan[rng.integers(0, T + 1, 5)]
    b = BatchedNoise(model, 5)
    W, V = b.motion(x0, x1), b.observation(x0)
    for k in range(5):
        W_k = model.motion_noise(np_means(x0[k])[0], np_means(x1[k])[0])
        np.testing.assert_allclose(W[k], np.asarray(W_k), rtol=1e-14, atol=0)
        np.testing.assert_allclose(V[k], np.asarray(model.observation_noise(np_means(x0[k])[0])),
                                   rtol=1e-14, atol=0)


def test_empirical_error_covariance_matches_the_ekf(default_setup, plan):
    """Model mode: the spread of x_true - mu over 4000 rollouts is the EKF's own Sigma_T (filter
    consistency).

    Tolerances: trace within 10 %, each diagonal entry within 15 % (the sampling error of a
    variance from 4000 draws is ~2.2 %), mean NEES e^T Sigma_T^-1 e within 6 +- 0.4 (chi^2_6
    mean 6; its standard error here is ~0.055). The true start is drawn from the prior.
    """
    model = default_setup.eval_model
    ro = rollout(model, plan, default_setup.x_goal, n=4000, rng=np.random.default_rng(2024),
                 mode="model", sample_initial=True)
    e = ro.final_error
    emp = e.T @ e / len(e)
    ekf = ro.sigma_final.mean(axis=0)
    assert abs(np.trace(emp) / np.trace(ekf) - 1) < 0.10
    assert np.all(np.abs(np.diag(emp) / np.diag(ekf) - 1) < 0.15)
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(ro.sigma_final), e)
    assert abs(nees.mean() - 6) < 0.4
    # the rollouts' EKF stays close to the maximum-likelihood covariance of the plan
    ml = model.propagate(plan)[0][-1]
    assert abs(np.trace(ekf) / np.trace(ml) - 1) < 0.2


def test_seeded_and_metrics(default_setup, plan):
    """Same seed, same rollouts; the eight metrics are finite, with the ML ones from the plan's
    Sigma_T."""
    model = default_setup.eval_model
    a = rollout(model, plan, default_setup.x_goal, n=20, rng=5, mode="true")
    b = rollout(model, plan, default_setup.x_goal, n=20, rng=np.random.default_rng(5), mode="true")
    np.testing.assert_array_equal(a.final_true, b.final_true)
    c = rollout(model, plan, default_setup.x_goal, n=20, rng=5, mode="model")
    assert not np.array_equal(a.final_true, c.final_true)
    met, ro = plan_metrics(model, plan, default_setup.x_goal, 20, 5, "true")
    assert list(met) == list(METRICS) and all(np.isfinite(v) for v in met.values())
    ml = model.propagate(plan)[0][-1]
    assert met["trace_ml"] == pytest.approx(np.trace(ml), rel=1e-12)
    assert met["entropy_noisy"] < 0 and met["pos_err_mean"] == pytest.approx(a.pos_err.mean())


def test_rejects_bad_arguments(default_setup, plan):
    """Unknown rollout modes and malformed plans are errors, not silent garbage."""
    with pytest.raises(ValueError, match="rollout mode"):
        rollout(default_setup.eval_model, plan, n=2, mode="optimistic")
    with pytest.raises(ValueError, match="shape"):
        rollout(default_setup.eval_model, plan[:, :3], n=2)


def test_detection_probability_of_the_true_pose(default_setup):
    """Behind or too close to the lens, or outside the image less the margin: 0; inside: 1; the
    falloff ramps."""
    cam = default_setup.eval_model.camera
    det = Detection(margin=0.05, min_depth=0.02)
    centre = np.array([(cam.width / 2 - cam.cx) / cam.fx, (cam.height / 2 - cam.cy) / cam.fy, 1.0])
    z = 0.15
    # camera-frame point projecting to (u, v) given as image fractions
    def at(u_frac, v_frac=0.5, depth=z):
        return np.array([[(u_frac * cam.width - cam.cx) / cam.fx * depth,
                          (v_frac * cam.height - cam.cy) / cam.fy
                          * depth, depth]])
    assert det.probability(cam, centre[None] * z)[0] == 1.0
    assert det.probability(cam, at(0.5, depth=-0.1))[0] == 0.0  # behind the lens
    assert det.probability(cam, at(0.5, depth=0.01))[0] == 0.0  # too close
    assert det.probability(cam, at(0.97))[0] == 0.0 and det.probability(cam, at(0.93))[0] == 1.0
    assert det.probability(cam, at(0.5, 0.02))[0] == 0.0
    ramp = Detection(margin=0.05, min_depth=0.02, falloff=0.1)
    assert ramp.probability(cam, at(0.10))[0] == pytest.approx(0.5)
    assert ramp.probability(cam, at(0.30))[0] == 1.0


def test_undetected_steps_only_predict(default_setup, plan):
    """A plan entirely outside the image gives no observation: the estimate follows the waypoints
    and Sigma_T = Sigma_0 + sum_t W(x_t, x_t+1) exactly (computed here from the model's own W), in
    both modes."""
    model = default_setup.eval_model
    out = plan.copy()
    out[:, 0] += 0.3  # 30 cm to the right at ~15 cm depth: far outside the image
    m = np_means(out)
    sigma = (np.asarray(model.noise.Sigma0, float)
             + sum(np.asarray(model.motion_noise(m[t], m[t + 1])) for t in range(T)))
    for mode in ("model", "true"):
        ro = rollout(model, out, n=5, rng=1, mode=mode, detection=Detection())
        assert not ro.detected.any()
        for k in range(5):
            np.testing.assert_allclose(ro.sigma_final[k], sigma, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(ro.final_estimate[:, :3], np.tile(out[-1, :3], (5, 1)),
                                   atol=1e-12)
        # without the detection model the same plan is observed at every step: a smaller covariance
        ro_all = rollout(model, out, n=5, rng=1, mode=mode)
        assert np.trace(ro_all.sigma_final[0]) < np.trace(sigma)


def test_detection_changes_nothing_where_the_tool_is_always_seen(default_setup, plan):
    """Inside the image, far from its border, the detection model leaves the rollouts as they were
    (without the orientation and depth terms, whose centimetre position noise carries some
    measurements out of the image)."""
    noise = dataclasses.replace(default_setup.ocp.noise, V_o0=np.zeros((6, 6)),
                                V_d0=np.zeros((6, 6)))
    model = BeliefModel(noise, default_setup.ocp.intrinsics)
    central = plan.copy()
    # the default goal is near the right border: pull the plan toward the centre
    central[:, :2] *= 0.3
    a = rollout(model, central, n=30, rng=4, mode="model", detection=Detection(margin=0.0))
    b = rollout(model, central, n=30, rng=4, mode="model")
    assert a.detected.all()
    np.testing.assert_array_equal(a.final_true, b.final_true)
    np.testing.assert_array_equal(a.sigma_final, b.sigma_final)


@pytest.fixture(scope="module")
def moving():
    """Type 4 (the camera moves four times) at T = 20 and its straight-line plan in each step's
    camera frame."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    setup = build_setup(load_problem(Path(__file__).resolve().parents[1] / "problems"
                                     / "type4_camera_moves.yaml"))
    plan = setup.in_step_frames(straight_line(setup.x_start, setup.x_goal, setup.ocp.horizon))
    return setup, plan


def test_camera_moves_without_noise_follow_the_plan(moving):
    """Zero noise (camera noise too): true and estimated poses are the plan's, frame by frame,
    through the moves."""
    setup, plan = moving
    z = np.zeros((6, 6))
    noise = dataclasses.replace(setup.ocp.noise, W_p0=z, W_o0=z, V_d0=z, V_f0=z, V_o0=z,
                                camera_W_p0=z, camera_W_o0=z)
    model = BeliefModel(noise, setup.ocp.intrinsics)
    changes = setup.camera_changes()
    assert sum(c is not None for c in changes) == 4
    ro = rollout(model, plan, n=3, rng=0, mode="true", keep_paths=True, changes=changes)
    for path in (ro.true_path, ro.estimate_path):
        assert np.abs(path[:, :, :3] - plan[:, :3]).max() < 1e-12
    assert ro.pos_err.max() < 1e-12


def test_camera_moves_match_the_ml_covariance(moving):
    """Model mode through the moves: the rollouts' EKF covariance stays near the plan's
    maximum-likelihood Sigma_T (BeliefModel.propagate with the camera changes, an independent CasADi
    implementation), and the spread of the true errors matches it (filter consistency through the
    moves)."""
    setup, plan = moving
    model, changes = setup.eval_model, setup.camera_changes()
    ro = rollout(model, plan, n=2000, rng=7, mode="model", changes=changes, sample_initial=True)
    ml = model.propagate(plan, changes)[0][-1]
    ekf = ro.sigma_final.mean(axis=0)
    assert abs(np.trace(ekf) / np.trace(ml) - 1) < 0.2
    e = ro.final_error
    assert abs(np.trace(e.T @ e / len(e)) / np.trace(ekf) - 1) < 0.15
    # no moves given: a different (smaller-noise) result, so the moves are not ignored
    still = rollout(model, plan, n=2000, rng=7, mode="model", sample_initial=True)
    assert not np.allclose(still.sigma_final.mean(axis=0), ekf)


def test_measurements_outside_the_image_are_no_detection(default_setup, plan):
    """Gating: with an absurd FOV noise the sampled measurements mostly land outside the image, and
    those steps are predictions only (a camera cannot report a detection outside its own image);
    max_depth bounds depth."""
    noise = dataclasses.replace(default_setup.ocp.noise, V_f0=1e3 * np.eye(6))
    model = BeliefModel(noise, default_setup.ocp.intrinsics)
    central = plan.copy()
    central[:, :2] *= 0.3
    ro = rollout(model, central, n=200, rng=2, mode="model", detection=Detection(margin=0.0))
    assert ro.detected.mean() < 0.6
    # every undetected step of a rollout that never saw the tool left its covariance at the
    # prediction
    never = ~ro.detected.any(axis=1)
    assert never.any()
    m = np_means(central)
    sigma = (np.asarray(model.noise.Sigma0, float)
             + sum(np.asarray(model.motion_noise(m[t], m[t + 1])) for t in range(T)))
    np.testing.assert_allclose(ro.sigma_final[never], np.broadcast_to(sigma, (never.sum(), 6, 6)),
                               rtol=1e-12, atol=1e-18)
    cam = model.camera
    assert Detection(max_depth=0.3).probability(cam, np.array([[0.0, 0.0, 0.35]]))[0] == 0.0


def test_falloff_keeps_the_normal_draws_and_detects_at_its_probability(default_setup, plan):
    """The falloff's uniforms come from their own stream: where the probability is 1 everywhere the
    rollouts are those without falloff, draw for draw; where it is 0.5 (Detection.probability, at
    every true pose of a noise-free rollout) half the steps are detected."""
    z = np.zeros((6, 6))
    noise = dataclasses.replace(default_setup.ocp.noise, W_p0=z, W_o0=z, V_d0=z, V_f0=z, V_o0=z)
    still = BeliefModel(noise, default_setup.ocp.intrinsics)
    cam = still.camera
    central = plan.copy()
    central[:, :2] *= 0.3
    a = rollout(default_setup.eval_model, central, n=30, rng=4, mode="model",
                detection=Detection(margin=0.0))
    b = rollout(default_setup.eval_model, central, n=30, rng=4, mode="model",
                # a ramp too thin to reach any sampled pose
                detection=Detection(margin=0.0, falloff=1e-9))
    np.testing.assert_array_equal(a.detected, b.detected)
    np.testing.assert_array_equal(a.final_true, b.final_true)
    # every waypoint on the ramp, at probability 0.5: u = margin + falloff / 2 of the image width
    det = Detection(margin=0.05, falloff=0.1)
    on_ramp = central.copy()
    on_ramp[:, 0] = (0.10 * cam.width - cam.cx) / cam.fx * on_ramp[:, 2]
    assert np.allclose(det.probability(cam, on_ramp[:, :3]), 0.5)
    ro = rollout(still, on_ramp, n=2000, rng=5, mode="true", detection=det)
    share = ro.detected.mean()  # 12000 Bernoulli(0.5) draws: standard error 0.0046
    assert abs(share - 0.5) < 0.025, share


def test_replan_hook_is_called_at_each_move_with_the_rollouts_own_belief(moving):
    """The hook sees each rollout's EKF mean (its estimate re-expressed in the new camera frame) and
    covariance; returning the waypoints unchanged changes nothing, draw for draw; returning others
    is what the rollouts follow."""
    setup, plan = moving
    model, changes = setup.eval_model, setup.camera_changes()
    ref = rollout(model, plan, n=6, rng=3, mode="true", keep_paths=True, changes=changes,
                  detection=Detection())
    calls = []

    def same(t, mean, cov, waypoints):
        calls.append((t, mean.copy(), cov.copy()))
        np.testing.assert_array_equal(waypoints, np.broadcast_to(plan, waypoints.shape))
        return waypoints

    ro = rollout(model, plan, n=6, rng=3, mode="true", keep_paths=True, changes=changes,
                 detection=Detection(), replan=same)
    np.testing.assert_array_equal(ro.final_true, ref.final_true)
    np.testing.assert_array_equal(ro.sigma_final, ref.sigma_final)
    assert [c[0] for c in calls] == [t for t, c in enumerate(changes) if c is not None]
    for t, mean, cov in calls:
        D = changes[t]
        est = ref.estimate_path[:, t]  # the estimate at waypoint t, before the move
        np.testing.assert_allclose(mean[:, :3], est[:, :3] @ D[:3, :3].T + D[:3, 3], atol=1e-12)
        rot = (Rotation.from_rotvec(mean[:, 3:]).inv() * Rotation.from_matrix(D[:3, :3])
               * Rotation.from_rotvec(est[:, 3:]))
        assert rot.magnitude().max() < 1e-9
        assert cov.shape == (6, 6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    # noise-free: the rollouts follow whatever the hook returns, from the step after the move
    z = np.zeros((6, 6))
    noise = dataclasses.replace(setup.ocp.noise, W_p0=z, W_o0=z, V_d0=z, V_f0=z, V_o0=z,
                                camera_W_p0=z, camera_W_o0=z)
    still = BeliefModel(noise, setup.ocp.intrinsics)
    # per rollout [m]
    offsets = np.array([0.0, 0.002, -0.004])[:, None] * np.array([1.0, -1.0, 0.5])

    def shifted(t, mean, cov, waypoints):
        out = waypoints.copy()
        if t == 3:
            out[:, t + 1:, :3] += offsets[:, None, :]
        return out

    ro = rollout(still, plan, n=3, rng=0, mode="true", keep_paths=True, changes=changes,
                 replan=shifted)
    expect = np.broadcast_to(plan[:, :3], (3, *plan[:, :3].shape)).copy()
    # the first move is before step 3 -> 4: waypoints 4.. moved
    expect[:, 4:] += offsets[:, None, :]
    np.testing.assert_allclose(ro.true_path[:, :, :3], expect, atol=1e-12)


# The rollouts against an independent one-rollout NumPy replay (tests/numpy_rollout.py), and the
# mechanism of the evaluation's worst rollout (issue 16, docs/findings.md, "the worst rollout"): a
# large planned rotation's motion noise `angle^2 W_o0`, W_o0 a multiple of the 6x6 identity, throws
# the tool's *position* out of the view.


@pytest.fixture(scope="module")
def turning_plan(default_setup) -> np.ndarray:
    """The straight line with a 2.4 rad detour of the orientation (0.9-1.4 rad per step, as the
    OCP's first steps) and a small position bump: many rollouts lose the tool, some measurements are
    gated."""
    poses = straight_line(default_setup.x_start, default_setup.x_goal, T)
    bump = np.sin(np.linspace(0, np.pi, T + 1))
    R = Rotation.from_rotvec(poses[:, 3:])
    poses[:, 3:] = (Rotation.from_rotvec(bump[:, None] * np.array([0.0, 2.4, 0.0])) * R).as_rotvec()
    poses[:, :3] += bump[:, None] * np.array([0.004, -0.003, 0.002])
    return poses


@pytest.mark.parametrize("mode", ["model", "true"])
def test_rollouts_match_an_independent_numpy_replay(default_setup, turning_plan, mode):
    """Every rollout's true path, estimate path, covariance and detection flags are the replay's
    from the same normal draws, with the evaluation's detection model (its gating included)."""
    model, cam = default_setup.eval_model, default_setup.eval_model.camera
    det = Detection()
    n = 40
    ro = rollout(model, turning_plan, n=n, rng=5, mode=mode, keep_paths=True, detection=det)
    rng = np.random.default_rng(5)
    z = [rng.standard_normal((n, 6)) for _ in range(2 * T)]  # per step: w's n x 6, then v's
    true_seen = gated = 0
    for k in range(n):
        z_w, z_v = np.array([z[2 * t][k] for t in range(T)]), np.array([z[2 * t + 1][k]
                                                                        for t in range(T)])
        rows = numpy_rollout.replay(turning_plan, model.noise, cam, mode, z_w, z_v,
                                    (det.margin, det.min_depth, det.max_depth))
        for r in rows:
            t = r["t"]
            np.testing.assert_allclose(ro.true_path[k, t + 1, :3], r["true"][:3], rtol=0,
                                       atol=1e-12)
            np.testing.assert_allclose(ro.estimate_path[k, t + 1, :3], r["est"][:3], rtol=0,
                                       atol=1e-12)
            for path, ref in ((ro.true_path, r["true"]), (ro.estimate_path, r["est"])):
                angle = (Rotation.from_rotvec(path[k, t + 1, 3:]).inv()
                         * Rotation.from_rotvec(ref[3:])).magnitude()
                assert angle < 1e-10
            assert ro.detected[k, t] == r["seen"]
            true_seen += r["true_seen"]
            gated += r["true_seen"] and not r["seen"]
        np.testing.assert_allclose(ro.sigma_final[k], rows[-1]["sigma"], rtol=1e-10, atol=1e-16)
        np.testing.assert_allclose(ro.pos_err[k],
                                   np.linalg.norm(rows[-1]["true"][:3] - turning_plan[-1, :3]),
                                   rtol=1e-12, atol=1e-15)
    # the plan exercises every branch: detected steps, undetected true poses, and gated measurements
    assert 0 < ro.detected.sum() < ro.detected.size
    assert true_seen < ro.detected.size and gated > 0


def test_a_pure_rotation_step_moves_the_position_by_angle_sqrt_W_o0(default_setup):
    """Hand-computed: one step that only rotates (by 2 rad) with W_p0 = 0 perturbs the true position
    by 2 sqrt(W_o0) z_w[:3] (the paper's W^{o,0} = 1e-3 I is 6x6: 63 mm std here), and the EKF, not
    detecting (the plan is outside the image), keeps the waypoint and Sigma_0 + 4 W_o0."""
    noise = dataclasses.replace(default_setup.ocp.noise, W_p0=np.zeros((6, 6)))
    model = BeliefModel(noise, default_setup.ocp.intrinsics)
    x0 = np.array([0.3, 0.0, 0.15, 0.0, 0.0, 0.5])  # 30 cm to the right: never detected
    x1 = x0.copy()
    x1[3:] = (Rotation.from_rotvec([2.0, 0.0, 0.0]) * Rotation.from_rotvec(x0[3:])).as_rotvec()
    poses = np.array([x0, x1])
    ro = rollout(model, poses, n=3, rng=11, mode="true", keep_paths=True, detection=Detection())
    z_w = np.random.default_rng(11).standard_normal((3, 6))
    assert not ro.detected.any()
    np.testing.assert_allclose(ro.true_path[:, 1, :3] - x0[:3], 2.0 * np.sqrt(1e-3) * z_w[:, :3],
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ro.estimate_path[:, 1, :3], np.tile(x0[:3], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(ro.sigma_final[0], (1e-2 + 4.0 * 1e-3) * np.eye(6), rtol=1e-12)
