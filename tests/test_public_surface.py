"""The public surface a user finds: the exports an editor and a type checker see, `py.typed` in the
wheel, the API reference built from the docstrings, the CHANGELOG, every CLI argument with help
text."""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import surestep_ocp
from surestep_ocp.cli import build_parser

REPO = Path(__file__).resolve().parents[1]


def test_every_lazy_export_is_imported_for_type_checkers():
    """`__all__`, the lazy table and the `if TYPE_CHECKING:` imports name the same objects."""
    tree = ast.parse((REPO / "surestep_ocp" / "__init__.py").read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If)
                 and getattr(n.test, "id", "") == "TYPE_CHECKING")
    seen = {}
    for node in block.body:
        assert isinstance(node, ast.ImportFrom) and node.level == 1, ast.dump(node)
        for alias in node.names:
            seen[alias.asname or alias.name] = (node.module, alias.name)
    assert set(seen) == set(surestep_ocp.__all__) == set(surestep_ocp._EXPORTS)
    from importlib import import_module

    for name, (module, attr) in seen.items():
        assert module == surestep_ocp._EXPORTS[name], name
        assert (getattr(import_module(f"surestep_ocp.{module}"), attr)
                is getattr(surestep_ocp, name)), name
    assert {"solve", "export", "Problem", "Planner"} <= set(dir(surestep_ocp))


def test_import_stays_light():
    code = ("import sys, surestep_ocp; heavy = [m for m in ('casadi', 'pinocchio', 'matplotlib', "
            "'numpy') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO).stdout
    assert out.strip() == "[]"


def test_py_typed_is_in_the_wheel(tmp_path):
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
    if not (clone / "surestep_ocp" / "py.typed").exists():
        pytest.skip("py.typed not committed yet (the wheel is built from a clone of HEAD)")
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w",
                            str(tmp_path / "w"),
                            str(clone)], capture_output=True, text=True, timeout=600, check=False)
    if build.returncode != 0 and "Could not find a version that satisfies" in build.stderr:
        pytest.skip("no package index to fetch the build backend from")
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = (tmp_path / "w").glob("surestep_ocp-*.whl")
    assert "surestep_ocp/py.typed" in zipfile.ZipFile(wheel).namelist()


def test_the_api_reference_builds(tmp_path):
    """`make docs`' build, into a temporary folder: the exports documented from their docstrings, no
    warnings."""
    res = subprocess.run([sys.executable, str(REPO / "docs" / "api_reference.py"),
                          str(tmp_path / "api")],
                         capture_output=True, text=True, cwd=REPO, timeout=300, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "Warn" not in res.stderr, res.stderr[-2000:]
    assert (tmp_path / "api" / "index.html").is_file()
    page = (tmp_path / "api" / "surestep_ocp.html").read_text()
    for name in surestep_ocp.__all__:
        assert f'id="{name}"' in page, name
    for text in ("with_goal", "axis_angle=", "rosbag2", "replan"):
        assert text in page, text
    assert (tmp_path / "api" / "surestep_ocp" / "problem" / "spec.html").is_file()
    assert "docs/api_reference.py docs/api" in (REPO / "Makefile").read_text()  # `make docs`


def test_the_changelog():
    text = (REPO / "CHANGELOG.md").read_text()
    assert (text.startswith("# Changelog") and "## [Unreleased]" in text
            and "keepachangelog.com" in text)
    unreleased = text.split("## [Unreleased]")[1].split("\n## [")[0]
    for heading in ("### Added", "### Changed"):
        assert heading in unreleased
    for feature in ("surestep cache", "ss.export", "ProblemErrors", "XDG_CACHE_HOME", "py.typed",
                    "rosbag2", "--joint-names", "requirements/", "Solution.attempts"):
        assert feature in unreleased, feature


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_argument_of_every_command_has_help():
    missing = [f"{name} {a.dest}" for name, parser in _subparsers().items() for a in parser._actions
               if not isinstance(a, argparse._HelpAction) and not (a.help and a.help.strip())]
    assert missing == []
    assert {"replan", "cache", "export"} <= set(_subparsers())
