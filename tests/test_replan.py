"""Moving camera: the belief follows the camera exactly; re-planning runs end to end."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.model.belief import BeliefModel, NoiseParams, unvech, vech
from surestep_ocp.model.camera import Intrinsics
from surestep_ocp.model.lie import matrix_to_pose, np_exp, np_means, np_poses, pose_to_matrix
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.spec import CameraMove
from surestep_ocp.methods.camera_move_replan import replan_after_camera_moves
from surestep_ocp.problem.setup import build_setup

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
CAMERA = Intrinsics(fx=769.0, fy=769.0, cx=320.0, cy=240.0, width=640, height=480)


def random_move(rng) -> np.ndarray:
    D = np.eye(4)
    D[:3, :3] = np_exp(rng.normal(scale=0.2, size=3))
    D[:3, 3] = rng.normal(scale=0.02, size=3)
    return D


@pytest.mark.parametrize("seed", range(5))
def test_camera_move_changes_the_belief_by_the_camera_transform(seed):
    """Without camera noise the mean moves by exactly D and the covariance of the tangent error
    rotates with the frame: checked by central differences of the map on perturbed poses (left
    perturbations `exp(e) R`)."""
    rng = np.random.default_rng(seed)
    noise = NoiseParams(camera_W_p0=np.zeros((6, 6)), camera_W_o0=np.zeros((6, 6)))
    model = BeliefModel(noise, CAMERA)
    x = np.array([0.01, -0.02, 0.14, 0.4, 0.2, 1.3])
    A = rng.normal(size=(6, 6))
    S = A @ A.T * 1e-4
    D = random_move(rng)
    mn, sn = model.camera_change(np_means(x)[0], vech(S), D)
    np.testing.assert_allclose(pose_to_matrix(np_poses(mn)[0]), D @ pose_to_matrix(x), atol=1e-12)
    Sn = unvech(sn)
    np.testing.assert_allclose(Sn[:3, :3], D[:3, :3] @ S[:3, :3] @ D[:3, :3].T, atol=1e-15)

    def moved(e):  # the new camera-frame pose of the perturbed pose (p + e_p, exp(e_r) R)
        R = Rotation.from_rotvec(e[3:]) * Rotation.from_rotvec(x[3:])
        M = D @ pose_to_matrix(np.r_[x[:3] + e[:3], R.as_rotvec()])
        return M[:3, 3], Rotation.from_matrix(M[:3, :3])

    R0 = moved(np.zeros(6))[1]
    h = 1e-6
    J = np.column_stack([np.r_[(moved(h * e)[0] - moved(-h * e)[0]) / (2 * h),
                               ((moved(h * e)[1] * R0.inv()).as_rotvec()
                                - (moved(-h * e)[1] * R0.inv()).as_rotvec())
                               / (2 * h)] for e in np.eye(6)])
    np.testing.assert_allclose(Sn, J @ S @ J.T, rtol=1e-6, atol=1e-12)


def test_camera_move_adds_its_motion_noise():
    """A camera move adds |t|^2 camera_W_p0 + angle^2 camera_W_o0 on top of the transformed
    covariance."""
    rng = np.random.default_rng(7)
    D = random_move(rng)
    quiet = BeliefModel(NoiseParams(camera_W_p0=np.zeros((6, 6)), camera_W_o0=np.zeros((6, 6))),
                        CAMERA)
    noisy = BeliefModel(NoiseParams(camera_W_p0=2e-3 * np.eye(6), camera_W_o0=3e-3 * np.eye(6)),
                        CAMERA)
    x, s = np.array([0.0, 0.0, 0.15, 0.3, 0.3, 1.0]), vech(1e-4 * np.eye(6))
    m = np_means(x)[0]
    diff = unvech(noisy.camera_change(m, s, D)[1]) - unvech(quiet.camera_change(m, s, D)[1])
    angle = np.linalg.norm(matrix_to_pose(D)[3:])
    np.testing.assert_allclose(diff, (np.sum(D[:3, 3] ** 2) * 2e-3 + angle**2 * 3e-3) * np.eye(6),
                               atol=1e-15)


def test_replan_runs_and_beats_the_plan_made_once(tmp_path):
    """`replan` on a short Type 4 problem: every re-plan succeeds; the executed trajectory meets the
    goal."""
    problem = load_problem(PROBLEMS / "type4_camera_moves.yaml")
    moves = tuple(CameraMove(step, m.ecm_joints)
                  for step, m in zip((3, 6), problem.camera.moves[1::2]))
    problem = replace(problem, horizon=8, camera=replace(problem.camera, moves=moves))
    setup = build_setup(problem)
    res = replan_after_camera_moves(setup, tmp_path)
    assert [p.method for p in res["plans"]] == ["ocp-replan-3", "ocp-replan-6"]
    assert all(p.success for p in res["plans"])
    executed, once = res["executed"], res["once"]
    err_m, err_rad = executed.terminal_error
    assert err_m < 1e-6 and err_rad < 1e-6
    assert executed.trace_final <= once.trace_final * (1 + 1e-9)
    for name in ("replan.md", "replan.json", "ocp-replanned.json", "ocp-once.json",
                 "baseline.json"):
        assert (tmp_path / name).is_file()
