"""The Python API without surprises (issue 29 item 5): the README's goal is a new one and the plan
ends there, one pose form everywhere, keyword errors that name the valid keywords, the minimal
`problem_from_dict`, `Problem ==`, every error of a file at once, `ss.export` of a Solution
object."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

import surestep_ocp as ss
from surestep_ocp.cli import main

REPO = Path(__file__).resolve().parents[1]
FILE = REPO / "problems" / "needle_regrasp_paper_pace.yaml"
TREE = yaml.safe_load(FILE.read_text())


@pytest.fixture(scope="module")
def problem():
    return ss.load_problem(FILE)


def _rotation(r) -> np.ndarray:
    """Rodrigues' formula (independent of the package's Lie helpers)."""
    r = np.asarray(r, float)
    a = np.linalg.norm(r)
    k = r / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _tool_in_camera(problem, sol) -> np.ndarray:
    """The last waypoint's tool pose in the camera frame by Pinocchio's forward kinematics of the
    URDF, from the solution's joints and camera pose and the file's base pose (not the package's
    kinematics)."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(problem.robot.urdf))
    data = model.createData()
    pin.framesForwardKinematics(model, data, np.asarray(sol.joints[-1], float))
    tool = data.oMf[model.getFrameId("tool")].homogeneous
    return np.linalg.inv(np.asarray(sol.camera_pose)) @ problem.robot.base_pose @ tool


def test_the_readme_example_changes_the_goal_and_the_plan_ends_there(problem):
    text = (REPO / "README.md").read_text()
    block = text[text.index("```python", text.index("### Python API")):]
    goal = json.loads(re.search(r"with_goal\(pose=(\[[^\]]*\])\)", block).group(1))
    assert not np.allclose(goal, problem.goal.pose, atol=1e-3), ("the README's goal must "
                                                                 "differ from the file's")
    changed = problem.with_goal(pose=goal).with_noise(Sigma0=2e-2).with_horizon(20)
    assert changed != problem and changed.noise != problem.noise
    np.testing.assert_array_equal(changed.goal.pose, goal)
    sol = ss.solve(changed, method="ocp")
    assert sol.success, sol.status
    T = _tool_in_camera(problem, sol)
    np.testing.assert_allclose(T[:3, 3], goal[:3], atol=1e-6)
    np.testing.assert_allclose(T[:3, :3], _rotation(goal[3:]), atol=1e-6)
    before = ss.solve(problem, method="ocp")
    assert abs(sol.trace_final - before.trace_final) > 1e-3 * before.trace_final  # a different plan


GOAL = [0.035, -0.010, 0.110, 0.6, 0.1, 1.4]


