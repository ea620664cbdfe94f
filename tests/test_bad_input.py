"""Bad input never crashes, hangs or destroys a file (issue 17): the command-level cases, one test
each.

Commands run in this process through `cli.main` (exit code, stdout and stderr captured); a
one-line error is exit 2 and a single `surestep: ...` line on stderr. Where a case must be
refused before the work starts, the work (`run_method`) is replaced by a function that fails
the test if it is called.
"""

from __future__ import annotations

import copy
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from surestep_ocp import cli
from surestep_ocp.errors import ProblemError, SurestepError
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.parse import MAX_HORIZON
from surestep_ocp.problem.setup import build_setup

REPO = Path(__file__).resolve().parents[1]
DEFAULT = REPO / "problems" / "needle_regrasp_paper_pace.yaml"
TREE = yaml.safe_load(DEFAULT.read_text())


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code: int, err: str, *words: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("surestep: "), err
    assert "Traceback" not in err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def write(tmp_path: Path, edit=None, name: str = "p.yaml", text: str | None = None) -> Path:
    path = tmp_path / name
    if text is None:
        tree = copy.deepcopy(TREE)
        if edit:
            edit(tree)
        text = yaml.safe_dump(tree, sort_keys=False)
    path.write_text(text)
    return path


@pytest.fixture()
def no_work(monkeypatch):
    """`run_method` that fails the test: the command must stop before any solve."""
    import importlib

    def forbidden(*args, **kwargs):
        raise AssertionError("the work started before the bad input was refused")

    # every module that binds it on import, imported first: one first imported while it is
    # patched would keep the forbidden function for the rest of the session
    modules = [importlib.import_module(f"surestep_ocp.{name}") for name in (
        "methods.registry", "comparison", "evaluation.configuration_record", "evaluation.table2",
        "evaluation.sure_grasp", "methods.camera_move_replan")]
    for module in modules:
        monkeypatch.setattr(module, "run_method", forbidden)


# ------------------------------------------------------------------ outputs
def test_solve_output_over_its_own_problem_file_is_refused(tmp_path, capsys, no_work):
    prob = write(tmp_path)
    before = prob.read_bytes()
    code, _, err = run(capsys, "solve", prob, "--method", "baseline", "--output", prob)
    one_line_error(code, err, "overwrite the input")
    assert prob.read_bytes() == before


def test_solve_output_over_the_robots_urdf_is_refused(tmp_path, capsys, no_work):
    urdf = tmp_path / "psm.urdf"
    urdf.write_bytes((REPO / "robots" / "psm.urdf").read_bytes())
    prob = write(tmp_path, lambda t: t["robot"].update(urdf=str(urdf)))
    code, _, err = run(capsys, "solve", prob, "--method", "baseline", "--output", urdf)
    one_line_error(code, err, "overwrite the input")
    assert urdf.read_bytes() == (REPO / "robots" / "psm.urdf").read_bytes()


def test_solve_output_onto_a_fifo_is_refused(tmp_path, capsys, no_work):
    """A special file (a FIFO here; /dev/full or /dev/null as root) is never replaced by a regular
    file."""
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    code, _, err = run(capsys, "solve", DEFAULT, "--method", "baseline", "--output", fifo)
    one_line_error(code, err, "not a regular file")
    assert not fifo.is_file() and fifo.exists()


def test_solve_output_that_is_a_directory_is_refused_before_the_solve(tmp_path, capsys, no_work):
    code, _, err = run(capsys, "solve", DEFAULT, "--method", "baseline", "--output", tmp_path)
    one_line_error(code, err, "is a directory")


def test_solve_output_under_a_regular_file_is_refused_before_the_solve(tmp_path, capsys, no_work):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    code, _, err = run(capsys, "solve", DEFAULT, "--method", "baseline", "--output",
                       blocker / "sol.json")
    one_line_error(code, err, "not a directory")
    assert blocker.read_text() == "x"


def test_compare_output_dir_that_is_a_file_is_refused_before_the_work(tmp_path, capsys, no_work):
    f = tmp_path / "out"
    f.write_text("keep me")
    code, _, err = run(capsys, "compare", DEFAULT, "--output-dir", f)
    one_line_error(code, err, "not a directory")
    assert f.read_text() == "keep me"


def test_replan_output_dir_under_a_file_is_refused_before_the_work(tmp_path, capsys, no_work):
    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = run(capsys, "replan", REPO / "problems" / "type4_camera_moves.yaml",
                       "--output-dir", f / "sub")
    one_line_error(code, err, "not a directory")


