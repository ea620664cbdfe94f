"""The optimality certificate (solvers/certificate.py, output/certificate.py) and `surestep check`:
its trace against the textbook NumPy EKF, its stationarity against finite differences, a perturbed
plan not certified, the one meaning of success, the solution file's record."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import numpy_ekf as ref
from surestep_ocp.cli import main
from surestep_ocp.output.certificate import FEASIBLE, INFEASIBLE, OPTIMAL
from surestep_ocp.output.solution import Solution
from surestep_ocp.solvers.certificate import NOT_CERTIFIED, certify, judge
from surestep_ocp.solvers.methods import run_method


@pytest.fixture(scope="module")
def ocp(default_setup):
    return run_method(default_setup, "ocp")


def _moved(sol: Solution, t: int, j: int, by: float) -> Solution:
    """A copy of `sol` with joint j of waypoint t moved by `by` (no reported trace: it was the
    plan's before the move)."""
    d = Solution.from_dict(sol.to_dict())
    d.run = replace(d.run, ocp_trace_final=None)
    d.q = [list(qi) for qi in d.q]
    d.q[t][j] += by
    return d


def test_the_optimum_is_certified_and_its_trace_is_the_textbook_ekfs(default_setup, ocp):
    c = ocp.certificate
    assert ocp.success and c.level == OPTIMAL and not c.failures()
    assert ocp.backend_status == ocp.status == "Solve_Succeeded"
    # the planning model's trace by tests/numpy_ekf.py along the plan's poses
    sig, _ = ref.propagate(np.asarray(ocp.poses), default_setup.ocp.noise,
                           default_setup.ocp.intrinsics, default_setup.model.components,
                           guard=default_setup.ocp.noise.cosine_guard ** 2)
    assert ref.rel_err(c.trace, np.trace(sig[-1])) < 1e-9
    assert c.terminal_position_m < 1e-9 and c.terminal_angle_rad < 1e-9


def test_stationarity_agrees_with_finite_differences(default_setup, ocp):
    """The reverse-mode gradient's stationarity against central differences of the NumPy EKF, at
    the optimum and at a point off it."""
    for sol in (ocp, _moved(ocp, 7, 1, 2e-3)):
        a = certify(default_setup, sol)
        b = certify(default_setup, sol, fd_step=1e-6)
        assert abs(a.stationarity - b.stationarity) <= 1e-7 + 1e-5 * b.stationarity
        assert a.level == b.level


def test_a_plan_off_the_optimum_is_not_certified(default_setup, ocp):
    off = certify(default_setup, _moved(ocp, 7, 1, 2e-3))
    assert off.level == FEASIBLE and off.stationarity > 1e-3
    assert [line.split(":")[0] for line in off.failures()] == ["stationarity"]
    # the last waypoint moved: the terminal pose is missed
    miss = certify(default_setup, _moved(ocp, ocp.horizon, 0, 1e-3))
    assert miss.level == INFEASIBLE
    assert "terminal position" in [line.split(":")[0] for line in miss.failures()]
    # a reported trace that is not the plan's
    wrong = _moved(ocp, 7, 1, 0.0)
    wrong.run = replace(wrong.run, ocp_trace_final=ocp.run.ocp_trace_final * (1 + 1e-4))
    lines = certify(default_setup, wrong).failures()
    assert [line.split(":")[0] for line in lines] == ["trace"]


def test_a_backend_success_without_a_certificate_is_not_a_success(default_setup, ocp):
    claimed = _moved(ocp, 7, 1, 2e-3)
    judge(default_setup, claimed)
    assert not claimed.success and claimed.status == NOT_CERTIFIED
    assert claimed.backend_status == "Solve_Succeeded" and claimed.backend_success
    # the gradient variant claims a completed run, not an optimum: its success stays its own
    grad = run_method(default_setup, "gradient")
    assert grad.success and grad.status.startswith("completed")
    assert grad.certificate.level == FEASIBLE


def test_the_certificate_is_in_the_solution_file(ocp, tmp_path):
    path = ocp.save(tmp_path / "ocp.json")
    back = Solution.load(path)
    assert back.certificate == ocp.certificate and back.backend_status == ocp.backend_status
    # a file written before certificates loads, without one
    d = ocp.to_dict()
    for key in ("certificate", "backend_status", "backend_success"):
        d.pop(key)
    old = Solution.from_dict(d)
    assert old.certificate is None and old.backend_status is None
    assert "certificate" not in old.extras


def test_check_command(ocp, tmp_path, capsys):
    good = ocp.save(tmp_path / "ocp.json")
    assert main(["check", str(good)]) == 0
    assert "certified optimal (recomputed from" in capsys.readouterr().out
    bad = _moved(ocp, 7, 1, 2e-3)
    bad.save(tmp_path / "moved.json")
    assert main(["check", str(tmp_path / "moved.json")]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].endswith("not certified (feasible; recomputed from "
                           f"{ocp.problem}):")
    assert [line.strip().split(":")[0] for line in out[1:]] == ["stationarity", "success"]
    # the recorded certificate when the problem file is gone
    d = ocp.to_dict()
    d["problem"] = str(tmp_path / "gone.yaml")
    d["certificate"] = replace(ocp.certificate, stationarity=0.5).to_json()
    Solution.from_dict(d).save(tmp_path / "recorded.json")
    assert main(["check", str(tmp_path / "recorded.json")]) == 1
    out = capsys.readouterr().out
    assert "the recorded certificate" in out and "stationarity: 0.5" in out
    (tmp_path / "not.json").write_text('{"q": 1}')
    assert main(["check", str(tmp_path / "not.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "not.json" in err and "Traceback" not in err
