"""A problem file with several wrong keys, in one section or in several, is reported whole: one line
per wrong key (each section read again without its bad keys), nothing for a key only missing because
it was taken out, exit 2."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

import surestep_ocp as ss

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _write(tmp_path, change):
    tree = yaml.safe_load((ROOT / "problems" / "needle_regrasp_paper_pace.yaml").read_text())
    change(tree)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(tree))
    return path


def _bad(tree):
    tree["solver"] = {"tol": -1, "max_iter": "many", "print_level": 99}
    tree["goal"]["pose"]["position"] = [0.0, "x", 0.1]


def test_every_wrong_key_once(tmp_path):
    path = _write(tmp_path, _bad)
    with pytest.raises(ss.ProblemErrors) as info:
        ss.load_problem(path)
    keys = sorted(e.key for e in info.value.errors)
    assert keys == sorted(["solver.tol", "solver.max_iter", "solver.print_level",
                           "goal.pose.position[1]"])


def test_validate_prints_one_line_each(tmp_path):
    path = _write(tmp_path, _bad)
    run = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "validate", str(path)],
                         capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 2
    lines = [line for line in (run.stdout + run.stderr).splitlines() if line.strip()]
    assert len(lines) == 4 and all("bad.yaml" in line for line in lines), lines
    assert not any("missing" in line for line in lines)
    assert "Traceback" not in run.stderr
