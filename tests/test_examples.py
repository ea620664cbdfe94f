"""Every script in examples/ runs (small horizons), writing into a temporary folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("script", "extra", "wrote"), [
    ("solve_and_plot.py", ["--horizon", "6"], "solve_and_plot.png"),
    ("replan_loop.py", ["--interpreted"], None),
    ("batch_evaluation.py", ["--horizon", "6", "--methods", "baseline", "ocp"], "batch.csv"),
    ("dvrk_servo_jp.py", ["--horizon", "6"], "servo_jp_trajectory.json"),  # a dry run (no --robot)
])
def test_example_runs(tmp_path, script, extra, wrote):
    args = [sys.executable, str(ROOT / "examples" / script), *extra]
    if wrote:
        args += ["--output-dir", str(tmp_path)]
    run = subprocess.run(args, check=False, cwd=ROOT, capture_output=True, text=True, timeout=900,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert run.returncode == 0, run.stderr[-2000:]
    if wrote:
        assert (tmp_path / wrote).stat().st_size > 0
        if script == "dvrk_servo_jp.py":  # without the dVRK's client: what would be sent, at 100 Hz
            assert ("dry run: " in run.stdout and "servo_jp([" in run.stdout
                    and "at 100 Hz" in run.stdout)
    else:
        assert "re-plan median" in run.stdout


def _readme_python_blocks() -> list[str]:
    """The README's "Python API" code blocks, in order."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("### Python API"):]
    section = section[:section.index("\n## ")] if "\n## " in section else section
    return [part.split("```", 1)[0] for part in section.split("```python\n")[1:]]


def test_readme_python_api_starts_with_the_loop_within_the_limits():
    """The README's first Python example is the 20 Hz re-planning loop on the default problem, whose
    file enforces the motion limits (the loop itself runs in examples/replan_loop.py above)."""
    import surestep_ocp as ss

    first = _readme_python_blocks()[0]
    assert 'ss.Planner(ss.load_problem("problems/needle_regrasp.yaml"))' in first
    assert "planner.replan(mean, cov, step=k)" in first
    assert ss.load_problem(ROOT / "problems" / "needle_regrasp.yaml").limits.enforce


def test_readme_python_api_script_runs(tmp_path):
    """The README's "Python API" script that changes and solves one problem, copied as a user would
    (at T = 6), runs from another folder."""
    script = next(b for b in _readme_python_blocks() if "with_horizon(20)" in b)
    script = script.replace("with_horizon(20)", "with_horizon(6)")
    assert "with_horizon(6)" in script
    (tmp_path / "api.py").write_text(script)
    run = subprocess.run([sys.executable, "api.py"], check=False, cwd=tmp_path, capture_output=True,
                         text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "Solve_Succeeded" in run.stdout
