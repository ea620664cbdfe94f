"""`surestep export` keeps the file reader's promises: every malformed or extreme
solution file or option is a one-line error naming the file or the flag, exit code 2, and nothing is
written; no NaN or Infinity reaches an output; the work is bounded (waypoints, samples, the URDF
read)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.cli import main
from surestep_ocp.errors import SurestepError
from surestep_ocp.output.files import NonFinite
from user_errors import assert_user_error  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def baseline(tmp_path_factory) -> dict:
    """The default problem's straight-line plan (fast: no optimisation), as its solution file's
    dict."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup
    from surestep_ocp.methods.registry import run_method

    d = tmp_path_factory.mktemp("baseline")
    setup = build_setup(load_problem(REPO / "problems" / "needle_regrasp_paper_pace.yaml"))
    path = run_method(setup, "baseline").save(d / "baseline.json")
    sol = json.loads(Path(path).read_text())
    sol["robot"]["urdf"] = str(REPO / "robots" / "psm.urdf")
    if sol.get("ecm"):
        sol["ecm"]["urdf"] = str(REPO / "robots" / "ecm.urdf")
    return sol


def run_export(tmp_path, capsys, text: str | None, *extra, sol=None, fmt="json"):
    """Export `text` (a solution file's text) or the dict `sol`; the exit code and stderr's
    lines."""
    src = tmp_path / "plan.json"
    src.write_text(text if text is not None else json.dumps(sol))
    out = tmp_path / f"out.{fmt}"
    capsys.readouterr()
    code = main(["export", str(src), "--format", fmt, "--output", str(out), "--no-plot", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err, out




def edited(sol: dict, edit) -> dict:
    d = json.loads(json.dumps(sol))
    edit(d)
    return d


def test_the_baseline_exports(baseline, tmp_path, capsys):
    code, err, out = run_export(tmp_path, capsys, None, sol=baseline)
    assert code == 0, err
    assert "Infinity" not in out.read_text() and "NaN" not in out.read_text()


@pytest.mark.parametrize("value", [math.inf, math.nan, -math.inf])
def test_a_non_finite_recorded_limit_is_an_error(baseline, tmp_path, capsys, value):
    """Reproducer: `limits.velocity[0]` of Infinity exported with exit 0 and a bare `Infinity` in
    the JSON."""
    sol = edited(baseline, lambda d: d["limits"]["velocity"].__setitem__(0, value))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "limits.velocity")


@pytest.mark.parametrize(("key", "value"),
                         [("tool_speed_m_s", math.inf), ("tool_rotation_rad_s", math.nan),
                          ("rcm_min_distance_m", math.inf)])
def test_a_non_finite_recorded_tool_limit_is_an_error(baseline, tmp_path, capsys, key, value):
    sol = edited(baseline, lambda d: d["limits"].__setitem__(key, value))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", key)


def test_a_deeply_nested_file_is_an_error(tmp_path, capsys):
    """Reproducer: a 100000-deep `[` was a RecursionError (exit 1)."""
    code, err, out = run_export(tmp_path, capsys, "[" * 100_000)
    assert_user_error(code, err, out, "plan.json")


def test_a_5000_digit_integer_is_an_error(baseline, tmp_path, capsys):
    """Reproducer: a 5000-digit integer was a ValueError from the int conversion (exit 1)."""
    text = json.dumps(baseline).replace('"step_s": 0.05', '"step_s": ' + "9" * 5000)
    code, err, out = run_export(tmp_path, capsys, text)
    assert_user_error(code, err, out, "plan.json")


def test_integer_joint_names_are_an_error(baseline, tmp_path, capsys):
    sol = edited(baseline, lambda d: d.update(joint_names=list(range(len(d["joint_names"])))))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "joint_names")


@pytest.mark.parametrize("step", [1e300, 1e-300])
def test_an_extreme_step_in_the_file_is_an_error(baseline, tmp_path, capsys, step):
    sol = edited(baseline, lambda d: d["timing"].update(step_s=step))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "timing.step_s")


