"""The straight-line baseline within enforced motion limits (issue 28, item 2): the same line
played at a time law within the limits, rest to rest, in the problem's duration, or (said) in the
fewest steps found; unchanged where the limits are not enforced.

The limit checks here do not use the planner's: the exported curve is sampled at 2 kHz and its
positions differenced with NumPy, against the URDF's joint velocities and the dVRK's accelerations
(test_export's tables, read from robots/psm.urdf with ElementTree), the tool's speed by Pinocchio's
FK of the samples."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_export import ACCEL, LIMITS, TOOL_ROTATION, TOOL_SPEED, read_json, tool_speeds

import surestep_ocp as ss
from surestep_ocp.cli import main
from surestep_ocp.evaluation.rollout import rollout
from surestep_ocp.problem.setup import build_setup

REPO = Path(__file__).resolve().parents[1]
DEFAULT = REPO / "problems" / "needle_regrasp.yaml"
RATE = 2000.0  # [Hz] the exported samples differenced
FD_TOL = 2e-3  # relative: the finite differences' own error at 0.5 ms (a quintic per step)


def cli(*args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surestep_ocp.cli", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=timeout)


def played_peaks(solution: Path, tmp_path: Path) -> dict:
    """The exported curve's peak ratios to the limits, from finite differences of its positions
    only; the export's own timing, duration and waypoint times beside them."""
    out = tmp_path / f"{solution.stem}_played.json"
    assert main(["export", str(solution), "--format", "json", "--output", str(out), "--no-plot",
                 "--rate", str(RATE)]) == 0
    c = read_json(out)
    t, q = c["t"], c["positions"]
    dt = np.diff(t)[:, None]
    v = np.diff(q, axis=0) / dt  # at the interval midpoints
    a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))
    vmax = np.array([LIMITS[n][2] for n in c["names"]])
    amax = np.array([ACCEL[n] for n in c["names"]])
    (chord_v, chord_w), _ = tool_speeds(c)
    d = json.loads(out.read_text())
    return {"velocity": float(np.max(np.abs(v) / vmax)),
            "acceleration": float(np.max(np.abs(a) / amax)),
            "tool_speed": float(chord_v.max() / TOOL_SPEED),
            "tool_rotation": float(chord_w.max() / TOOL_ROTATION),
            "timing": d["timing"], "duration_s": d["duration_s"],
            "waypoint_times": c["waypoint_times"]}


def assert_within(peaks: dict) -> None:
    for key in ("velocity", "acceleration", "tool_speed", "tool_rotation"):
        assert peaks[key] <= 1 + FD_TOL, (key, peaks[key])


def rest_to_rest_bound(sol) -> float:
    """[s] the least time any rest-to-rest motion between the plan's end joints takes within the
    acceleration limits alone (per joint 2 sqrt(distance / limit), a bang-bang move)."""
    q = sol.joints
    return max(2 * math.sqrt(abs(q[-1, j] - q[0, j]) / ACCEL[n])
               for j, n in enumerate(sol.joint_names))


def test_the_default_baseline_runs_within_every_limit_in_its_duration(tmp_path):
    """`surestep solve problems/needle_regrasp.yaml --method baseline` exits 0 (before: 1, its
    constant pace from rest broke the yaw's acceleration limit); its played curve is within every
    limit, in the problem's 2 s."""
    out = tmp_path / "baseline.json"
    assert main(["solve", str(DEFAULT), "--method", "baseline", "--output", str(out)]) == 0
    sol = ss.Solution.load(out)
    assert sol.success and sol.status == "not optimised" and sol.horizon == 40
    law = sol.extras["time_law"]
    assert law["law"] == "minimum-jerk" and law["steps"] == law["problem_steps"] == 40
    assert law["lengthened_by_s"] == 0 and sol.motion_limits.violations == []
    peaks = played_peaks(out, tmp_path)
    assert_within(peaks)
    assert peaks["acceleration"] > 0.2 and peaks["tool_speed"] > 0.5  # it moves: the check bites
    assert peaks["timing"] == "planned" and peaks["duration_s"] == 2.0
    # the same move at a constant pace from rest: its first step breaks an acceleration limit
    q, amax = sol.joints, np.array([ACCEL[n] for n in sol.joint_names])
    assert np.max(np.abs(q[-1] - q[0]) / 40 / 0.05**2 / amax) > 1


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    """The default problem in 10 steps of 0.05 s (0.5 s), its limits enforced; its baseline solved
    by the CLI: (problem, solution, the run)."""
    d = tmp_path_factory.mktemp("short")
    text = DEFAULT.read_text()
    assert "\nhorizon: 40 " in text
    path = d / "short.yaml"
    path.write_text(text.replace("\nhorizon: 40 ", "\nhorizon: 10 "))
    out = d / "baseline.json"
    return path, out, cli("solve", str(path), "--method", "baseline", "--output", str(out))


