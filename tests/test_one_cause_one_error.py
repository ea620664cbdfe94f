"""One cause, one error (issue 46, item 4): a wrong value in a problem (every key of several
trees covering every section and alternative form), a wrong CLI option value (every typed option
of every command) and a wrong API argument each give exactly one error line, naming the key,
option or argument. A `camera.pose.matrix` with a list inside also reported
`camera.pose.position: missing required key` (the alternative form); `robot: {urdff: ...}` an
unknown key and a missing one; `solver.options` IPOPT's bare `type mismatch`; `sim-robot
--duration nan` ran for ever."""

from __future__ import annotations

import argparse
import contextlib
import copy
import io
import math
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml

import surestep_ocp as ss
from surestep_ocp.cli import build_parser, main
from surestep_ocp.errors import ProblemError, ProblemErrors, SurestepError, error_lines
from surestep_ocp.problem.load import problem_from_dict

ROOT = Path(__file__).resolve().parents[1]
PACE = ROOT / "problems" / "needle_regrasp_paper_pace.yaml"
FILE = str(ROOT / "problems" / "x.yaml")  # (relative URDFs resolve from the problems' folder)
WRONG = ["zz", [[0]], {"zz": 1}, None, True, math.nan, 1e300, -1, []]


def _tree(name: str) -> dict:
    return yaml.safe_load((ROOT / "problems" / name).read_text())


def _bases() -> dict[str, dict]:
    """Valid trees that hold every section, key and alternative form between them."""
    full = _tree("type1_easy.yaml")  # goal relative to a needle arm; ECM camera
    full["timing"] = {"step_s": 0.05, "tracker_hz": 20, "max_duration": 2.0}
    full["detection"] = {"enabled": True, "margin": 0.02, "min_depth": 0.02, "max_depth": 0.3,
                         "falloff": 0.0}
    full["noise"].update(orientation_formula="cosine", cosine_guard=0.05, cut_band=0.2,
                         observation_noise="mean", observation_scale=1.0, camera_W_p0=1e-3,
                         camera_W_o0=1e-3, V_min=0.0, joint_motion_sigma=[0] * 6)
    full["objective"] = {"smoothness": 0.0, "covariance": "posterior"}
    full["solver"] = {"name": "auto", "tol": 1e-6, "max_iter": 3000, "print_level": 0,
                      "covariance": "auto", "hessian": "auto", "surrogate_max_iter": 300,
                      "codegen": "auto", "options": {"mu_strategy": "adaptive"}}
    full["gradient"] = {"preset": "paper", "optimizer": "scipy", "iterations": 50, "memory": 10}
    full["limits"] = {"enforce": False, "joint_velocity": {"yaw": 1.0},
                      "joint_acceleration": {"insertion": 0.1}, "tool_speed": 0.1,
                      "tool_rotation_speed": 1.5, "rcm_distance": 0.045}
    full["goal"].update(tolerance={"position": 0.005, "angle": 0.2}, confidence=0.95)
    out = {"full": full, "moves": _tree("type4_camera_moves.yaml")}
    for form, pose in (("matrix", {"matrix": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, -0.05],
                                              [0, 0, 0, 1]]}),
                       ("rpy", {"position": [0, 0, -0.05], "rpy": [3.14159, 0, 0]}),
                       ("axis_angle", {"position": [0, 0, -0.05], "axis_angle": [3.14159, 0, 0]}),
                       ("list", [0, 0, -0.05, 3.14159, 0, 0])):
        t = _tree("needle_regrasp_paper_pace.yaml")
        t["camera"].pop("ecm")
        t["camera"]["pose"] = pose
        t["start"] = {"pose": [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]}
        t["robot"]["needle"] = {"radius": 0.01, "grasp": [0, 0, 0, 0, 0, 0]}
        out[form] = t
    return out


