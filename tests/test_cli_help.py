"""`surestep <cmd> --help` tells the truth: defaults as they behave, every method name, inapplicable options
are errors (exit 2, one line), a closed pipe is a quiet exit, `--version` works."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from surestep_ocp.cli import build_parser, main
from surestep_ocp.solvers.method_names import ABLATIONS, BASE_METHODS, EXPECTED, PREDICTED

REPO = Path(__file__).resolve().parents[1]
DEFAULT = REPO / "problems" / "needle_regrasp_paper_pace.yaml"


def subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def help_text(parser: argparse.ArgumentParser, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "1000")  # no wrapping (argparse breaks lines at hyphens)
    return " ".join(parser.format_help().split())


def test_every_stated_default_is_argparses(monkeypatch):
    """An option with a default (not None, not a False switch) states it in its help, as argparse has it."""
    checked = []
    for name, parser in subparsers().items():
        for a in parser._actions:
            if not a.option_strings or a.default in (None, False, argparse.SUPPRESS) or a.required:
                continue
            d = a.default
            shown = {str(d), f"{d:g}"} if isinstance(d, float) else {str(d)}
            assert any(re.search(rf"default:? {re.escape(s)}\b", a.help) for s in shown), (name, a.dest, a.help)
            checked.append(f"{name} {a.dest}")
    assert {"solve method", "evaluate configs", "export rate"} <= set(checked)


def test_solver_flag_defaults_are_the_solver_specs(monkeypatch, write_problem):
    """--solver/--hessian/--codegen state SolverSpec's defaults; every offered --solver is one a problem accepts."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.spec import SolverSpec

    d = SolverSpec()
    text = help_text(subparsers()["solve"], monkeypatch)
    assert f"solver.name, else {d.name}" in text and f"solver.hessian, else {d.hessian}" in text
    assert f"solver.codegen, else {d.codegen}" in text
    solver = next(a for a in subparsers()["solve"]._actions if a.dest == "solver")
    assert "fatrop" not in solver.choices
    for choice in solver.choices:
        assert load_problem(write_problem(lambda t, c=choice: t.update(solver={"name": c}))).solver.name == choice


def test_help_lists_every_method_name_from_the_registry(monkeypatch):
    for cmd in ("solve", "compare"):
        text = help_text(subparsers()[cmd], monkeypatch)
        for part in (*BASE_METHODS, *ABLATIONS, EXPECTED, PREDICTED):
            assert part in text, (cmd, part)
    assert "(default: " + " ".join(BASE_METHODS) + ")" in help_text(subparsers()["compare"], monkeypatch)
    from surestep_ocp.solvers.methods import COMPARE_METHODS

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
    (["compare", str(DEFAULT), "--output-dir", "unused", "--methods", "baseline", "gradient", "--hessian", "exact"],
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
    """`surestep solve ... | head -1`: the reader is gone before anything is written (no race): exit 141, silent."""
    r, w = os.pipe()
    os.close(r)
    try:
        res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "solve", str(DEFAULT), "--method", "baseline"],
                             stdout=w, stderr=subprocess.PIPE, text=True, cwd=REPO, timeout=300, check=False)
    finally:
        os.close(w)
    assert res.returncode == 141 and res.stderr == ""


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and re.fullmatch(r"surestep \S+\n", capsys.readouterr().out)