def test_one_pose_form_everywhere(problem, tmp_path):
    mapping = {"position": GOAL[:3], "axis_angle": GOAL[3:]}
    forms = [problem.with_goal(pose=GOAL), problem.with_goal(pose=np.array(GOAL)),
             problem.with_goal(pose=mapping),
             problem.with_goal(position=GOAL[:3], axis_angle=GOAL[3:]),
             ss.problem_from_dict({**TREE, "goal": {"pose": GOAL}}, FILE),
             ss.problem_from_dict({**TREE, "goal": {"pose": mapping}}, FILE)]
    path = tmp_path / "flat.yaml"
    tree = copy.deepcopy(TREE)
    tree["goal"] = {"pose": GOAL}
    tree["robot"]["urdf"] = str(REPO / "robots" / "psm.urdf")
    tree["camera"]["ecm"]["urdf"] = str(REPO / "robots" / "ecm.urdf")
    path.write_text(yaml.safe_dump(tree))
    forms.append(ss.load_problem(path))
    for p in forms:
        np.testing.assert_array_equal(p.goal.pose, GOAL)
    assert all(p.goal == forms[0].goal for p in forms)
    # a world pose too: the list of 6 is position and axis-angle
    T = ss.problem_from_dict({**TREE, "robot": {**TREE["robot"],
                                                "base_pose": [0.1, 0.0, -0.02, 0.3, -0.2, 0.1]}},
                             FILE).robot.base_pose
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.0, -0.02])
    np.testing.assert_allclose(T[:3, :3], _rotation([0.3, -0.2, 0.1]), atol=1e-12)
    cam = problem.with_camera_pose([0.0, 0.0, -0.05, np.pi, 0.0, 0.0]).camera.pose
    np.testing.assert_allclose(cam[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    with pytest.raises(ss.ProblemError, match=r"goal\.pose: expected 6 numbers"):
        ss.problem_from_dict({**TREE, "goal": {"pose": GOAL[:4]}}, FILE)
    with pytest.raises(ss.ProblemError, match=r"goal\.pose\[4\]: expected a number"):
        ss.problem_from_dict({**TREE, "goal": {"pose": [*GOAL[:4], "x", 0.0]}}, FILE)


@pytest.mark.parametrize("call, says", [
    (lambda p: p.with_goal(positon=[0.04, 0.0, 0.11]),
     "unexpected keyword argument 'positon'; valid keywords: "
                                                       "pose, joints, position, axis_angle"),
    (lambda p: p.with_start(orientation=[0, 0, 1]),
     "valid keywords: pose, joints, position, axis_angle"),
    (lambda p: p.with_goal(position=[0.04, 0.0, 0.11]), "go together"),
    (lambda p: p.with_goal(pose=GOAL, joints=[0.0] * 7), "exactly one of"),
    (lambda p: p.with_goal(), "got none"),
])
def test_keyword_errors_name_the_valid_keywords(problem, call, says):
    with pytest.raises(TypeError, match=re.escape(says)):
        call(problem)


def test_keyword_errors_of_the_sections_name_the_allowed_keys(problem):
    with pytest.raises(ss.ProblemError, match="noise.V_dd: unknown key; allowed keys here: .*V_d0"):
        problem.with_noise(V_dd=1.0)
    with pytest.raises(ss.ProblemError,
                       match="solver.speed: unknown key; allowed keys here: .*max_iter"):
        problem.with_solver(speed=3)


def test_the_minimal_problem_dict_is_documented_and_solves(tmp_path, monkeypatch):
    from surestep_ocp.problem.load import MINIMAL_PROBLEM

    readme = (REPO / "problems" / "README.md").read_text()
    block = readme[readme.index("```python", readme.index("## A problem built in Python")):]
    block = block[len("```python"):block.index("```", 3)]
    monkeypatch.chdir(tmp_path)  # the shipped URDF is found from any folder
    scope: dict = {}
    exec(compile(block, "problems/README.md", "exec"), scope)  # noqa: S102 - the documented example itself
    documented = scope["problem"]
    assert documented == ss.problem_from_dict(MINIMAL_PROBLEM)
    from surestep_ocp.model.belief import NoiseParams
    from surestep_ocp.problem.spec import LimitsSpec, SolverSpec, TimingSpec

    assert documented.noise == NoiseParams() and documented.solver == SolverSpec()  # the defaults
    assert documented.timing == TimingSpec() and documented.limits == LimitsSpec()
    sol = ss.solve(documented.with_horizon(6), "ocp")
    assert sol.success
    T = _tool_in_camera(documented, sol)
    goal = MINIMAL_PROBLEM["goal"]["pose"]
    np.testing.assert_allclose(T[:3, 3], goal[:3], atol=1e-6)
    np.testing.assert_allclose(T[:3, :3], _rotation(goal[3:]), atol=1e-6)
    for key in ("robot", "camera", "start", "goal", "horizon"):  # each of the five is needed
        with pytest.raises(ss.ProblemError, match=rf"^<python>: {key}: missing required key"):
            ss.problem_from_dict({k: v for k, v in MINIMAL_PROBLEM.items() if k != key})


def test_problems_compare_by_value(problem):
    again = ss.load_problem(FILE)
    assert again == problem and hash(again) == hash(problem) and not (again != problem)
    assert len({again, problem}) == 1
    assert problem.with_noise(Sigma0=2e-2) != problem
    assert problem.with_goal(pose=GOAL) != problem
    assert problem.with_goal(pose=list(problem.goal.pose)) == problem  # the same goal given again
    assert problem.with_horizon(20) == problem and problem.with_horizon(19) != problem
    assert (problem != "a problem" and problem.camera == again.camera
            and problem.robot == again.robot)


def test_every_error_of_a_file_at_once(tmp_path, capsys):
    tree = copy.deepcopy(TREE)
    tree["robot"]["urdf"] = str(REPO / "robots" / "psm.urdf")
    tree["camera"]["ecm"]["urdf"] = str(REPO / "robots" / "ecm.urdf")
    tree["noise"]["V_dd"] = 1.0  # 1
    tree["horizon"] = "long"  # 2
    tree["solver"]["name"] = "fast"  # 3
    tree["extra"] = 1  # 4
    del tree["start"]  # 5
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    with pytest.raises(ss.ProblemErrors) as info:
        ss.load_problem(path)
    keys = [e.key for e in info.value.errors]
    assert sorted(keys) == sorted(["noise.V_dd", "horizon", "solver.name", "extra", "start"]), keys
    assert isinstance(info.value, ss.ProblemError) and info.value.key == keys[0]
    assert "\n" not in str(info.value) and "and 4 more errors" in str(info.value)
    # fixing one leaves the others: the same lines less one
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 5 and all(ln.startswith(f"error {path}: ") for ln in lines), lines
    assert {ln.split(": ")[1] for ln in lines} == set(keys)
    assert main(["solve", str(path)]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 5 and all(ln.startswith(f"surestep: {path}: ") for ln in lines), lines
    # one error: one ProblemError as before
    one = copy.deepcopy(TREE)
    one["horizon"] = 0
    with pytest.raises(ss.ProblemError) as info:
        ss.problem_from_dict(one)
    assert type(info.value) is ss.ProblemError and info.value.key == "horizon"


def test_export_beside_solve(problem, tmp_path):
    sol = ss.solve(problem.with_horizon(6), "ocp")
    traj, files = ss.export(sol, "json", tmp_path / "from_object.json")
    assert files == [tmp_path / "from_object.json"]  # no plot unless asked
    sol.save(tmp_path / "sol.json")
    assert main(["export", str(tmp_path / "sol.json"), "--format", "json", "--output",
                 str(tmp_path / "from_file.json"), "--no-plot"]) == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("from_object.json", "from_file.json"))
    strip = lambda d: {k: v for k, v in d.items() if k not in ("source", "meta")}  # noqa: E731
    assert strip(a) == strip(b)
    np.testing.assert_allclose(traj.q[0], sol.joints[0], atol=1e-9)
    np.testing.assert_allclose(traj.q[-1], sol.joints[-1], atol=1e-9)
    with pytest.raises(ss.SurestepError, match="unknown format 'mp4'"):
        ss.export(sol, "mp4", tmp_path / "x.mp4")
