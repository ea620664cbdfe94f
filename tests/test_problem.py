"""Strict loading of problem files: every mistake is a ProblemError naming file and key path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.errors import ProblemError, SurestepError
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.ocp_spec import OcpSpec
from surestep_ocp.problem.scene import Scene
from surestep_ocp.problem.setup import build_setup

PROBLEMS_DIR = Path(__file__).resolve().parents[1] / "problems"


def default_text() -> str:
    return (PROBLEMS_DIR / "needle_regrasp_paper_pace.yaml").read_text()


def load_and_build(path):
    return build_setup(load_problem(path))


def _non_pd_sigma0(tree):
    M = 1e-2 * np.eye(6)
    M[2, 2] = -1e-3  # symmetric, one negative eigenvalue
    tree["noise"]["Sigma0"] = M.tolist()


# (case id, edit of the default tree, expected key path, a word the message must contain)
BAD_FILES = [
    ("unknown_top_level_key", lambda t: t.update(colour="red"), "colour", "unknown key"),
    ("unknown_nested_key", lambda t: t["noise"].update(W_p=1e-3), "noise.W_p", "unknown key"),
    ("wrong_type", lambda t: t.update(horizon="ten"), "horizon", "integer"),
    ("missing_goal", lambda t: t.pop("goal"), "goal", "missing"),
    ("zero_horizon", lambda t: t.update(horizon=0), "horizon", ">= 1"),
    ("negative_horizon", lambda t: t.update(horizon=-3), "horizon", ">= 1"),
    ("non_pd_sigma0", _non_pd_sigma0, "noise.Sigma0", "positive definite"),
    (
        "goal_behind_camera",
        lambda t: t["goal"]["pose"].update(position=[0.0, 0.0, -0.05]),
        "goal.pose",
        "behind the camera",
    ),
    (
        "unreachable_goal",
        lambda t: t["goal"]["pose"].update(position=[0.045, 0.005, 1.115]),
        "goal.pose",
        "not reachable",
    ),
    (
        "orientation_formula",
        lambda t: t["noise"].update(orientation_formula="euclidean"),
        "noise.orientation_formula",
        "cosine, geodesic",
    ),
    ("codegen", lambda t: t["solver"].update(codegen="yes"), "solver.codegen",
     "true, false or auto"),
]


@pytest.mark.parametrize("case, edit, key, words", BAD_FILES, ids=[c[0] for c in BAD_FILES])
def test_bad_problem_file_names_file_and_key(write_problem, case, edit, key, words):
    """A mistake must point at the file and the exact key, not surface later as a solver failure."""
    path = write_problem(edit, name=case)
    with pytest.raises(ProblemError) as info:
        load_and_build(path)
    msg = str(info.value)
    assert path.name in msg
    assert f": {key}:" in msg, msg  # "<file>: <key path>: <what is wrong>"
    assert info.value.key == key
    assert info.value.file == str(path)
    assert words in msg
    assert isinstance(info.value, SurestepError)


def test_missing_file(tmp_path):
    """A missing problem file is a ProblemError naming it (not a bare FileNotFoundError)."""
    path = tmp_path / "no_such_problem.yaml"
    with pytest.raises(ProblemError) as info:
        load_problem(path)
    assert "no_such_problem.yaml" in str(info.value)
    assert "no such file" in str(info.value)


def test_invalid_yaml(tmp_path):
    """Broken YAML syntax is reported with the file name."""
    path = tmp_path / "broken.yaml"
    path.write_text("horizon: [1, 2\nrobot: {")
    with pytest.raises(ProblemError, match="broken.yaml"):
        load_problem(path)


@pytest.mark.parametrize(
    "edit, key",
    [
        (lambda t: t["noise"].update(components=["depth", "colour"]), "noise.components[1]"),
        (lambda t: t["robot"].update(frame="no_such_frame"), "robot.frame"),
        (lambda t: t["robot"].update(urdf="robots/nope.urdf"), "robot.urdf"),
        (lambda t: t["start"].update(joints=[0.1, 0.1, 0.2]), "start.joints"),
        (lambda t: t["start"].update(joints=[0.1, 0.1, 0.9, 0.3, 0.2, 0.1, 0.0]), "start.joints"),
        (lambda t: t["noise"].update(W_o0=-1e-3), "noise.W_o0"),
        (lambda t: t["camera"]["intrinsics"].pop("fy"), "camera.intrinsics.fy"),
        (lambda t: t["goal"]["pose"].update(position=[0.0, 0.1]), "goal.pose.position"),
    ],
    ids=[
        "component",
        "frame",
        "urdf",
        "joint_count",
        "joint_limit",
        "negative_W",
        "missing_fy",
        "short_vector",
    ],
)
def test_more_bad_files(write_problem, edit, key):
    """Other common mistakes are caught with their key path too."""
    path = write_problem(edit, name="more")
    with pytest.raises(ProblemError) as info:
        load_and_build(path)
    assert info.value.key == key
    assert path.name in str(info.value) and key in str(info.value)


def test_frame_error_lists_frames(write_problem):
    """A wrong tracked frame tells the user which frames exist."""
    path = write_problem(lambda t: t["robot"].update(frame="tooltip"), name="frame")
    with pytest.raises(ProblemError) as info:
        load_and_build(path)
    assert "tool" in str(info.value) and "jaw_tip" in str(info.value)


def test_default_problem_values(default_problem, default_setup):
    """The default file is read as written (paper's constants, goal pose, horizon)."""
    p = default_problem
    assert p.horizon == 20
    np.testing.assert_array_equal(p.noise.W_p0, 1e-3 * np.eye(6))
    np.testing.assert_array_equal(p.noise.V_d0, 1e-1 * np.eye(6))
    np.testing.assert_array_equal(p.noise.Sigma0, 1e-2 * np.eye(6))
    assert p.noise.depth_star == 0.15
    assert p.noise.components == ("depth", "fov", "orientation")
    np.testing.assert_allclose(
        default_setup.x_goal, [0.045, 0.005, 0.115, 0.60, 0.10, 1.40], rtol=0, atol=1e-12
    )
    # start given as joints: its pose is their FK; the goal joints reach the goal pose
    np.testing.assert_array_equal(default_setup.q_start, [0.10, 0.10, 0.20, 0.30, 0.20, 0.10, 0.0])
    np.testing.assert_allclose(
        default_setup.pose_of(default_setup.q_goal), default_setup.x_goal, rtol=0, atol=1e-9
    )
    np.testing.assert_allclose(
        default_setup.pose_of(default_setup.q_start), default_setup.x_start, rtol=0, atol=1e-15
    )


def test_a_setup_holds_its_ocp_data_and_scene_not_the_problem(default_problem, default_setup):
    """`build_setup` turns the problem into what the solvers read (`OcpSpec`, the camera
    intrinsics included) and what solution files record (`Scene`); `with_ocp` changes the OcpSpec
    (Sigma_0 into the noise), rebuilds the models and refuses an unknown field."""
    setup = default_setup
    assert not hasattr(setup, "problem")
    assert setup.ocp == OcpSpec.of(default_problem) and setup.scene == Scene.of(default_problem)
    assert setup.ocp.intrinsics == default_problem.camera.intrinsics
    assert setup.scene.robot.urdf == default_problem.robot.urdf_rel
    assert setup.model.camera == setup.ocp.intrinsics and setup.model.noise == setup.ocp.noise
    sigma0 = 2e-3 * np.eye(6)
    changed = setup.with_ocp(horizon=5, smoothness=0.1, sigma0=sigma0)
    assert (changed.ocp.horizon, changed.ocp.smoothness) == (5, 0.1)
    np.testing.assert_array_equal(changed.model.noise.Sigma0, sigma0)
    assert changed.scene is setup.scene and changed.ocp.source == setup.ocp.source
    assert setup.ocp.horizon == default_problem.horizon  # the original unchanged
    with pytest.raises(TypeError, match="unknown field.*intrinsics"):
        setup.with_ocp(intrinsics=setup.ocp.intrinsics)


# Monte-Carlo configuration files (not problems) live in problems/evaluations/, outside this glob
@pytest.mark.parametrize("path", sorted(PROBLEMS_DIR.glob("*.yaml")),
                         ids=lambda p: p.name)
def test_every_shipped_problem_loads_and_builds(path):
    """Every file in problems/ is valid; start and goal are reachable and in front of the camera."""
    problem = load_problem(path)
    setup = build_setup(problem)
    for q, x in ((setup.q_start, setup.x_start), (setup.q_goal, setup.x_goal)):
        assert np.all(q >= setup.robot.lower - 1e-12) and np.all(q <= setup.robot.upper + 1e-12)
        np.testing.assert_allclose(setup.pose_of(q), x, rtol=0, atol=1e-6)
        assert x[2] >= problem.min_depth


def test_unloadable_urdf(write_problem, tmp_path):
    """A URDF Pinocchio cannot parse is a ProblemError at robot.urdf, not a parser traceback."""
    bad = tmp_path / "broken.urdf"
    bad.write_text("<robot name='x'><link name='a'/><joint")
    path = write_problem(lambda t: t["robot"].update(urdf=str(bad)), name="bad_urdf")
    with pytest.raises(ProblemError) as info:
        load_and_build(path)
    assert info.value.key == "robot.urdf" and path.name in str(info.value)


def test_pose_forms_agree(write_problem, default_problem):
    """The four pose forms (minus_z_toward, rpy, axis_angle, matrix) give the same transform."""
    T = default_problem.robot.base_pose
    R = T[:3, :3]
    # minus_z_toward means what it says: the frame's -z axis points at the given point
    d = np.array([0.0, 0.0, -0.2007]) - T[:3, 3]
    np.testing.assert_allclose(R @ [0, 0, -1], d / np.linalg.norm(d), atol=1e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
    forms = {
        "rpy": {
            "position": T[:3, 3].tolist(),
            "rpy": Rotation.from_matrix(R).as_euler("xyz").tolist(),
        },
        "axis_angle": {
            "position": T[:3, 3].tolist(),
            "axis_angle": Rotation.from_matrix(R).as_rotvec().tolist(),
        },
        "matrix": {"matrix": T.tolist()},
    }
    for kind, pose in forms.items():
        path = write_problem(lambda t, pose=pose: t["robot"].update(base_pose=pose), name=kind)
        np.testing.assert_allclose(
            load_problem(path).robot.base_pose, T, rtol=0, atol=1e-12, err_msg=kind
        )


def test_camera_pose_given_directly_equals_ecm(write_problem, default_setup):
    """A camera placed by a 4x4 matrix gives the same set-up as the ECM joints producing it."""
    cam = default_setup.camera_pose

    def edit(tree):
        del tree["camera"]["ecm"]
        tree["camera"]["pose"] = {"matrix": cam.tolist()}

    path = write_problem(edit, name="camera_pose")
    setup = load_and_build(path)
    assert setup.ecm is None
    np.testing.assert_allclose(setup.camera_pose, cam, atol=0)
    np.testing.assert_allclose(setup.x_start, default_setup.x_start, atol=1e-12)
    np.testing.assert_allclose(setup.x_goal, default_setup.x_goal, atol=1e-12)
    np.testing.assert_allclose(setup.pose_of(setup.q_goal), setup.x_goal, atol=1e-9)


def test_unknown_keys_of_mixed_types(tmp_path):
    """Unknown keys YAML reads as numbers (`1:`) next to string ones still give a ProblemError."""
    path = tmp_path / "mixed_keys.yaml"
    path.write_text(default_text() + "1: one\ncolour: red\n")
    with pytest.raises(ProblemError, match="mixed_keys.yaml"):
        load_problem(path)


def test_duplicate_key_rejected(tmp_path):
    """Strict loading: a key written twice (the last silently winning) is an error naming it."""
    path = tmp_path / "duplicate.yaml"
    path.write_text(default_text() + "horizon: 5\n")  # the default file already sets horizon: 20
    with pytest.raises(ProblemError) as info:
        load_problem(path)
    assert "horizon" in str(info.value)
