"""`surestep compare`'s exit status with the limits enforced: only the methods that plan within the
limits (the OCP methods and the baseline) count; the gradient variants' violations are printed with
how far they go. (An evaluation file's own `limits:`: test_evaluation.py.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def compare(tmp_path, problem, methods):
    return subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "compare", str(problem),
                           "--methods", *methods, "--output-dir",
                           str(tmp_path / "out")], capture_output=True, text=True, cwd=ROOT,
                          timeout=600)


def test_compare_counts_only_the_methods_that_honour_the_limits(tmp_path, write_problem):
    """Enforced at 0.1 s per step: the OCP's and the baseline's plans are within the limits, the
    gradient variant's is not: exit 0, its violations printed with their worst ratio. Before, exit 1
    ("failed: baseline")."""
    path = write_problem(lambda t: t.update(limits={"enforce": True},
                                            timing={"step_s": 0.1, "tracker_hz": 20},
                                            solver={**t["solver"], "codegen": False}), "enforced")
    res = compare(tmp_path, path, ["baseline", "gradient", "ocp"])
    assert res.returncode == 0, res.stderr
    assert "over the limits: gradient" in res.stderr and "joint_acceleration" in res.stderr
    assert "x the limit" in res.stderr and "over the limits: baseline" not in res.stderr
    assert "failed" not in res.stderr


def test_compare_exits_1_when_an_ocp_method_breaks_the_limits(tmp_path, write_problem):
    """An OCP plan that cannot meet them (rest to rest in 3 steps of 0.05 s: IPOPT reports it
    infeasible) fails the comparison; the baseline takes more steps within them (said;
    tests/test_baseline.py)."""
    path = write_problem(lambda t: t.update(limits={"enforce": True}, horizon=3,
                                            solver={**t["solver"], "codegen": False}), "tight")
    res = compare(tmp_path, path, ["baseline", "ocp"])
    assert res.returncode == 1, res.stderr
    assert "failed: ocp" in res.stderr and "baseline" not in res.stderr.split("failed:")[-1]
    assert "baseline: " in res.stdout and "lengthened by" in res.stdout
