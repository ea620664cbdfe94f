"""The belief-space OCP on the default problem (horizon shortened to 8), checked independently.

One IPOPT solve per module. Poses are re-derived with Pinocchio, covariances with
the plain NumPy EKF of tests/numpy_ekf.py, and the saved JSON is read back as
plain JSON.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from surestep_ocp.model.belief import COSINE_GUARD
import numpy_ekf as ref
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.methods.baseline import solve_baseline
from surestep_ocp.ocp.straight_line import straight_line
from surestep_ocp.ocp.iterate import InitialGuess
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.output.solution import Solution

T = 8
# [rad^2] the package's guard of |r| in the cosine formula (section 4: "guard it")
GUARD = COSINE_GUARD


@pytest.fixture(scope="module")
def setup(default_problem):
    return build_setup(dataclasses.replace(default_problem, horizon=T))


@pytest.fixture(scope="module")
def baseline(setup):
    return solve_baseline(setup)


@pytest.fixture(scope="module")
def solution(setup):
    q_best, ok, _, _ = setup.joints_along(
        straight_line(setup.x_start, setup.x_goal, T), setup.q_start
    )
    assert ok.all(), "the straight line of the default problem should be reachable (initial guess)"
    return solve_ocp(setup, InitialGuess(q_best, "baseline"))


def _angle(ra, rb) -> float:
    return float((Rotation.from_rotvec(ra).inv() * Rotation.from_rotvec(rb)).magnitude())


def test_solve_succeeds(solution):
    """IPOPT converges; a silent failure would make every other number meaningless."""
    assert solution.success, solution.status
    assert solution.status == "Solve_Succeeded"
    assert solution.method == "ocp"
    assert solution.horizon == T
    assert solution.iterations > 0
    assert solution.run.init == "baseline"
    assert solution.run.constraint_violation < 1e-8


def test_waypoints_are_forward_kinematics_of_joints(solution, setup):
    """Every waypoint is where the arm really is: the camera-frame pose of Pinocchio FK of its q."""
    model = pin.buildModelFromUrdf(str(setup.robot.urdf))
    data = model.createData()
    fid = model.getFrameId(setup.scene.robot.frame)
    T_cam_base = np.linalg.inv(setup.camera_pose) @ setup.scene.robot.base_pose
    q, poses = np.asarray(solution.q), np.asarray(solution.poses)
    assert q.shape == (T + 1, setup.robot.nq) and poses.shape == (T + 1, 6)
    for qt, xt in zip(q, poses, strict=True):
        np.testing.assert_allclose(setup.pose_of(qt), xt, rtol=0, atol=1e-9)
        # independent of the package: Pinocchio directly (the PSM has no continuous joints)
        pin.framesForwardKinematics(model, data, qt)
        M = T_cam_base @ data.oMf[fid].homogeneous
        np.testing.assert_allclose(M[:3, 3], xt[:3], rtol=0, atol=1e-9)
        assert _angle(Rotation.from_matrix(M[:3, :3]).as_rotvec(), xt[3:]) < 1e-9


def test_joints_inside_limits_and_start_fixed(solution, setup):
    """The plan is executable: joint limits hold, it starts at q_start, the jaw never moves."""
    q = np.asarray(solution.q)
    lo, hi = setup.robot.lower, setup.robot.upper
    assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)
    np.testing.assert_allclose(q[0], setup.q_start, rtol=0, atol=1e-12)
    jaw = setup.robot.joint_names.index("jaw")
    np.testing.assert_allclose(q[:, jaw], setup.q_start[jaw], rtol=0, atol=1e-12)
    assert np.all(np.asarray(solution.poses)[:, 2] >= setup.ocp.min_depth - 1e-9)


def test_terminal_pose_is_the_goal(solution, setup):
    """The hard terminal equality mu_T = x^G (no clipping action) holds on the executed pose."""
    x_T, g = np.asarray(solution.poses[-1]), setup.x_goal
    assert np.linalg.norm(x_T[:3] - g[:3]) <= 1e-6
    assert _angle(x_T[3:], g[3:]) <= 1e-6
    np.testing.assert_allclose(solution.goal, g, rtol=0, atol=0)
    np.testing.assert_allclose(solution.poses[0], setup.x_start, rtol=0, atol=1e-9)
    d_m, d_rad = solution.terminal_error
    assert d_m <= 1e-6 and d_rad <= 1e-6


def test_trace_equals_numpy_ekf(solution, setup):
    """The reported Tr(Sigma_t) is the textbook EKF along the executed poses, all components."""
    noise = setup.ocp.noise
    sig, _ = ref.propagate(
        np.asarray(solution.poses),
        noise,
        setup.ocp.intrinsics,
        ref.ALL_COMPONENTS,
        guard=GUARD,
    )
    trace = np.array([np.trace(s) for s in sig])
    np.testing.assert_allclose(solution.trace, trace, rtol=1e-9, atol=0)
    assert ref.rel_err(solution.sigma_final, sig[-1]) < 1e-9
    assert ref.rel_err(solution.sigma[-1], sig[-1]) < 1e-9
    assert solution.trace_final == pytest.approx(trace[-1], rel=1e-9)


def test_ocp_objective_is_the_exact_ekf_trace(solution):
    """Free Joseph-form gains end at Kalman's: the OCP's own Tr(Sigma_T) is the exact one."""
    assert solution.objective == pytest.approx(solution.trace_final, rel=1e-6)
    assert solution.run.ocp_trace_final == pytest.approx(solution.trace_final, rel=1e-6)


def test_beats_straight_line_baseline(solution, baseline, setup):
    """The point of SURESTEP: a smaller final covariance than the straight line to the same goal."""
    assert baseline.horizon == T
    sig_b, _ = ref.propagate(
        np.asarray(baseline.poses),
        setup.ocp.noise,
        setup.ocp.intrinsics,
        guard=GUARD,
    )
    assert baseline.trace_final == pytest.approx(np.trace(sig_b[-1]), rel=1e-9)
    assert solution.trace_final < baseline.trace_final
    # the two plans share their endpoints
    np.testing.assert_allclose(baseline.poses[0], solution.poses[0], atol=1e-9)
    np.testing.assert_allclose(baseline.poses[-1], solution.poses[-1], atol=1e-6)


REQUIRED_KEYS = [
    "method",
    "problem",
    "success",
    "status",
    "solve_time_s",
    "iterations",
    "horizon",
    "joint_names",
    "q",
    "poses",
    "goal",
    "camera",
    "camera_pose",
    "robot",
    "noise",
    "trace",
    "sigma_final",
    "objective",
]


def test_saved_json_has_documented_keys(solution, setup, tmp_path):
    """Downstream tools read the solution file: every documented key is there, well formed."""
    path = solution.save(tmp_path / "sol" / "ocp.json")
    d = json.loads(path.read_text())
    missing = [k for k in REQUIRED_KEYS if k not in d]
    assert not missing, missing
    assert d["method"] == "ocp" and d["success"] is True and isinstance(d["status"], str)
    assert d["problem"].endswith("needle_regrasp_paper_pace.yaml")
    assert isinstance(d["solve_time_s"], float) and d["solve_time_s"] >= 0
    assert isinstance(d["iterations"], int) and d["horizon"] == T
    assert d["joint_names"] == [
        "yaw",
        "pitch",
        "insertion",
        "roll",
        "wrist_pitch",
        "wrist_yaw",
        "jaw",
    ]
    assert (
        np.shape(d["q"]) == (T + 1, 7)
        and np.shape(d["poses"]) == (T + 1, 6)
        and np.shape(d["goal"]) == (6,)
    )
    assert set(d["camera"]) >= {"fx", "fy", "cx", "cy", "width", "height"}
    assert d["camera"]["fx"] == pytest.approx(768.98551924) and d["camera"]["width"] == 640
    assert np.shape(d["camera_pose"]) == (4, 4)
    np.testing.assert_allclose(d["camera_pose"], setup.camera_pose, atol=0)
    assert set(d["robot"]) >= {"urdf", "frame", "base_pose"}
    assert d["robot"]["urdf"] == "robots/psm.urdf" and d["robot"]["frame"] == "tool"
    assert np.shape(d["robot"]["base_pose"]) == (4, 4)
    assert set(d["noise"]) >= {
        "W_p0",
        "W_o0",
        "V_d0",
        "V_f0",
        "V_o0",
        "Sigma0",
        "depth_star",
        "o_star",
        "components",
    }
    assert d["noise"]["W_p0"] == pytest.approx(1e-3) and d["noise"]["Sigma0"] == pytest.approx(1e-2)
    assert d["noise"]["depth_star"] == pytest.approx(0.15) and d["noise"][
        "o_star"
    ] == pytest.approx([0.4, 0.4, 1.53])
    assert d["noise"]["components"] == ["depth", "fov", "orientation"]
    assert len(d["trace"]) == T + 1 and np.shape(d["sigma_final"]) == (6, 6)
    assert d["trace"][-1] == pytest.approx(np.trace(d["sigma_final"]), rel=1e-12)
    assert isinstance(d["objective"], float)
    # no temporary files left beside it (atomic write), and it loads back unchanged
    assert sorted(p.name for p in path.parent.iterdir()) == ["ocp.json"]
    back = Solution.load(path)
    assert back.trace == solution.trace and back.q == solution.q and back.poses == solution.poses
