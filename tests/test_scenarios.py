"""The paper's scenarios: a needle as the tracked object, a goal relative to another arm, any
robot."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from surestep_ocp.model.lie import pose_to_matrix
from surestep_ocp.methods.registry import run_method
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"


def test_needle_pose_is_jaw_pose_composed_with_grasp():
    """The tracked needle's pose equals Pinocchio's jaw-frame pose times the grasp transform,
    symbolically too."""
    setup = build_setup(load_problem(PROBLEMS / "type2_needle_arm_moves.yaml"))
    robot, grasp = setup.robot, setup.scene.robot.grasp
    rng = np.random.default_rng(4)
    fk = robot.fk_function()
    for _ in range(10):
        q = rng.uniform(robot.lower, robot.upper)
        pin.framesForwardKinematics(robot.model, robot.data, robot.to_pinocchio(q))
        expected = robot.data.oMf[robot.model.getFrameId("tool")].homogeneous @ grasp
        np.testing.assert_allclose(robot.frame_pose(q), expected, atol=1e-12)
        p, R = fk(q)
        np.testing.assert_allclose(np.asarray(p).ravel(), expected[:3, 3], atol=1e-12)
        np.testing.assert_allclose(np.asarray(R), expected[:3, :3], atol=1e-12)
        # and the camera-frame pose used by the OCP
        np.testing.assert_allclose(
            pose_to_matrix(setup.pose_of(q)),
            np.linalg.inv(setup.camera_pose) @ robot.base_pose @ expected, atol=1e-10)


def test_relative_goal_resolves_to_the_absolute_pose():
    """A goal given on the other arm's needle is that needle's pose composed with the relative
    pose."""
    problem = load_problem(PROBLEMS / "type1_medium.yaml")
    setup = build_setup(problem)
    rel = problem.goal.relative
    other = setup.other_arms[0]
    pin.framesForwardKinematics(other.model, other.data, other.to_pinocchio(rel.arm.joints))
    T_needle = (rel.arm.base_pose @ other.data.oMf[other.model.getFrameId("tool")].homogeneous
                @ rel.arm.grasp)
    expected = np.linalg.inv(setup.camera_pose) @ T_needle @ pose_to_matrix(rel.pose)
    np.testing.assert_allclose(pose_to_matrix(setup.x_goal), expected, atol=1e-9)
    # the regrasping arm reaches it: its goal joints give that pose
    np.testing.assert_allclose(pose_to_matrix(setup.pose_of(setup.q_goal)), expected, atol=1e-8)


def test_dim_light_scales_the_observation_noise():
    """type1_hard is type1_medium with every observation constant four times larger."""
    hard, medium = (load_problem(PROBLEMS / "type1_hard.yaml"),
                    load_problem(PROBLEMS / "type1_medium.yaml"))
    for k in ("V_d0", "V_f0", "V_o0"):
        np.testing.assert_allclose(getattr(hard.noise, k), 4 * getattr(medium.noise, k))
    np.testing.assert_allclose(hard.noise.W_p0, medium.noise.W_p0)


@pytest.fixture(scope="module")
def ur5_solutions():
    problem = replace(load_problem(PROBLEMS / "ur5_fixed_camera.yaml"), horizon=6)
    setup = build_setup(problem)
    return setup, run_method(setup, "baseline"), run_method(setup, "ocp")


def test_example_robot_data_arm_solves(ur5_solutions):
    """Nothing is PSM-specific: a UR5 from example-robot-data plans, meets the goal and beats the
    line."""
    setup, base, ocp = ur5_solutions
    assert ocp.success, ocp.status
    err_m, err_rad = ocp.terminal_error
    assert err_m < 1e-6 and err_rad < 1e-6
    assert ocp.trace_final < base.trace_final
    for q, x in zip(ocp.q, ocp.poses):
        np.testing.assert_allclose(setup.pose_of(np.array(q)), x, atol=1e-9)