def test_a_too_short_duration_is_lengthened_and_said(short, tmp_path):
    """0.5 s is too short for any rest-to-rest motion between these joints within the accelerations
    (a bound from the end joints alone): the baseline takes more steps of the same 0.05 s, succeeds
    and says how much longer; it is played as planned, within every limit."""
    path, out, res = short
    assert res.returncode == 0, res.stderr
    sol = ss.Solution.load(out)
    law = sol.extras["time_law"]
    steps = law["steps"]
    assert sol.success and sol.status == "Duration_Lengthened"
    assert sol.horizon == steps > 10
    assert len(sol.q) == len(sol.poses) == len(sol.sigma) == steps + 1
    assert rest_to_rest_bound(sol) > 0.5  # lengthening is needed
    assert steps * 0.05 >= law["time_optimal_s"] >= rest_to_rest_bound(sol) - 1e-9
    assert law["lengthened_by_s"] == pytest.approx((steps - 10) * 0.05, abs=1e-12)
    assert "Duration_Lengthened (success)" in res.stdout
    assert f"lengthened by {(steps - 10) * 0.05:.3f} s" in res.stdout, res.stdout
    assert f"{steps * 0.05:.3f} s ({steps} steps)" in res.stdout
    np.testing.assert_allclose(sol.times, 0.05 * np.arange(steps + 1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sol.positions[-1], sol.goal[:3], rtol=0, atol=1e-12)
    peaks = played_peaks(out, tmp_path)
    assert_within(peaks)
    assert peaks["timing"] == "planned"
    assert peaks["duration_s"] == pytest.approx(steps * 0.05, abs=1e-12)
    np.testing.assert_allclose(peaks["waypoint_times"], 0.05 * np.arange(steps + 1), rtol=0,
                               atol=1e-9)


def test_the_comparison_says_every_method_within_or_by_how_much(short, tmp_path):
    """`surestep compare` on the short problem: the baseline's row at its own duration and the
    lengthening said below the table; the gradient variant over its limits, said with its worst
    ratio."""
    res = cli("compare", str(short[0]), "--methods", "baseline", "gradient", "--output-dir",
              str(tmp_path / "out"))
    assert res.returncode == 0, res.stderr
    sols = {m: ss.Solution.load(tmp_path / "out" / f"{m}.json") for m in ("baseline", "gradient")}
    steps = sols["baseline"].horizon
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in res.stdout.splitlines()
             if line.startswith(("| method | max velocity", "| baseline |"))][-2:]
    row = dict(zip(*cells))  # the limits table's header and the baseline's row
    assert row["duration [s]"] == f"{steps * 0.05:.2f}" and row["violations"] == "0"
    assert float(row["played curve: peak / limit"].split()[0]) <= 1.0
    said = (f"baseline: {steps * 0.05:.3f} s ({steps} steps): the problem's 0.500 s (10 steps) "
            "lengthened by")
    assert said in res.stdout and "over the limits: baseline" not in res.stderr
    rep = sols["gradient"].motion_limits
    worst = max(abs(v.value) / v.limit for v in rep.violations
                if v.kind == "joint_acceleration")
    line = next(x for x in res.stderr.splitlines() if x.startswith("over the limits: gradient"))
    assert f"joint_acceleration {worst:.2f}x the limit" in line, line
    assert (tmp_path / "out" / "motion.png").is_file() and (tmp_path / "out" / "path.png").is_file()