@pytest.mark.parametrize("step", ["1e300", "1e-300"])
def test_an_extreme_step_option_is_an_error(baseline, tmp_path, capsys, step):
    code, err, out = run_export(tmp_path, capsys, None, "--step-s", step, sol=baseline)
    assert_user_error(code, err, out, "--step-s")


def test_a_tiny_recorded_velocity_limit_is_an_error(baseline, tmp_path, capsys):
    """Reproducer: a velocity limit of 1e-300 was an internal error (exit 1)."""
    sol = edited(baseline, lambda d: d["limits"]["velocity"].__setitem__(0, 1e-300))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "limits.velocity")


@pytest.mark.parametrize("flag", ["--velocity-limit", "--acceleration-limit"])
@pytest.mark.parametrize("value", ["1e-300", "1e300"])
def test_an_extreme_limit_option_is_an_error(baseline, tmp_path, capsys, flag, value):
    code, err, out = run_export(tmp_path, capsys, None, flag, f"yaw={value}", sol=baseline)
    assert_user_error(code, err, out, flag)


def test_too_many_waypoints_is_an_error(baseline, tmp_path, capsys):
    """Reproducer: 1e5 waypoints took 72 s and then ran out of memory."""
    sol = edited(baseline, lambda d: d.update(q=[d["q"][0]] * 100_000))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "10000")


def test_a_huge_solution_file_is_an_error(tmp_path, capsys):
    code, err, out = run_export(tmp_path, capsys, " " * 60_000_000 + "{}")
    assert_user_error(code, err, out, "plan.json", "bytes")


def test_a_urdf_that_is_not_a_regular_file_is_an_error(baseline, tmp_path, capsys):
    sol = edited(baseline, lambda d: d["robot"].update(urdf="/dev/zero"))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "robot.urdf")


def test_a_too_large_urdf_is_an_error(baseline, tmp_path, capsys):
    big = tmp_path / "big.urdf"
    with big.open("wb") as f:
        f.truncate(60_000_000)
    sol = edited(baseline, lambda d: d["robot"].update(urdf=str(big)))
    code, err, out = run_export(tmp_path, capsys, json.dumps(sol))
    assert_user_error(code, err, out, "plan.json", "robot.urdf", "bytes")


def test_too_many_samples_is_an_error(baseline, tmp_path, capsys):
    """A slow limit and a fast rate would write more than a million samples: refused before the
    work."""
    code, err, out = run_export(tmp_path, capsys, None, "--rate", "10000", "--step-s", "100",
                                sol=baseline)
    assert_user_error(code, err, out, "samples")


def test_the_writers_refuse_non_finite_numbers(baseline, tmp_path):
    """check_finite at every writer: a trajectory holding NaN writes nothing."""
    from surestep_ocp.output.export import export_solution

    traj, _ = export_solution(_saved(baseline, tmp_path), "json", tmp_path / "ok.json", plot=False)
    traj.q[3, 1] = math.nan
    from surestep_ocp.output.export_writers import write

    for fmt, name in (("json", "a.json"), ("csv", "a.csv"), ("ros2", "a.yaml"), ("rosbag2", "bag")):
        extra = {"rate_hz": 100.0, "arm": "PSM1"} if fmt == "rosbag2" else {}
        with pytest.raises(NonFinite):
            write(traj, fmt, tmp_path / name, {"source": "x"}, None, **extra)
        assert not (tmp_path / name).exists()
    traj.q[3, 1] = 0.0
    with pytest.raises(NonFinite):
        write(traj, "json", tmp_path / "b.json", {"source": math.inf}, None)


def _saved(sol: dict, tmp_path: Path) -> Path:
    p = tmp_path / "saved.json"
    p.write_text(json.dumps(sol))
    return p


def test_a_solution_object_is_checked_too(baseline, tmp_path):
    """`export_solution` given a dict-backed object checks it as the file reader does."""
    from surestep_ocp.output.export_load import load_solution

    with pytest.raises(SurestepError, match="limits.velocity"):
        load_solution(_saved(edited(baseline,
                                    lambda d: d["limits"]["velocity"].__setitem__(0, 1e-300)),
                             tmp_path))
    assert np.isfinite(np.array(load_solution(_saved(baseline, tmp_path))["q"])).all()