def test_a_non_finite_solution_is_not_written(tmp_path, default_setup):
    """NaN in a solution: an error naming the key that diverged, and no file."""
    from surestep_ocp.methods.baseline import solve_baseline
    from surestep_ocp.output.files import NonFinite

    sol = solve_baseline(default_setup)
    sol.trace[3] = math.nan
    out = tmp_path / "sol.json"
    with pytest.raises(NonFinite, match=r"trace\[3\] is nan"):
        sol.save(out)
    assert not out.exists()
    sol.trace[3] = 1.0
    sol.sigma[2][1][1] = math.inf
    with pytest.raises(NonFinite, match=r"sigma\[2\]\[1\]\[1\] is inf"):
        sol.save(out)
    assert not out.exists() and not list(tmp_path.iterdir())  # no temp file left either


# ------------------------------------------------------------------ problem files
@pytest.mark.parametrize("edit, key, words", [
    (lambda t: t.update(horizon=10**9), "horizon", f"<= {MAX_HORIZON}"),
    (lambda t: t["camera"]["intrinsics"].update(fx=10**400), "camera.intrinsics.fx", "digits"),
    (lambda t: t["camera"]["intrinsics"].update(fx=5e-324), "camera.intrinsics.fx", "range"),
    (lambda t: t["goal"]["pose"].update(position=[1e308, 0, 0.1]), "goal.pose.position[0]",
     "at most"),
    (lambda t: t["noise"].update(components=[]), "noise.components", "at least one"),
    (lambda t: t["noise"].update(observation_scale=1e-308), "noise.observation_scale", "range"),
    (lambda t: t["noise"].update(Sigma0=1e300), "noise.Sigma0", "at most"),
    (lambda t: t["objective"].update(smoothness=1e200) if "objective" in t
     else t.update(objective={"smoothness": 1e200}), "objective.smoothness", "range"),
    (lambda t: t["robot"].update(frame="universe"), "robot.frame", "not moved by any joint"),
    (lambda t: t["robot"].update(urdf="problems/needle_regrasp_paper_pace.yaml"), "robot.urdf",
     "URDF"),
    (lambda t: t["solver"].update(options={"no_such_option": 1}),
     "solver.options.no_such_option", "No such IPOPT option"),
    (lambda t: t["robot"].update(frame="a\nb" * 500), "robot.frame", "not in the model"),
])
def test_bad_values_are_one_line_named_errors(tmp_path, capfd, edit, key, words):
    path = write(tmp_path, edit)
    with pytest.raises(ProblemError) as info:
        build_setup(load_problem(path))
    assert info.value.key == key, str(info.value)
    msg = str(info.value)
    assert "\n" not in msg and len(msg) <= 1000, msg[:300]
    assert words in msg, msg
    _, err = capfd.readouterr()
    assert err == ""  # nothing printed by the C libraries either (urdfdom on a non-URDF file)
    code, _, err = run(capfd, "validate", path)
    assert code == 2 and len(err.strip().splitlines()) == 1, err


def test_unknown_ipopt_option_is_refused_for_every_solver(tmp_path, capsys, no_work):
    path = write(tmp_path, lambda t: t["solver"].update(options={"no_such_option": 1}))
    for solver in ("auto", "ipopt", "newton"):
        code, _, err = run(capsys, "solve", path, "--solver", solver)
        one_line_error(code, err, "solver.options.no_such_option",
                       "No such IPOPT option: no_such_option")
    path = write(tmp_path, lambda t: t["solver"].update(options={"mu_strategy": "sideways"}))
    code, _, err = run(capsys, "solve", path)
    one_line_error(code, err, "not a valid setting", "mu_strategy")


@pytest.mark.parametrize("text, words", [
    ("horizon: 1:20\n", "the string '1:20'"),  # YAML 1.1 would read 80
    ("a: " + "[" * 100 + "]" * 100 + "\n", "nested deeper"),
    ("\n".join(["a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]"]
               + [f"a{i}: &a{i} [{', '.join(f'*a{i - 1}' for _ in range(10))}]"
                  for i in range(1, 9)]), "aliases"),
    ("? [1, 2]\n: 3\n", "a key must be a name"),
])
def test_yaml_structure_errors(tmp_path, text, words):
    if words.startswith("the string"):
        text = DEFAULT.read_text().replace("horizon: 20", "horizon: 1:20")
        assert "horizon: 1:20" in text
    path = write(tmp_path, text=text)
    with pytest.raises(ProblemError) as info:
        build_setup(load_problem(path))
    msg = str(info.value)
    assert words in msg and "\n" not in msg and len(msg) < 400, msg