def test_the_default_comparison_is_within_or_says_by_how_much(tmp_path):
    """Every method of the default comparison: no violation at the waypoints and its played curve
    within the limits, or a line on stderr with its worst ratio per kind broken and the played
    curve's peak."""
    res = cli("compare", str(DEFAULT), "--output-dir", str(tmp_path / "out"))
    assert res.returncode == 0, res.stderr
    rows = json.loads((tmp_path / "out" / "comparison.json").read_text())["methods"]
    over = 0
    for row in rows:
        m = row["method"]
        rep = ss.Solution.load(tmp_path / "out" / f"{m}.json").motion_limits
        if rep.violations:
            over += 1
            line = next(x for x in res.stderr.splitlines()
                        if x.startswith(f"over the limits: {m} "))
            assert "x the limit" in line and "the played curve's peak" in line
            assert all(f"{k} " in line for k in {v.kind for v in rep.violations})
        else:
            assert f"over the limits: {m} " not in res.stderr
            assert rep.played_curve.within, (m, rep.played_curve)
    assert over >= 1 and {r["method"] for r in rows} >= {"baseline", "ocp"}
    base = ss.Solution.load(tmp_path / "out" / "baseline.json")
    assert base.success and base.motion_limits.violations == []


def test_baselines_without_enforced_limits_keep_the_constant_pace(default_problem):
    """`limits.enforce: false`: the line at a constant pace as before (equal steps in position), no
    time law; tests/test_stored_plans.py pins these baselines' joints to 1e-10."""
    assert not default_problem.limits.enforce
    sol = ss.solve(default_problem, "baseline")
    assert sol.status == "not optimised" and "time_law" not in sol.extras
    assert sol.horizon == default_problem.horizon
    steps = np.diff(sol.positions, axis=0)
    np.testing.assert_allclose(steps, np.broadcast_to(steps[0], steps.shape), rtol=0, atol=1e-12)
    np.testing.assert_allclose(steps[0] * sol.horizon, sol.positions[-1] - sol.positions[0],
                               rtol=0, atol=1e-12)


def test_a_moving_camera_holds_its_last_pose_after_the_horizon():
    """Type 3 (the camera moves once) with its limits enforced needs more than its 20 steps: the
    plan's camera poses hold the last one after step 20, and a rollout through the problem's own 20
    camera changes runs it whole."""
    problem = ss.load_problem(REPO / "problems" / "type3_camera_moves_once.yaml")
    problem = problem.with_sections(limits={"enforce": True})
    setup = build_setup(problem)
    sol = ss.solve(problem, "baseline")
    T = problem.horizon
    assert sol.status == "Duration_Lengthened" and sol.horizon > T
    cams = np.array(sol.problem_record.camera_poses)
    assert len(cams) == sol.horizon + 1 and not np.array_equal(cams[0], cams[T])  # it moved
    np.testing.assert_array_equal(cams[T:], np.broadcast_to(cams[T], cams[T:].shape))
    ro = rollout(setup.eval_model, np.asarray(sol.poses), n=3, rng=0,
                 changes=setup.camera_changes())
    assert ro.pos_err.shape == (3,) and np.all(np.isfinite(ro.pos_err))


def test_a_line_no_time_law_keeps_within_is_a_failure_that_says_why(write_problem, capsys):
    """A tool speed of 10 um/s would need hours: beyond the search (MAX_STEPS) the baseline is the
    line at a constant pace in the problem's steps, status Motion_Limits_Violated, exit 1, said."""
    from surestep_ocp.methods.baseline import MAX_STEPS

    path = write_problem(lambda t: t.update(limits={"enforce": True, "tool_speed": 1e-5}), "slow")
    sol = ss.solve(ss.load_problem(path), "baseline")
    assert not sol.success and sol.status == "Motion_Limits_Violated" and sol.horizon == 20
    assert f"at most {MAX_STEPS} steps" in sol.extras["time_law"]["not_within"]
    assert main(["solve", str(path), "--method", "baseline"]) == 1
    assert "no time law keeps the straight line within the limits" in capsys.readouterr().out
