"""`surestep evaluate --jobs 2` killed from outside: no pool worker outlives the run, the files are
whole or absent.

The run is started in its own session (so the test can clean up whatever is left), with far more
configurations than it can finish before the signal; the signal is sent once its first configuration
is in progress.jsonl (the pool's workers exist and work), waited for with a generous timeout. What
is checked does not depend on when the signal lands: the process tree (psutil) and the files.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

psutil = pytest.importorskip("psutil")

PROBLEMS_DIR = Path(__file__).resolve().parents[1] / "problems"

START_TIMEOUT_S = 300  # spawn, imports and the first configuration on a loaded 2-core machine
EXIT_TIMEOUT_S = 120
OUTPUTS = {"run.json", "progress.jsonl", "table.md", "raw.csv", "solves.csv", "boxplot.png"}


def _start(out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "surestep_ocp.cli", "evaluate",
           str(PROBLEMS_DIR / "evaluations" / "evaluation.yaml"), "--configs", "5000", "--rollouts",
           "2", "--rollout-mode", "model", "--methods", "baseline",
           "--jobs", "2", "--quiet", "--output-dir", str(out)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    # files, not pipes: a worker that outlives the run keeps a pipe open and a read would wait for
    # it
    with open(out.parent / "stdout.txt", "w") as so, open(out.parent / "stderr.txt", "w") as se:
        return subprocess.Popen(cmd, stdout=so, stderr=se, env=env, start_new_session=True)


def _wait_started(proc: subprocess.Popen, out: Path) -> list:
    """Block until a configuration is recorded; the run's descendants then (the pool's workers among
    them)."""
    prog = out / "progress.jsonl"
    deadline = time.monotonic() + START_TIMEOUT_S
    while not (prog.is_file() and prog.read_bytes().count(b"\n") >= 1):
        if proc.poll() is not None:
            pytest.fail(f"the run ended before it started (exit {proc.returncode}): "
                        f"{(out.parent / 'stderr.txt').read_text()}")
        if time.monotonic() > deadline:
            pytest.fail(f"no configuration recorded within {START_TIMEOUT_S} s")
        time.sleep(0.2)
    return psutil.Process(proc.pid).children(recursive=True)


def _survivors(procs: list) -> list:
    """The processes of `procs` still running after up to 30 s (zombies count as gone)."""
    _, alive = psutil.wait_procs(procs, timeout=30)
    return [p for p in alive if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


def _check_files(out: Path, whole_lines: bool = True) -> None:
    """Every file is one of the run's outputs (no temporary file left), and each is whole."""
    names = {p.name for p in out.iterdir()}
    assert names <= OUTPUTS, ("unexpected files (temporary files of a torn write?): "
                              f"{sorted(names - OUTPUTS)}")
    header = json.loads((out / "run.json").read_text())
    assert header["methods"] == ["baseline"]
    from surestep_ocp.evaluation.evaluation import read_progress

    if whole_lines:
        text = (out / "progress.jsonl").read_text()
        assert text.endswith("\n")
        records = [json.loads(line) for line in text.splitlines()]
    else:  # a write cut by SIGKILL may leave a torn last line, which --resume drops
        records = list(read_progress(out / "progress.jsonl").values())
    assert records and all(set(r["solves"]) == {"baseline"} for r in records)


def _cleanup(proc: subprocess.Popen, procs: list) -> None:
    for p in procs:
        try:
            p.kill()
        except psutil.Error:
            pass
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _pool_started(proc, out):
    """(the run's processes once it has started, its two pool workers: what must not survive)."""
    workers = _wait_started(proc, out)
    pool = [p for p in workers if "spawn_main" in " ".join(p.cmdline())]
    assert len(pool) == 2, [p.cmdline() for p in workers]
    return workers, pool


def test_sigterm_stops_the_pool_workers_and_exits_143_with_one_line(tmp_path):
    out = tmp_path / "run"
    proc = _start(out)
    workers = []
    try:
        workers, pool = _pool_started(proc, out)
        proc.send_signal(signal.SIGTERM)  # to the parent only, as `kill -TERM <pid>`
        proc.wait(timeout=EXIT_TIMEOUT_S)
        err = (tmp_path / "stderr.txt").read_text()
        assert proc.returncode == 143, err
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("surestep: terminated (SIGTERM): "), err
        assert "configurations kept" in lines[0] and "--resume" in lines[0]
        assert "Traceback" not in err
        assert _survivors(workers) == [], "pool workers outlived the run"
        _check_files(out)
    finally:
        _cleanup(proc, workers)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_sigkill_of_the_parent_takes_the_workers_with_it(tmp_path):
    """The parent cannot clean up after SIGKILL; its workers end by themselves (parent-death
    signal)."""
    out = tmp_path / "run"
    proc = _start(out)
    workers = []
    try:
        workers, pool = _pool_started(proc, out)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=EXIT_TIMEOUT_S)
        assert _survivors(pool) == [], "pool workers outlived a killed parent"
        _check_files(out, whole_lines=False)
    finally:
        _cleanup(proc, workers)