@pytest.mark.parametrize("data, words", [
    (b"\x00\x01\x02binary", "a binary file"),
    ("horizon: 20\nname: caf\u00e9\n".encode("latin-1"), "not UTF-8"),
])
def test_binary_and_non_utf8_files(tmp_path, data, words):
    path = tmp_path / "bin.yaml"
    path.write_bytes(data)
    with pytest.raises(ProblemError, match=words):
        load_problem(path)


def test_plain_exponents_are_numbers(tmp_path):
    """`1e-3` (YAML 1.2) is a number, as users write it (YAML 1.1 would read a string)."""
    text = DEFAULT.read_text().replace("W_p0: 1.0e-3", "W_p0: 1e-3")
    assert "W_p0: 1e-3" in text
    problem = load_problem(write(tmp_path, text=text))
    assert np.allclose(problem.noise.W_p0, 1e-3 * np.eye(6))


# ------------------------------------------------------------------ show
def _solution(tmp_path, default_setup) -> Path:
    from surestep_ocp.methods.baseline import solve_baseline

    out = tmp_path / "sol.json"
    solve_baseline(default_setup).save(out)
    return out


@pytest.mark.parametrize("make, words", [
    (lambda d, good: good.read_bytes()[:300], "not valid JSON"),
    (lambda d, good: b"", "empty"),
    (lambda d, good: bytes(range(128, 256)), "not UTF-8"),
    (lambda d, good: b"[1, 2]", "holds no solution"),
    (lambda d, good: b'{"a": 1}', "no 'poses'"),
    (lambda d, good: json.dumps({k: v for k, v in d.items() if k != "camera_pose"}).encode(),
     "'camera_pose' is missing"),
    (lambda d, good: json.dumps(dict(d, poses=[[1, 2]])).encode(), "'poses[0]'"),
    (lambda d, good: json.dumps(dict(d, camera="x")).encode(), "'camera'"),
])
def test_show_bad_solution_files(tmp_path, capsys, default_setup, make, words):
    good = _solution(tmp_path, default_setup)
    d = json.loads(good.read_text())
    bad = tmp_path / "bad.json"
    bad.write_bytes(make(d, good))
    code, _, err = run(capsys, "show", bad, "--html", tmp_path / "page.html")
    one_line_error(code, err, words)
    assert not (tmp_path / "page.html").exists()


def test_show_html_into_an_impossible_folder_and_over_its_input(tmp_path, capsys, default_setup):
    good = _solution(tmp_path, default_setup)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run(capsys, "show", good, "--html", blocker / "page.html")
    one_line_error(code, err, "not a directory")
    before = good.read_bytes()
    code, _, err = run(capsys, "show", good, "--html", good)
    one_line_error(code, err, "overwrite the input")
    assert good.read_bytes() == before


# ------------------------------------------------------------------ evaluate
def eval_file() -> Path:
    return next(p for p in (REPO / "problems").rglob("evaluation.yaml"))


def test_evaluate_output_dir_that_is_a_file(tmp_path, capsys):
    f = tmp_path / "out"
    f.write_text("keep")
    code, _, err = run(capsys, "evaluate", eval_file(), "--configs", "1", "--rollouts", "2",
                       "--output-dir", f, "--quiet")
    one_line_error(code, err, "not a directory")
    assert f.read_text() == "keep"


@pytest.mark.parametrize("record, words", [
    ('{"config": 0, "solves": [], "metrics": {}, "pos_errors": {}}', "line 1"),
    ('[1, 2, 3]', "not an object"),
    ('{"config": "zero"}', "config"),
])
def test_evaluate_resume_with_a_wrong_progress_record(tmp_path, capsys, record, words):
    out = tmp_path / "run"
    out.mkdir()
    (out / "progress.jsonl").write_text(record + "\n")
    code, _, err = run(capsys, "evaluate", eval_file(), "--configs", "1", "--rollouts", "2",
                       "--output-dir", out, "--resume", "--quiet", "--methods", "baseline")
    one_line_error(code, err, "progress.jsonl", words)