def _paths(node, prefix=()):
    if prefix:
        yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _key(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _edited(tree, path, value=None, rename=None):
    t = copy.deepcopy(tree)
    node = t
    for p in path[:-1]:
        node = node[p]
    if rename is None:
        node[path[-1]] = value
    else:
        node[rename] = node.pop(path[-1])
    return t


def _errors(tree) -> list:
    try:
        problem_from_dict(tree, FILE)
    except ProblemErrors as exc:
        return exc.errors
    except SurestepError as exc:
        return [exc]
    return []


def _names(key: str, err) -> bool:
    """The error is at `key`, inside it, or at a section above it that names its last part."""
    at = getattr(err, "key", None) or ""
    if at == key or at.startswith((key + ".", key + "[")):
        return True
    last = key.split(".")[-1].split("[")[0]
    return key.startswith((at + ".", at + "[")) and last in str(err)


@pytest.mark.parametrize("base", list(_bases()))
def test_a_wrong_value_in_a_problem_is_one_error_naming_its_key(base):
    tree = _bases()[base]
    assert _errors(tree) == []
    wrong = []
    for path in _paths(tree):
        for value in WRONG:
            errs = _errors(_edited(tree, path, value))
            if len(errs) > 1 or (errs and not _names(_key(path), errs[0])):
                wrong.append(f"{_key(path)} = {value!r}: " + " || ".join(map(str, errs)))
    assert not wrong, f"{len(wrong)} inputs:\n" + "\n".join(wrong[:20])


@pytest.mark.parametrize("base", list(_bases()))
def test_a_misspelt_key_is_one_error_naming_it_and_the_allowed_keys(base):
    tree = _bases()[base]
    wrong = []
    for path in _paths(tree):
        if isinstance(path[-1], int):
            continue
        bad = f"{path[-1]}x"
        errs = _errors(_edited(tree, path, rename=bad))
        key = _key(path[:-1] + (bad,))
        said = str(errs[0]) if errs else ""
        if len(errs) != 1 or errs[0].key != key or not ("allowed" in said
                                                        or "No such IPOPT option" in said):
            wrong.append(f"{key}: " + " || ".join(map(str, errs)))
    assert not wrong, f"{len(wrong)} inputs:\n" + "\n".join(wrong[:20])


def test_the_issues_example_and_ipopt_options():
    tree = _bases()["matrix"]
    tree["camera"]["pose"]["matrix"][0][3] = [0]
    assert [str(e).split(": ", 1)[1] for e in _errors(tree)] == [
        "camera.pose.matrix[0][3]: expected a number, got a list"]
    tree = _bases()["full"]
    tree["robot"]["urdff"] = tree["robot"].pop("urdf")
    (err,) = _errors(tree)
    assert err.key == "robot.urdff" and str(err).endswith("missing here: urdf")
    for value, allowed in ((-1, "the option takes a string"), ("abc", "the option takes a number")):
        tree = _bases()["full"]
        tree["solver"]["options"] = {"mu_strategy": "adaptive",
                                     "mu_strategy" if value == -1 else "tol": value}
        (err,) = _errors(tree)
        assert err.key.startswith("solver.options.") and allowed in str(err), str(err)


# ------------------------------------------------------------------------------ the CLI
@pytest.fixture(scope="module")
def solution_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sol") / "sol.json"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["solve", str(PACE), "--method", "baseline", "-o", str(path)]) == 0
    return path


def _command_bases(sol: Path, tmp: Path) -> dict[str, list[str]]:
    default = str(ROOT / "problems" / "needle_regrasp.yaml")
    evaluation = str(ROOT / "problems" / "evaluations" / "evaluation.yaml")
    return {
        "solve": ["solve", str(PACE), "--method", "baseline"],
        "compare": ["compare", str(PACE), "--methods", "baseline", "--output-dir",
                    str(tmp / "c")],
        "replan": ["replan", str(PACE), "--output-dir", str(tmp / "r")],
        "validate": ["validate", str(PACE)],
        "show": ["show", str(sol), "--html", str(tmp / "s.html")],
        "evaluate": ["evaluate", evaluation, "--configs", "1", "--rollouts", "1", "--methods",
                     "baseline", "--output-dir", str(tmp / "e"), "--quiet"],
        "export": ["export", str(sol), "--format", "csv", "-o", str(tmp / "x.csv"), "--no-plot"],
        "sweep": ["sweep", str(ROOT / "problems" / "evaluations" / "table1_readings.yaml"),
                  "--output-dir", str(tmp / "sw")],
        "cache": ["cache"], "check": ["check", str(sol)], "serve": ["serve", default],
        "sim-robot": ["sim-robot", default]}


class _Late(Exception):
    pass


def _run(argv: list[str]) -> tuple[object, list[str]]:
    """`surestep argv` in this process: (exit code, stderr's lines); a command that starts its
    work on a wrong value is stopped after 60 s (it had accepted it)."""
    def late(*_):
        raise _Late()

    err = io.StringIO()
    old = signal.signal(signal.SIGALRM, late)
    signal.alarm(60)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main(argv)
            except SystemExit as exc:
                code = exc.code
    except _Late:
        code = "accepted (ran 60 s)"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    return code, [ln for ln in err.getvalue().splitlines() if ln.strip()]


def test_a_wrong_option_value_is_one_line_naming_the_option(solution_file, tmp_path):
    bases = _command_bases(solution_file, tmp_path)
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(subs.choices) <= set(bases), "a command without its base arguments here"
    wrong, tried = [], 0
    for name, parser in subs.choices.items():
        for action in parser._actions:
            if not action.option_strings or action.nargs == 0 or (action.type is None
                                                                   and not action.choices):
                continue
            option = max(action.option_strings, key=len)
            for value in ("zz", "nan", "inf", ""):
                argv = list(bases[name])
                if option in argv:
                    argv[argv.index(option) + 1] = value
                else:
                    argv += [option, value]
                code, lines = _run(argv)
                tried += 1
                if code != 2 or len(lines) != 1 or option not in lines[0]:
                    wrong.append(f"{name} {option} {value!r}: {code}: {' / '.join(lines)}")
    assert tried > 100
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("argv", [["--duration", "nan"], ["--duration", "-1"],
                                  ["--seed", "-1"]])
def test_sim_robot_refuses_what_it_would_run_on(argv):
    code, lines = _run(["sim-robot", str(ROOT / "problems" / "needle_regrasp.yaml"), *argv])
    assert code == 2 and len(lines) == 1 and argv[0] in lines[0]


# ------------------------------------------------------------------------------ the API
def _one(call, name: str) -> None:
    with pytest.raises(SurestepError) as info:
        call()
    lines = error_lines(info.value)
    assert len(lines) == 1 and "\n" not in lines[0] and name in lines[0], lines


RIGID_WITH_A_LIST = [[1, 0, 0, [0]], [0, -1, 0, 0], [0, 0, -1, -0.05], [0, 0, 0, 1]]


@pytest.mark.parametrize("method,args,name", [
    ("with_horizon", ("zz",), "horizon"), ("with_horizon", (0,), "horizon"),
    ("with_horizon", (2.5,), "horizon"), ("with_horizon", (None,), "horizon"),
    ("with_horizon", (10**9,), "horizon"),
    ("with_camera_pose", (RIGID_WITH_A_LIST,), "camera.pose.matrix[0][3]"),
    ("with_camera_pose", ("zz",), "camera.pose"), ("with_camera_pose", (np.eye(3),),
                                                  "camera.pose.matrix"),
    ("with_camera_pose", ({"position": [0, 0, 0], "rpy": "x"},), "camera.pose.rpy"),
])
def test_a_wrong_problem_argument_is_one_error(method, args, name):
    problem = ss.load_problem(PACE)
    _one(lambda: getattr(problem, method)(*args), name)


@pytest.mark.parametrize("kwargs,name", [
    ({"pose": "zz"}, "goal.pose"), ({"pose": [1, 2]}, "goal.pose"),
    ({"pose": [math.nan] * 6}, "goal.pose"), ({"joints": [0, "x"]}, "goal.joints[1]"),
    ({"pose": {"position": [0, 0, 0.1], "axis_angle": None}}, "goal.pose.axis_angle"),
])
def test_a_wrong_goal_is_one_error(kwargs, name):
    problem = ss.load_problem(PACE)
    _one(lambda: problem.with_goal(**kwargs), name)


@pytest.mark.parametrize("section,kwargs,name", [
    ("noise", {"W_p0": "zz"}, "noise.W_p0"), ("noise", {"W_p0": [[1]]}, "noise.W_p0"),
    ("noise", {"V_d0": -1}, "noise.V_d0"), ("noise", {"components": []}, "noise.components"),
    ("solver", {"tol": 0}, "solver.tol"), ("solver", {"name": "x"}, "solver.name"),
    ("solver", {"options": {"mu_strategy": -1}}, "solver.options.mu_strategy"),
    ("solver", {"options": {"tol": "x"}}, "solver.options.tol"),
])
def test_a_wrong_section_value_is_one_error(section, kwargs, name):
    problem = ss.load_problem(PACE)
    _one(lambda: getattr(problem, f"with_{section}")(**kwargs), name)


def test_wrong_solve_export_and_planner_arguments_are_one_error(solution_file, tmp_path):
    problem = ss.load_problem(PACE)
    for method in (1, None, "zz", ""):
        _one(lambda: ss.solve(problem, method), "method")
    for value in (math.nan, "3", -1, True):
        _one(lambda: ss.Planner(problem, replan_iterations=value), "replan_iterations")
    out = tmp_path / "x.csv"
    for kwargs, name in (({"rate_hz": "100"}, "rate_hz"), ({"rate_hz": math.nan}, "rate"),
                         ({"step_s": -1.0}, "step"), ({"tool_speed": "x"}, "tool_speed"),
                         ({"timing": "zz"}, "timing"), ({"joint_names": "a,b"}, "names")):
        _one(lambda: ss.export(solution_file, "csv", out, **kwargs), name)
    _one(lambda: ss.export(solution_file, "zz", out), "format")
    assert not out.exists()
    assert isinstance(ProblemError(None, None, "x"), SurestepError)
