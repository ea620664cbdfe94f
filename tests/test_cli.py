"""The command line: exit codes, one-line errors, solution and comparison files, and `--help`
telling the truth."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from surestep_ocp.cli import build_parser, main
from surestep_ocp.method_grammar import ABLATIONS, BASE_METHODS, EXPECTED, PREDICTED


REPO = Path(__file__).resolve().parents[1]
DEFAULT = REPO / "problems" / "needle_regrasp_paper_pace.yaml"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surestep_ocp.cli", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=600)


def small_problem(tmp_path: Path, horizon: int = 6, **changes) -> Path:
    tree = yaml.safe_load(DEFAULT.read_text())
    tree["horizon"] = horizon
    tree.update(changes)
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(tree))
    return path


@pytest.mark.parametrize(
    "change, key",
    [
        ({"colour": "red"}, "colour"),
        ({"horizon": "ten"}, "horizon"),
        ({"goal": {"pose": {"position": [0.5, 0.5, 0.6], "axis_angle": [0, 0, 1]}}}, "goal.pose"),
    ],
)
def test_bad_problem_exits_2_with_one_line(tmp_path, change, key):
    """User errors are one line naming the file and key, exit code 2, no traceback."""
    path = small_problem(tmp_path, **change)
    for cmd in (["validate", str(path)], ["solve", str(path), "--method", "baseline"]):
        res = run(*cmd)
        assert res.returncode == 2, res.stderr
        assert "Traceback" not in res.stderr
        lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "small.yaml" in lines[0] and key in lines[0], res.stderr


def test_missing_file_and_unknown_method_exit_2(tmp_path):
    """A missing problem file or an unknown method name is a clean error listing what is allowed."""
    res = run("solve", str(tmp_path / "nope.yaml"))
    assert res.returncode == 2 and "no such file" in res.stderr and "Traceback" not in res.stderr
    res = run("solve", str(small_problem(tmp_path)), "--method", "magic")
    assert res.returncode == 2 and "allowed" in res.stderr and "Traceback" not in res.stderr


def test_solve_writes_solution(tmp_path):
    """`surestep solve` writes the solution JSON and prints the summary against the baseline."""
    out = tmp_path / "sol.json"
    res = run("solve", str(small_problem(tmp_path)), "--method", "ocp", "--output", str(out))
    assert res.returncode == 0, res.stderr
    assert "Tr(Sigma_T)" in res.stdout and "baseline" in res.stdout
    sol = json.loads(out.read_text())
    assert sol["method"] == "ocp" and sol["success"] and sol["horizon"] == 6
    assert len(sol["q"]) == len(sol["poses"]) == len(sol["trace"]) == 7
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp file left


def test_compare_writes_files_and_ocp_wins(tmp_path):
    """`surestep compare` writes every method's JSON, the tables and plots; the OCP beats the
    paper's variant."""
    out = tmp_path / "cmp"
    res = run("compare", str(small_problem(tmp_path)), "--output-dir", str(out))
    assert res.returncode == 0, res.stderr
    methods = ["baseline", "gradient", "gradient-no-pose-loss", "ocp", "ocp-from-gradient"]
    for m in methods:
        assert json.loads((out / f"{m}.json").read_text())["method"] == m
    table = json.loads((out / "comparison.json").read_text())
    rows = {r["method"]: r for r in table["methods"]}
    assert set(rows) == set(methods)
    assert rows["ocp"]["trace_final"] <= rows["gradient"]["trace_final"]
    assert rows["ocp"]["terminal_error_m"] < 1e-6 and rows["ocp"]["terminal_error_rad"] < 1e-6
    assert rows["baseline"]["trace_rel"] == pytest.approx(1.0)
    assert "final_step_m" in rows["gradient"]
    md = (out / "comparison.md").read_text()
    assert all(m in md for m in methods)
    for png in ("trace.png", "path.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_solver_flags_hessian_newton_and_fatrop(tmp_path):
    """--hessian picks the OCP Hessian (reported in the solution); --solver newton gives the same
    optimum; --solver fatrop is a clean error, exit 2."""
    path = small_problem(tmp_path, horizon=4)
    traces = {}
    for hessian in ("exact", "surrogate", "gauss-newton"):
        out = tmp_path / f"{hessian}.json"
        res = run("solve", str(path), "--hessian", hessian, "-o", str(out))
        assert res.returncode == 0, res.stderr
        sol = json.loads(out.read_text())
        assert sol["hessian"] == hessian
        traces[hessian] = sol["trace"][-1]
    assert traces["gauss-newton"] == pytest.approx(traces["exact"], rel=1e-6)
    assert traces["surrogate"] == pytest.approx(traces["exact"], rel=1e-6)
    res = run("solve", str(path), "--solver", "fatrop")
    assert res.returncode == 2 and "fatrop" in res.stderr and "Traceback" not in res.stderr
    out = tmp_path / "newton.json"  # --solver newton, and solver.name: newton in a file
    res = run("solve", str(path), "--solver", "newton", "-o", str(out))
    assert res.returncode == 0, res.stderr
    sol = json.loads(out.read_text())
    assert (sol["solver"] == "newton" and sol["trace"][-1]
            == pytest.approx(traces["exact"], rel=1e-6))
    assert run("validate",
               str(small_problem(tmp_path, horizon=4, solver={"name": "newton"}))).returncode == 0
    bad = small_problem(tmp_path, horizon=4, solver={"hessian": "newton"})
    res = run("validate", str(bad))
    assert res.returncode == 2 and "solver.hessian" in res.stderr and "gauss-newton" in res.stderr
    # not silently replaced by IPOPT
    bad = small_problem(tmp_path, horizon=4, solver={"name": "fatrop"})
    res = run("validate", str(bad))
    assert res.returncode == 2 and "solver.name" in res.stderr and "ipopt" in res.stderr


@pytest.mark.skipif(not __import__("surestep_ocp.ocp.codegen").ocp.codegen.available(),
                    reason="no C compiler on this machine")
def test_codegen_compiles_once_and_gives_the_same_plan(tmp_path):
    """--codegen: the compiled derivatives give the VM's plan; the second run loads the cached
    libraries."""
    path = small_problem(tmp_path, horizon=3)
    env_cache = tmp_path / "cache"
    sols, libs = {}, {}
    for name, flags in (("vm", ["--no-codegen"]), ("cg", ["--codegen"]), ("cg2", ["--codegen"])):
        out = tmp_path / f"{name}.json"
        res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "solve", str(path),
                              "--hessian", "surrogate", "-o", str(out),
                              *flags], capture_output=True, text=True, cwd=REPO,
                             timeout=600,
                             env={**__import__("os").environ, "SURESTEP_CACHE": str(env_cache)},
                             check=False)
        assert res.returncode == 0, res.stderr
        sols[name] = json.loads(out.read_text())
        libs[name] = {(p.name, p.stat().st_mtime_ns) for p in env_cache.glob("*.so")}
    assert not libs["vm"] and sols["vm"]["compiled"] is False
    # gradient, constraint Jacobian and Hessian compiled once, loaded (untouched) the second time
    assert len(libs["cg"]) == 3 and libs["cg2"] == libs["cg"] and sols["cg"]["compiled"] is True
    for name in ("cg", "cg2"):
        assert sols[name]["trace"][-1] == pytest.approx(sols["vm"]["trace"][-1], rel=1e-9)
        assert sols[name]["iterations"] == sols["vm"]["iterations"]