def test_evaluate_resume_with_a_wrong_run_record(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.json").write_text("[1, 2]")
    code, _, err = run(capsys, "evaluate", eval_file(), "--configs", "1", "--rollouts", "2",
                       "--output-dir", out, "--resume", "--quiet", "--methods", "baseline")
    one_line_error(code, err, "run.json", "not a run record")


@pytest.mark.parametrize("flags, words", [
    (["--seed", "-1"], "--seed"),
    (["--configs", "1000000000"], "--configs"),
    (["--jobs", "100000"], "--jobs"),
])
def test_evaluate_flags_out_of_range(tmp_path, capsys, flags, words):
    code, _, err = run(capsys, "evaluate", eval_file(), "--rollouts", "2", "--output-dir",
                       tmp_path / "o", "--quiet", *flags)
    one_line_error(code, err, words)


# --------------------------------------------------------------- interrupts, pipes, internal errors
def test_ctrl_c_is_one_line_and_130(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_validate", interrupted)
    monkeypatch.setattr(cli, "build_parser", _parser_with("validate", interrupted))
    code, _, err = run(capsys, "validate", DEFAULT)
    assert code == 130 and err.strip() == "surestep: interrupted"


def test_closed_pipe_is_quiet(monkeypatch, capsys):
    def closed(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(cli, "build_parser", _parser_with("validate", closed))
    monkeypatch.setattr(os, "dup2", lambda *a: None)  # keep pytest's own stdout
    code, _, err = run(capsys, "validate", DEFAULT)
    assert code == 141 and err == ""


def _parser_with(command: str, func):
    build = cli.build_parser

    def parser():
        p = build()
        for action in p._subparsers._group_actions:
            action.choices[command].set_defaults(func=func)
        return p

    return parser


def test_closed_pipe_in_a_real_pipeline():
    """`surestep validate ... | head -c 1`: the reader goes away; no traceback on stderr."""
    many = [str(DEFAULT)] * 400
    proc = subprocess.run(f"{sys.executable} -m surestep_ocp.cli validate {' '.join(many)} | "
                          "head -c 1",
                          shell=True, capture_output=True, text=True, cwd=REPO, timeout=300)
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr[-500:]


# ------------------------------------------------------------------ the codegen cache
def test_a_corrupt_cached_library_is_rebuilt_with_a_note(tmp_path):
    """Truncated, garbage and empty cached libraries: verified before loading, rebuilt, the note
    said.

    In a subprocess: loading a truncated shared library can kill the process (SIGBUS).
    """
    pytest.importorskip("casadi")
    from surestep_ocp.ocp.codegen import available

    if not available():
        pytest.skip("no C compiler")
    script = """
import casadi as ca
from surestep_ocp.ocp import codegen
x = ca.SX.sym("x", 3)
g, fresh = codegen.compiled(ca.Function("fuzz_cache_probe", [x], [ca.sin(x) * x]))
print(fresh, float(g([1, 2, 3])[1]))
"""
    env = {**os.environ, "SURESTEP_CACHE": str(tmp_path)}

    def solve_once():
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                              timeout=300, env=env, cwd=REPO)
        assert proc.returncode == 0, proc.stderr[-2000:]  # -7 would be SIGBUS
        fresh, value = proc.stdout.split()
        assert float(value) == pytest.approx(2 * math.sin(2), rel=1e-6)
        return fresh == "True", [ln for ln in proc.stderr.splitlines()
                                 if ln.startswith("note: solver.codegen:")
                                 and "compiling" not in ln]

    assert solve_once() == (True, [])
    lib = next(tmp_path.glob("fuzz_cache_probe_*.so"))
    good = lib.read_bytes()
    for bad in (good[: len(good) // 2], b"garbage", b""):
        lib.write_bytes(bad)
        fresh, notes = solve_once()
        assert fresh and lib.read_bytes() == good
        assert len(notes) == 1 and "does not match its checksum" in notes[0], notes
    assert solve_once() == (False, [])


def test_surestep_errors_are_one_line():
    err = SurestepError("first line\nsecond line\r\nthird")
    assert str(err) == "first line second line third"


@pytest.mark.parametrize("argv, words", [
    (["solve"], "required: problem"),
    (["evaluate", "x.yaml", "--configs", "ten"], "invalid int value"),
    (["frobnicate"], "invalid choice"),
])
def test_usage_errors_are_one_line(capsys, argv, words):
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    _, err = capsys.readouterr()
    assert info.value.code == 2
    assert len(err.strip().splitlines()) == 1 and words in err, err
