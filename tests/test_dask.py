"""`surestep evaluate --scheduler`: the configurations on a Dask cluster (a small in-process
LocalCluster here)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from surestep_ocp.evaluation import evaluation
from surestep_ocp.errors import SurestepError

# in the test extra; skipped only where it is not installed
distributed = pytest.importorskip("distributed")

REPO = Path(__file__).resolve().parents[1]
EVAL = next(p for p in (REPO / "problems" / "evaluations" / "evaluation.yaml",
                        REPO / "problems" / "evaluation.yaml")
             if p.is_file())


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="surestep")
    evaluation.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None, silence_logs=40) as c:
        yield c


def test_dask_gives_the_process_pools_numbers_and_resumes(tmp_path, cluster):
    """Same raw.csv as the in-process run; progress.jsonl per configuration; --resume runs only what
    is missing."""
    common = ["evaluate", str(EVAL), "--rollouts", "4", "--methods", "baseline", "--quiet",
              "--rollout-mode", "true"]
    assert _run(common + ["--configs", "3", "--output-dir", str(tmp_path / "local")]) == 0
    out = tmp_path / "dask"
    assert _run(common + ["--configs", "2", "--output-dir", str(out), "--scheduler",
                          cluster.scheduler_address]) == 0
    assert sorted(json.loads(x)["config"]
                  for x in (out / "progress.jsonl").read_text().splitlines()) == [0, 1]
    assert _run(common + ["--configs", "3", "--output-dir", str(out), "--scheduler",
                          cluster.scheduler_address, "--resume"]) == 0
    lines = (out / "progress.jsonl").read_text().splitlines()
    assert [json.loads(x)["config"] for x in lines][2] == 2 and len(lines) == 3
    assert (out / "raw.csv").read_text() == (tmp_path / "local" / "raw.csv").read_text()


def test_unreachable_scheduler_is_a_user_error(tmp_path, monkeypatch):
    monkeypatch.setattr(evaluation, "DASK_CONNECT_TIMEOUT", "1s")
    with pytest.raises(SurestepError, match="cannot connect"):
        evaluation.run_evaluation(EVAL, tmp_path / "x", configs=1, rollouts=2,
                                  methods=("baseline",), progress=False,
                                  scheduler="tcp://127.0.0.1:9")
    assert not (tmp_path / "x" / "run.json").exists()  # refused before anything was written
