"""An evaluation file's own `limits:` (replacing its base problem's), and `surestep compare`'s exit status with the
limits enforced: only the methods that plan within the limits (the OCP methods) count; the others' violations are
printed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from surestep_ocp.errors import ProblemError
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

ROOT = Path(__file__).resolve().parents[1]
EVAL = ROOT / "problems" / "evaluations" / "evaluation.yaml"


def write_evaluation(tmp_path, base=None, **keys):
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str(base or (EVAL.parent / tree["base"]).resolve())
    tree.update(keys)
    path = tmp_path / "e.yaml"
    path.write_text(yaml.safe_dump(tree))
    return path


def test_an_evaluation_file_sets_its_own_limits(tmp_path, write_problem):
    assert not load_evaluation(EVAL).base.limits.enforce  # inherited from needle_regrasp_paper_pace.yaml
    spec = load_evaluation(write_evaluation(tmp_path, limits={"enforce": True, "tool_speed": 0.05,
                                                              "joint_velocity": {"yaw": 0.3}}))
    lim = spec.base.limits
    assert lim.enforce and lim.tool_speed == 0.05 and lim.joint_velocity == (("yaw", 0.3),)
    sampler = ConfigurationSampler(spec)
    assert sampler.problem(sampler.sample(0, 1)).limits == lim  # every configuration's problem
    # a base problem that enforces them, an evaluation file that does not: the evaluation's section replaces it
    base = write_problem(lambda t: t.update(limits={"enforce": True, "tool_speed": 0.2}), "enforcing")
    assert load_evaluation(write_evaluation(tmp_path, base=base)).base.limits.enforce
    spec = load_evaluation(write_evaluation(tmp_path, base=base, limits={"enforce": False}))
    assert not spec.base.limits.enforce and spec.base.limits.tool_speed is None


@pytest.mark.parametrize("section, key", [({"enforce": "yes"}, "limits.enforce"),
                                          ({"joint_velocity": {"elbow": 1.0}}, "limits.joint_velocity.elbow"),
                                          ({"tool_speed": -1}, "limits.tool_speed"),
                                          ({"rcm": 0.04}, "limits.rcm"),
                                          ([1, 2], "limits")])
def test_bad_limits_in_an_evaluation_file_are_named_errors(tmp_path, section, key):
    path = write_evaluation(tmp_path, limits=section)
    with pytest.raises(ProblemError) as exc:
        load_evaluation(path)
    msg = str(exc.value)
    assert "e.yaml" in msg and key in msg and len(msg.splitlines()) == 1, msg


def compare(tmp_path, problem, methods):
    return subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "compare", str(problem), "--methods", *methods,
                           "--output-dir", str(tmp_path / "out")], capture_output=True, text=True, cwd=ROOT,
                          timeout=600)


def test_compare_counts_only_the_methods_that_honour_the_limits(tmp_path, write_problem):
    """Enforced at 0.1 s per step: the OCP's plan is within the limits, the straight line's is not (it starts at
    full speed from rest): exit 0, the baseline's violations printed. Before, exit 1 ("failed: baseline")."""
    path = write_problem(lambda t: t.update(limits={"enforce": True}, timing={"step_s": 0.1, "tracker_hz": 20},
                                            solver={**t["solver"], "codegen": False}), "enforced")
    res = compare(tmp_path, path, ["baseline", "ocp"])
    assert res.returncode == 0, res.stderr
    assert "over the limits: baseline" in res.stderr and "joint_acceleration" in res.stderr
    assert "failed" not in res.stderr


def test_compare_exits_1_when_an_ocp_method_breaks_the_limits(tmp_path, write_problem):
    """An OCP plan that cannot meet them (rest to rest in 3 steps of 0.05 s: IPOPT reports it infeasible) fails
    the comparison, whatever the baseline does."""
    path = write_problem(lambda t: t.update(limits={"enforce": True}, horizon=3,
                                            solver={**t["solver"], "codegen": False}), "tight")
    res = compare(tmp_path, path, ["baseline", "ocp"])
    assert res.returncode == 1, res.stderr
    assert "failed: ocp" in res.stderr and "over the limits: baseline" in res.stderr
