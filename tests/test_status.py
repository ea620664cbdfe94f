"""Statuses (surestep_ocp.status): one enum, written as its text, and no status spelt out anywhere
else in the package (read from the source with `ast`, docstrings and comments apart)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from surestep_ocp.status import Status

PKG = Path(__file__).resolve().parents[1] / "surestep_ocp"


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(body[0].value, ast.Constant):
            out.add(id(body[0].value))
    return out


def test_no_status_is_spelt_out_outside_the_enum():
    texts, found = {s.value for s in Status}, []
    for f in PKG.rglob("*.py"):
        if f.name == "status.py":
            continue
        tree = ast.parse(f.read_text())
        skip = _docstrings(tree)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and node.value in texts and id(node) not in skip):
                found.append(f"{f.relative_to(PKG)}:{node.lineno} {node.value}")
    assert not found, found


def test_a_status_is_its_text():
    s = Status.NOT_CERTIFIED
    assert s == "Not_Certified" and f"{s}" == "Not_Certified" and str(s) == "Not_Certified"
    assert json.loads(json.dumps({"status": s})) == {"status": "Not_Certified"}
    assert {Status.SOLVE_SUCCEEDED: 1}["Solve_Succeeded"] == 1


def test_an_unknown_backend_status_is_named_not_passed_through():
    assert Status.of("Restoration_Failed") is Status.RESTORATION_FAILED
    with pytest.raises(ValueError, match="unknown solver status 'Made_Up'.*Solve_Succeeded"):
        Status.of("Made_Up")
