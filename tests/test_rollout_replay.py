"""The rollouts against an independent one-rollout NumPy replay (tests/numpy_rollout.py), and the mechanism of the
evaluation's worst rollout (issue 16, benchmarks/results/worst_rollout.md): a large planned rotation's motion
noise `angle^2 W_o0`, W_o0 a multiple of the 6x6 identity, throws the tool's *position* out of the view."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy_rollout
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.evaluation.rollout import Detection, rollout
from surestep_ocp.model.belief import BeliefModel
from surestep_ocp.solvers.baseline import straight_line

T = 6


@pytest.fixture(scope="module")
def turning_plan(default_setup) -> np.ndarray:
    """The straight line with a 2.4 rad detour of the orientation (0.9-1.4 rad per step, as the OCP's first steps)
    and a small position bump: many rollouts lose the tool, some measurements are gated."""
    poses = straight_line(default_setup.x_start, default_setup.x_goal, T)
    bump = np.sin(np.linspace(0, np.pi, T + 1))
    R = Rotation.from_rotvec(poses[:, 3:])
    poses[:, 3:] = (Rotation.from_rotvec(bump[:, None] * np.array([0.0, 2.4, 0.0])) * R).as_rotvec()
    poses[:, :3] += bump[:, None] * np.array([0.004, -0.003, 0.002])
    return poses


@pytest.mark.parametrize("mode", ["model", "true"])
def test_rollouts_match_an_independent_numpy_replay(default_setup, turning_plan, mode):
    """Every rollout's true path, estimate path, covariance and detection flags are the replay's from the same
    normal draws, with the evaluation's detection model (its gating included)."""
    model, cam = default_setup.eval_model, default_setup.eval_model.camera
    det = Detection()
    n = 40
    ro = rollout(model, turning_plan, n=n, rng=5, mode=mode, keep_paths=True, detection=det)
    rng = np.random.default_rng(5)
    z = [rng.standard_normal((n, 6)) for _ in range(2 * T)]  # per step: w's n x 6, then v's
    true_seen = gated = 0
    for k in range(n):
        z_w, z_v = np.array([z[2 * t][k] for t in range(T)]), np.array([z[2 * t + 1][k] for t in range(T)])
        rows = numpy_rollout.replay(turning_plan, model.noise, cam, mode, z_w, z_v,
                                    (det.margin, det.min_depth, det.max_depth))
        for r in rows:
            t = r["t"]
            np.testing.assert_allclose(ro.true_path[k, t + 1, :3], r["true"][:3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(ro.estimate_path[k, t + 1, :3], r["est"][:3], rtol=0, atol=1e-12)
            for path, ref in ((ro.true_path, r["true"]), (ro.estimate_path, r["est"])):
                angle = (Rotation.from_rotvec(path[k, t + 1, 3:]).inv() * Rotation.from_rotvec(ref[3:])).magnitude()
                assert angle < 1e-10
            assert ro.detected[k, t] == r["seen"]
            true_seen += r["true_seen"]
            gated += r["true_seen"] and not r["seen"]
        np.testing.assert_allclose(ro.sigma_final[k], rows[-1]["sigma"], rtol=1e-10, atol=1e-16)
        np.testing.assert_allclose(ro.pos_err[k], np.linalg.norm(rows[-1]["true"][:3] - turning_plan[-1, :3]),
                                   rtol=1e-12, atol=1e-15)
    # the plan exercises every branch: detected steps, undetected true poses, and gated measurements
    assert 0 < ro.detected.sum() < ro.detected.size
    assert true_seen < ro.detected.size and gated > 0


def test_a_pure_rotation_step_moves_the_position_by_angle_sqrt_W_o0(default_setup):
    """Hand-computed: one step that only rotates (by 2 rad) with W_p0 = 0 perturbs the true position by
    2 sqrt(W_o0) z_w[:3] (the paper's W^{o,0} = 1e-3 I is 6x6: 63 mm std here), and the EKF, not detecting
    (the plan is outside the image), keeps the waypoint and Sigma_0 + 4 W_o0."""
    noise = dataclasses.replace(default_setup.problem.noise, W_p0=np.zeros((6, 6)))
    model = BeliefModel(noise, default_setup.problem.camera.intrinsics)
    x0 = np.array([0.3, 0.0, 0.15, 0.0, 0.0, 0.5])  # 30 cm to the right: never detected
    x1 = x0.copy()
    x1[3:] = (Rotation.from_rotvec([2.0, 0.0, 0.0]) * Rotation.from_rotvec(x0[3:])).as_rotvec()
    poses = np.array([x0, x1])
    ro = rollout(model, poses, n=3, rng=11, mode="true", keep_paths=True, detection=Detection())
    z_w = np.random.default_rng(11).standard_normal((3, 6))
    assert not ro.detected.any()
    np.testing.assert_allclose(ro.true_path[:, 1, :3] - x0[:3], 2.0 * np.sqrt(1e-3) * z_w[:, :3], rtol=1e-12,
                               atol=1e-15)
    np.testing.assert_allclose(ro.estimate_path[:, 1, :3], np.tile(x0[:3], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(ro.sigma_final[0], (1e-2 + 4.0 * 1e-3) * np.eye(6), rtol=1e-12)
