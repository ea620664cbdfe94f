"""`surestep evaluate` and `surestep sweep` keep the file reader's promises at every entry
point.

Inputs are never overwritten (nor written through a symbolic link), one writer per output folder, a
resumed run uses only whole, finite records of the same settings, and a bad sweep file is a one-line
user error (exit 2).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from surestep_ocp.errors import SurestepError
from surestep_ocp.evaluation import evaluation

REPO = Path(__file__).resolve().parents[1]
EVAL = REPO / "problems" / "evaluations" / "evaluation.yaml"
TINY = ["--configs", "2", "--rollouts", "2", "--methods", "baseline", "--rollout-mode", "model",
        "--quiet"]


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="surestep")
    evaluation.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surestep_ocp.cli", *map(str, argv)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)


def _user_error(res: subprocess.CompletedProcess, *words: str) -> str:
    """Exit 2, one line on stderr naming what is wrong, no traceback."""
    err = res.stderr.strip()
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert len(err.splitlines()) == 1 and err.startswith("surestep: "), err
    assert "Traceback" not in err and "internal error" not in err
    for w in words:
        assert w in err, (w, err)
    return err


def _evaluation_copy(path: Path) -> Path:
    """The shipped evaluation file at `path`, its base problem made absolute."""
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str((EVAL.parent / tree["base"]).resolve())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return path


def _sweep(path: Path, evaluation_file: str, **keys) -> Path:
    tree = {"evaluation": evaluation_file, "configs": 1, "rollouts": 2, "rollout_mode": "model",
            "methods": ["baseline"], "runs": [{"name": "runA"}], **keys}
    path.write_text(yaml.safe_dump(tree, sort_keys=False))
    return path


# -------------------------------------------------------- 1. sweep outputs never replace its inputs
def test_sweep_refuses_to_overwrite_its_own_evaluation_file(tmp_path):
    d = tmp_path / "D"
    ev = _evaluation_copy(d / "runA" / "evaluation.yaml")
    before = ev.read_bytes()
    sweep = _sweep(d / "sweep.yaml", "runA/evaluation.yaml")
    _user_error(_cli("sweep", sweep, "--output-dir", d, "--quiet"), "input", "evaluation.yaml")
    assert ev.read_bytes() == before
    assert not (d / "runA" / "progress.jsonl").exists()


def test_sweep_refuses_to_write_through_a_symbolic_link(tmp_path):
    ev = _evaluation_copy(tmp_path / "in" / "e.yaml")
    sweep = _sweep(tmp_path / "in" / "sweep.yaml", "e.yaml")
    target = tmp_path / "elsewhere.yaml"
    target.write_text("precious\n")
    (tmp_path / "out" / "runA").mkdir(parents=True)
    (tmp_path / "out" / "runA" / "evaluation.yaml").symlink_to(target)
    _user_error(_cli("sweep", sweep, "--output-dir", tmp_path / "out", "--quiet"), "symbolic link")
    assert target.read_text() == "precious\n" and ev.is_file()


def test_sweep_writes_its_run_files_atomically(tmp_path):
    """A run file is replaced by a rename (a new file), never rewritten in place: a hard link to it
    keeps its text."""
    from surestep_ocp.evaluation.sweep import load_sweep, write_run_files

    _evaluation_copy(tmp_path / "in" / "e.yaml")
    sweep = load_sweep(_sweep(tmp_path / "in" / "sweep.yaml", "e.yaml",
                              runs=[{"name": "runA", "noise": {"V_f0": 0.04}}]))
    out = tmp_path / "out" / "runA"
    out.mkdir(parents=True)
    other = tmp_path / "other"
    other.mkdir()
    for name in ("evaluation.yaml", "base.yaml"):
        (other / name).write_text("old\n")
        os.link(other / name, out / name)
    write_run_files(sweep, sweep["runs"][0], out)
    for name in ("evaluation.yaml", "base.yaml"):
        assert (other / name).read_text() == "old\n"
        assert (out / name).read_text() != "old\n"
    # no temporary file left
    assert sorted(p.name for p in out.iterdir()) == ["base.yaml", "evaluation.yaml"]


# ---------------------------------------------------- 2. one writer per folder; settings in records
def test_a_second_writer_into_the_same_folder_is_refused(tmp_path):
    from surestep_ocp.evaluation.run_lock import hold

    out = tmp_path / "run"
    out.mkdir()
    with hold(out):
        err = _user_error(_cli("evaluate", EVAL, *TINY, "--output-dir", out),
                          "another surestep process")
        assert str(out) in err
        with pytest.raises(SurestepError, match="another surestep process"):
            _run(["evaluate", str(EVAL), *TINY, "--output-dir", str(out)])
    assert not (out / "progress.jsonl").exists()
    # released: the run goes ahead
    assert _run(["evaluate", str(EVAL), *TINY, "--output-dir", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["run.json", "progress.jsonl", "table.md", "raw.csv", "solves.csv", "boxplot.png"])


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished tiny run (2 configurations, the baseline, rollouts in mode `model`)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert _run(["evaluate", str(EVAL), *TINY, "--seed", "0", "--output-dir", str(out)]) == 0
    return out


def _copy(finished: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(finished, out)
    return out


@pytest.mark.parametrize("flag,value", [("--seed", "1"), ("--rollouts", "3")])
def test_resume_without_run_json_checks_the_settings_in_the_records(finished, tmp_path, flag,
                                                                   value):
    out = _copy(finished, tmp_path)
    (out / "run.json").unlink()
    before = (out / "progress.jsonl").read_text()
    argv = [a for a in TINY]
    i = argv.index(flag) if flag in argv else None
    if i is None:
        argv += [flag, value]
    else:
        argv[i + 1] = value
    _user_error(_cli("evaluate", EVAL, *argv, "--output-dir", out, "--resume"), "other settings",
                flag[2:])
    assert (out / "progress.jsonl").read_text() == before
    assert not (out / "run.json").exists()


def test_records_carry_their_settings(finished):
    for line in (finished / "progress.jsonl").read_text().splitlines():
        rec = json.loads(line)
        assert rec["seed"] == 0 and rec["rollouts"] == 2


# --------------------------------------------------------- 3. --resume re-runs any record not whole
def _nan_metric(rec):
    rec["metrics"]["model"]["baseline"]["pos_err_mean"] = math.nan


def _nan_success(rec):
    rec["success"]["model"]["baseline"] = math.nan


def _string_metric(rec):
    rec["metrics"]["model"]["baseline"]["trace_ml"] = "abc"


def _null_metric(rec):
    rec["metrics"]["model"]["baseline"]["trace_ml"] = None


def _no_solve(rec):
    del rec["solves"]["baseline"]


def _no_metric(rec):
    del rec["metrics"]["model"]["baseline"]["entropy_ml"]


def _no_mode(rec):
    del rec["metrics"]["model"]


def _no_method(rec):
    del rec["metrics"]["model"]["baseline"]


def _short_errors(rec):
    rec["pos_errors"]["model"]["baseline"] = rec["pos_errors"]["model"]["baseline"][:1]


def _no_settings_no_run_json(rec):
    del rec["seed"]


BREAKS = [_nan_metric, _nan_success, _string_metric, _null_metric, _no_solve, _no_metric, _no_mode,
          _no_method, _short_errors, _no_settings_no_run_json]


@pytest.mark.parametrize("brk", BREAKS, ids=[b.__name__.lstrip("_") for b in BREAKS])
def test_resume_runs_a_broken_record_again(finished, tmp_path, capsys, brk, count_evaluated):
    out = _copy(finished, tmp_path)
    if brk is _no_settings_no_run_json:
        (out / "run.json").unlink()
    lines = (out / "progress.jsonl").read_text().splitlines()
    rec = json.loads(lines[1])
    brk(rec)
    lines[1] = json.dumps(rec)
    (out / "progress.jsonl").write_text("\n".join(lines) + "\n")
    calls = count_evaluated()
    capsys.readouterr()
    assert _run(["evaluate", str(EVAL), *TINY, "--seed", "0", "--output-dir", str(out),
                 "--resume"]) == 0
    assert calls == [1]
    err = capsys.readouterr().err
    assert "line 2" in err and "run again" in err
    with open(out / "raw.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(r["missing"] == "" and math.isfinite(float(r["value"])) for r in rows)
    assert (out / "raw.csv").read_text() == (finished / "raw.csv").read_text()
    assert [json.loads(x)["config"]
            for x in (out / "progress.jsonl").read_text().splitlines()] == [0, 1]


# ------------------------------------------------------------- 4. bad sweep files: one line, exit 2
def test_sweep_of_a_problem_file_is_a_user_error(tmp_path):
    problem = REPO / "problems" / "needle_regrasp.yaml"
    sweep = _sweep(tmp_path / "s.yaml", str(problem))
    _user_error(_cli("sweep", sweep, "--output-dir", tmp_path / "out", "--quiet"),
                "not an evaluation file")


@pytest.mark.parametrize("name", ["a\x00b", "tab\there", "x" * 300, "back\\slash"])
def test_a_run_name_that_is_no_folder_name_is_a_user_error(tmp_path, name):
    from surestep_ocp.evaluation.sweep import load_sweep

    _evaluation_copy(tmp_path / "e.yaml")
    sweep = _sweep(tmp_path / "s.yaml", "e.yaml", runs=[{"name": name}])
    with pytest.raises(SurestepError, match=r"runs\[0\]\.name"):
        load_sweep(sweep)
    if "\x00" in name:
        _user_error(_cli("sweep", sweep, "--output-dir", tmp_path / "out", "--quiet"),
                    "runs[0].name")


def test_a_grid_has_a_stated_bound(tmp_path):
    from surestep_ocp.evaluation.sweep import MAX_RUNS, load_sweep

    assert MAX_RUNS == 1000
    _evaluation_copy(tmp_path / "e.yaml")
    grid = {f"detection.k{i}": list(range(6)) for i in range(4)}  # 1296 points
    sweep = _sweep(tmp_path / "s.yaml", "e.yaml", grid=grid)
    with pytest.raises(SurestepError, match="at most 1000"):
        load_sweep(sweep)
    big = _sweep(tmp_path / "big.yaml", "e.yaml",
                 grid={f"k{i}": list(range(10)) for i in range(10)})
    _user_error(_cli("sweep", big, "--output-dir", tmp_path / "out", "--quiet"), "grid",
                "at most 1000")
    ok = _sweep(tmp_path / "ok.yaml", "e.yaml", runs=[],
                grid={"detection.falloff": [0.0, 0.1, 0.2], "seedless": list(range(333))})
    assert len(load_sweep(ok)["runs"]) == 999


# ------------------------------------------------ 5. --scheduler: a bad address, one line at once
@pytest.mark.parametrize("address, words", [("::::", ["'::::'", "tcp://host:8786"]),
                                            ("foo://x", ["unknown scheme 'foo'"]),
                                            ("tcp://127.0.0.1", ["missing port"]),
                                            ("tcp://h:70000", ["1..65535"]),
                                            ("inproc://zz", ["inproc://"])])
def test_a_scheduler_address_that_does_not_parse_is_one_line(tmp_path, address, words):
    """Refused before a dask `Client` is made (a half-made one printed a traceback later on:
    CHANGELOG)."""
    pytest.importorskip("distributed")
    out = tmp_path / "out"
    res = _cli("evaluate", EVAL, *TINY, "--output-dir", out, "--scheduler", address)
    _user_error(res, "--scheduler", *words)
    assert "Exception ignored" not in res.stderr
    assert not (out / "run.json").exists()