# `surestep <cmd> --help` tells the truth: defaults as they behave, every method name, inapplicable
# options are errors (exit 2, one line), a closed pipe is a quiet exit, `--version` works.


def subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def help_text(parser: argparse.ArgumentParser, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "1000")  # no wrapping (argparse breaks lines at hyphens)
    return " ".join(parser.format_help().split())


def test_every_stated_default_is_argparses(monkeypatch):
    """An option with a default (not None, not a False switch) states it in its help, as argparse
    has it."""
    checked = []
    for name, parser in subparsers().items():
        for a in parser._actions:
            if not a.option_strings or a.default in (None, False, argparse.SUPPRESS) or a.required:
                continue
            d = a.default
            shown = {str(d), f"{d:g}"} if isinstance(d, float) else {str(d)}
            assert any(re.search(rf"default:? {re.escape(s)}\b", a.help) for s in shown), (
                name, a.dest, a.help)
            checked.append(f"{name} {a.dest}")
    assert {"solve method", "evaluate configs", "export rate"} <= set(checked)


def test_solver_flag_defaults_are_the_solver_specs(monkeypatch, write_problem):
    """--solver/--hessian/--codegen state SolverSpec's defaults; every offered --solver is one a
    problem accepts."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.spec import SolverSpec

    d = SolverSpec()
    text = help_text(subparsers()["solve"], monkeypatch)
    assert f"solver.name, else {d.name}" in text and f"solver.hessian, else {d.hessian}" in text
    assert f"solver.codegen, else {d.codegen}" in text
    solver = next(a for a in subparsers()["solve"]._actions if a.dest == "solver")
    assert "fatrop" not in solver.choices
    for choice in solver.choices:  # interior: for problems with enforced limits only
        tree = {"solver": {"name": choice},
                **({"limits": {"enforce": True}} if choice == "interior" else {})}
        assert load_problem(write_problem(lambda t, u=tree: t.update(u))).solver.name == choice


def test_help_lists_every_method_name_from_the_registry(monkeypatch):
    for cmd in ("solve", "compare"):
        text = help_text(subparsers()[cmd], monkeypatch)
        for part in (*BASE_METHODS, *ABLATIONS, EXPECTED, PREDICTED):
            assert part in text, (cmd, part)
    assert "(default: " + " ".join(BASE_METHODS) + ")" in help_text(subparsers()["compare"],
                                                                    monkeypatch)
    from surestep_ocp.methods.registry import COMPARE_METHODS

    assert COMPARE_METHODS == BASE_METHODS


def one_line_exit_2(capsys, *argv: str) -> str:
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize("argv, says", [
    (["solve", str(DEFAULT), "--method", "baseline", "--init", "gradient"], "--init"),
    (["solve", str(DEFAULT), "--method", "ocp-from-gradient", "--init", "baseline"], "--init"),
    (["solve", str(DEFAULT), "--method", "gradient", "--solver", "ipopt"], "--solver"),
    (["solve", str(DEFAULT), "--method", "baseline", "--no-codegen"], "--codegen"),
    (["compare", str(DEFAULT), "--output-dir", "unused", "--methods", "baseline", "gradient",
      "--hessian", "exact"],
     "--hessian"),
    (["solve", str(DEFAULT), "--solver", "fatrop"], "fatrop"),
    (["solve", str(DEFAULT), "--method", "ocp-no-colour"], "allowed"),
    (["compare", str(DEFAULT), "--output-dir", "unused", "--methods", "ocp", "magic"], "allowed"),
])
def test_inapplicable_or_unknown_option_is_one_line_exit_2(capsys, argv, says):
    assert says in one_line_exit_2(capsys, *argv)


def test_init_gradient_keeps_the_variant():
    from surestep_ocp.cli import _with_init

    assert _with_init("ocp", "gradient") == "ocp-from-gradient"
    assert _with_init("ocp-no-depth-expected", "gradient") == "ocp-from-gradient-no-depth-expected"
    assert _with_init("ocp", "baseline") == "ocp" and _with_init("gradient", None) == "gradient"


def test_closed_pipe_is_a_quiet_exit():
    """`surestep solve ... | head -1`: the reader is gone before anything is written (no race): exit
    141, silent."""
    r, w = os.pipe()
    os.close(r)
    try:
        res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "solve", str(DEFAULT),
                              "--method", "baseline"],
                             stdout=w, stderr=subprocess.PIPE, text=True, cwd=REPO, timeout=300,
                             check=False)
    finally:
        os.close(w)
    assert res.returncode == 141 and res.stderr == ""


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and re.fullmatch(r"surestep \S+\n", capsys.readouterr().out)