# ------------------------------------------------------------ a hostile disk and user (issue 48)
def _export(tmp_path, capsys, sol, out, fmt, *extra):
    src = tmp_path / "plan.json"
    src.write_text(json.dumps(sol))
    capsys.readouterr()
    code = main(["export", str(src), "--format", fmt, "--output", str(out), *extra])
    return code, capsys.readouterr().err.strip().splitlines()


def test_two_exports_never_share_a_figure(baseline, tmp_path, capsys):
    """`bag.1` and `bag.2` both wrote `bag_motion.png` (the second replaced the first's plot): the
    figure is named after the whole output name."""
    for name in ("traj.1", "traj.2"):
        assert _export(tmp_path, capsys, baseline, tmp_path / name, "csv")[0] == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["plan.json", "traj.1", "traj.1_motion.png", "traj.2", "traj.2_motion.png"]


def test_a_rate_too_low_for_the_plan_is_refused(baseline, tmp_path, capsys):
    """A rosbag2 at --rate 0.5 held one set-point step for the whole 20-step motion, at 1e-6 the
    goal 1,000,000 s later: fewer set-points than planned steps is one line, exit 2, no bag."""
    for rate in ("0.5", "1e-6"):
        code, err = _export(tmp_path, capsys, baseline, tmp_path / "bag", "rosbag2", "--no-plot",
                            "--rate", rate)
        assert code == 2 and len(err) == 1 and "fewer than its 20 planned steps" in err[0], err
        assert not (tmp_path / "bag").exists()


def test_a_full_disk_is_a_clean_error_and_leaves_nothing(baseline, tmp_path, capsys, monkeypatch):
    """The bag's storage failing (sqlite3's `database or disk is full`) was `internal error:
    OperationalError`; now one line naming the bag, exit 2, and neither the bag nor its figure."""
    import sqlite3

    from rosbags.rosbag2 import Writer

    def full(*args, **kwargs):
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(Writer, "write", full)
    out = tmp_path / "bag"
    code, err = _export(tmp_path, capsys, baseline, out, "rosbag2")
    assert code == 2 and err == [f"surestep: {out}: cannot write the bag (database or disk is "
                                 "full)"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.json"]


@pytest.mark.parametrize("fmt", ["csv", "rosbag2"])
def test_an_interrupted_export_leaves_all_its_files_or_none(baseline, tmp_path, capsys,
                                                           monkeypatch, fmt):
    """Ctrl-C while the figure is drawn (after the data was written) left the data without its
    figure: now nothing of the export is left."""
    from surestep_ocp.output import export

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(export, "plot_trajectory", interrupted)
    code, _ = _export(tmp_path, capsys, baseline, tmp_path / "out", fmt)
    assert code == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.json"]


def test_an_empty_output_path_is_refused(baseline, tmp_path, capsys, monkeypatch):
    """`-o ''` exited 0 and wrote nothing; now exit 2 naming it."""
    monkeypatch.chdir(tmp_path)
    code, err = _export(tmp_path, capsys, baseline, "", "csv")
    assert code == 2 and err == ["surestep: '': an empty path; the export must be a named file"]


@pytest.mark.parametrize("output", [".", "..", "/", "sub/.."])
@pytest.mark.parametrize("fmt", ["csv", "ros2", "rosbag2"])
def test_an_output_with_no_name_at_its_end_is_refused(baseline, tmp_path, capsys, monkeypatch,
                                                      output, fmt):
    """`-o .` was an internal ValueError (its figure is named after the output's name, which `.`
    has not); now exit 2 naming it, nothing written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    code, err = _export(tmp_path, capsys, baseline, output, fmt)
    assert code == 2 and len(err) == 1 and err[0].startswith(f"surestep: {output}: no name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.json", "sub"]
