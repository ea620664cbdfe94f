"""The camera registration of a re-plan within the limits (surestep_ocp/methods/registration.py):
where the tracker's estimate puts the goal beyond a joint limit, the nearest estimate its belief
allows (Mahalanobis metric) that keeps the goal within reach is registered.

References outside the code under test: SciPy's trust-region least squares for the projection's
minimum, Pinocchio's numeric kinematics for the goal's reach, the Mahalanobis distance recomputed
from the registered camera.
"""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

import surestep_ocp as ss
from surestep_ocp.evaluation.closed_loop import robot_pace
from surestep_ocp.methods import registration as rg
from surestep_ocp.model.lie import pose_to_matrix
from surestep_ocp.problem.setup import build_setup


@pytest.fixture(scope="module")
def easy():
    # Type 1 easy: the goal's insertion 5 mm inside its upper limit
    return build_setup(ss.load_problem("problems/type1_easy.yaml"))


def _error(Ta, Tb):
    """The tracker's error coordinates (p_a - p_b, log(R_a R_b^T))."""
    return np.hstack([Ta[:3, 3] - Tb[:3, 3],
                      Rotation.from_matrix(Ta[:3, :3] @ Tb[:3, :3].T).as_rotvec()])


def _random_case(setup, rng):
    mean = setup.pose_of(setup.q_start) + np.hstack([rng.normal(0, 0.01, 3),
                                                     rng.normal(0, 0.02, 3)])
    B = rng.normal(size=(6, 6))
    return pose_to_matrix(mean), B @ B.T * 1e-5 + 1e-6 * np.eye(6)


def test_the_projection_is_scipys_bounded_least_squares_minimum(easy):
    """30 random estimates and covariances: the bounded Gauss-Newton's minimum equals SciPy's
    trust-region reflective method's on the same residual (its own finite-difference Jacobian),
    to 1e-8 relative; the joints lie within the limits less MARGIN; a third of the cases or more
    have a bound active (the cases the registration is for)."""
    robot = easy.robot
    mov = np.array(robot.supporting_joints())
    span = robot.upper[mov] - robot.lower[mov]
    lo, hi = robot.lower[mov] + rg.MARGIN * span, robot.upper[mov] - rg.MARGIN * span
    A = pose_to_matrix(easy.x_goal)
    F0 = robot.frame_pose(easy.q_start)  # Pinocchio: the tool at q0 in the URDF root
    rng = np.random.default_rng(1)
    active = 0
    for _ in range(30):
        M, cov = _random_case(easy, rng)
        q, m, d2 = rg.nearest_reaching(easy, easy.q_start, M, cov, easy.q_goal)
        L_inv = np.linalg.inv(np.linalg.cholesky(cov))

        def residual(x):
            q_full = np.array(easy.q_goal, float)
            q_full[mov] = x
            # m(q) = A F(q)^-1 F0 with Pinocchio's F
            return L_inv @ _error(A @ np.linalg.inv(robot.frame_pose(q_full)) @ F0, M)

        ref = least_squares(residual, np.clip(easy.q_goal[mov], lo, hi), bounds=(lo, hi),
                            xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert d2 == pytest.approx(float(ref.fun @ ref.fun), rel=1e-8, abs=1e-10)
        assert np.all(q[mov] >= lo - 1e-12) and np.all(q[mov] <= hi + 1e-12)
        np.testing.assert_allclose(m, A @ np.linalg.inv(robot.frame_pose(q)) @ F0, atol=1e-9)
        active += bool(np.any((q[mov] <= lo + 1e-9) | (q[mov] >= hi - 1e-9)))
    assert active >= 10


def _deeper_estimate(setup, q1, depth):
    """An estimate at joints q1 seen `depth` [m] nearer the camera than the kinematics say: the
    camera registered to it puts the goal deeper, beyond the insertion limit."""
    mean = np.array(setup.pose_of(q1), float)
    mean[2] -= depth
    return mean


@pytest.mark.parametrize("sigma, beyond_gate", [(0.01, False), (0.001, True)])
def test_a_replan_registers_the_nearest_estimate_that_reaches_the_goal(sigma, beyond_gate):
    """Type 1 easy at its first re-plan, the estimate 2 cm nearer the camera (its goal beyond the
    insertion limit: IK from 50 random starts ends over 0.1 mm from it). With a 1 cm
    standard deviation the belief allows the goal within reach: the re-plan registers the nearest
    such estimate, within the gate, and its goal joints (inside the limits) put the tool on the goal
    as that camera sees it (Pinocchio); its Mahalanobis distance recomputed from the registered
    camera is the one recorded. With 1 mm the belief rules it out (beyond the gate): the nearest
    estimate is registered all the same, nearer the belief than the held registration's."""
    problem = robot_pace(ss.load_problem("problems/type1_easy.yaml"))
    planner = ss.Planner(problem, prebuild=False)
    setup = planner.setup
    q1 = planner.executed_state(1)[0]
    mean = _deeper_estimate(setup, q1, 0.02)
    tracker = rg.registered_to(setup, q1, pose_to_matrix(mean))
    _, res_m, _ = tracker.joints_for(setup.x_goal, setup.q_goal, raise_on_fail=False, restarts=50)
    assert res_m > 1e-3
    cov = sigma**2 * np.eye(6)

    sol = planner.replan(mean, cov, step=1)
    assert sol.success
    assert sol.extras["goal_ik_residual"]["m"] > 1e-4
    record = sol.replan
    assert not record.registration_held
    d2 = record.registration_constrained
    assert 0 < d2 and (d2 > rg.GATE) == beyond_gate
    # the held registration (the first plan's: none) is the estimate at q1 through the given camera,
    # 2 cm from the mean in depth alone: the projection is nearer the belief
    assert d2 <= 0.02**2 / sigma**2
    robot, q_goal = setup.robot, np.array(sol.q[-1], float)
    assert np.all(q_goal >= robot.lower) and np.all(q_goal <= robot.upper)
    # the registered camera, recovered from the plan: the kinematics at q1 show the tool at m
    camera = setup.camera_pose @ planner._registration
    world_base = setup.camera_pose @ setup.T_cam_base  # the URDF root in the world
    tool_1 = np.linalg.inv(camera) @ world_base @ robot.frame_pose(q1)
    np.testing.assert_allclose(_error(tool_1, pose_to_matrix(mean)) @ np.linalg.solve(
        cov, _error(tool_1, pose_to_matrix(mean))), d2, rtol=1e-6)
    goal = np.linalg.inv(camera) @ world_base @ robot.frame_pose(q_goal)
    np.testing.assert_allclose(_error(goal, pose_to_matrix(setup.x_goal)), 0, atol=1e-6)
