"""Random configurations (surestep_ocp.evaluation.configs) and the `evaluate` runner
(surestep_ocp.evaluation.evaluation)."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from surestep_ocp.evaluation import evaluation

from surestep_ocp.evaluation import evaluation_report
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.errors import ProblemError, SurestepError
from surestep_ocp.evaluation.metrics import relative
from surestep_ocp.evaluation.rollout import METRICS

REPO = Path(__file__).resolve().parents[1]
EVAL = REPO / "problems" / "evaluations" / "evaluation.yaml"


@pytest.fixture(scope="module")
def sampler() -> ConfigurationSampler:
    return ConfigurationSampler(load_evaluation(EVAL))


def test_configurations_are_reachable_and_in_image(sampler):
    """evaluation.yaml loads; its configurations are seeded, in the image, in the depth range and
    reachable."""
    spec = sampler.spec
    assert spec.horizon == 20 and spec.base.horizon == 20
    intr = spec.base.camera.intrinsics
    for i in range(8):
        cfg = sampler.sample(0, i)
        assert np.array_equal(cfg.q_goal, sampler.sample(0, i).q_goal)  # same draw every time
        # raises if a joint is outside its limits or a pose behind the camera
        setup = sampler.setup_of(cfg)
        assert setup.ocp.horizon == 20
        for q, x in ((cfg.q_start, setup.x_start), (cfg.q_goal, setup.x_goal)):
            assert np.all(q >= setup.robot.lower) and np.all(q <= setup.robot.upper)
            # the pose is the FK of a joint sample
            np.testing.assert_allclose(setup.pose_of(q), x, atol=1e-12)
            assert spec.depth[0] <= x[2] <= spec.depth[1]
            u, v = intr.project(x[:3])
            assert 0 < u < intr.width and 0 < v < intr.height
        assert np.linalg.norm(setup.x_start[:3] - setup.x_goal[:3]) >= spec.min_distance
    assert not np.array_equal(sampler.sample(0, 0).q_goal, sampler.sample(1, 0).q_goal)


@pytest.mark.parametrize("edit, key", [
    (lambda t: t.update(colour="red"), "colour"),
    (lambda t: t["accept"].update(depth=[0.3, 0.1]), "accept.depth"),
    (lambda t: t["goal_joints"]["high"].__setitem__(2, 0.5), "goal_joints.high[2]"),
    (lambda t: t.update(horizon="long"), "horizon"),
    (lambda t: t.pop("start_joints"), "start_joints"),
])
def test_evaluation_file_is_read_strictly(tmp_path, edit, key):
    """A bad evaluation file is an error naming the file and the key."""
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str(EVAL.parent / tree["base"])
    edit(tree)
    path = tmp_path / "bad_eval.yaml"
    path.write_text(yaml.safe_dump(tree))
    with pytest.raises(ProblemError) as exc:
        load_evaluation(path)
    assert "bad_eval.yaml" in str(exc.value) and key in str(exc.value)


def test_relative_scaling_is_the_papers():
    """y / b for positive metrics, 1 - (y - b) / b for negative ones (entropies); lower is better in
    both."""
    assert relative(2.0, 4.0) == pytest.approx(0.5)
    # lower (better) entropy than the baseline: < 1
    assert relative(-30.0, -20.0) == pytest.approx(0.5)
    assert relative(-10.0, -20.0) == pytest.approx(1.5)  # higher entropy: > 1
    assert relative(-20.0, -20.0) == 1.0 and np.isnan(relative(1.0, -1.0))
    # the table averages the per-configuration ratios
    recs = [{"metrics": {"model": {"baseline": {k: b for k in METRICS},
                                   "x": {k: y for k in METRICS}}}}
            for y, b in ((1.0, 2.0), (-30.0, -20.0), (3.0, -1.0))]
    rel = evaluation_report.relative_means(recs, ("baseline", "x"), ("model",))
    assert rel["model"]["x"]["trace_ml"] == (pytest.approx(0.5), 2)  # mixed signs excluded
    assert rel["model"]["baseline"]["entropy_ml"] == (pytest.approx(1.0), 3)


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="surestep")
    evaluation.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_evaluate_end_to_end_and_resume(tmp_path, capsys, count_evaluated):
    """`evaluate` writes table.md, raw.csv, solves.csv, boxplot.png; `--resume` only runs unfinished
    configs."""
    out = tmp_path / "run"
    base = ["evaluate", str(EVAL), "--rollouts", "5", "--seed", "0", "--output-dir", str(out),
            "--methods", "baseline,gradient", "--quiet"]
    assert _run(base + ["--configs", "2"]) == 0
    table = (out / "table.md").read_text()
    for text in ("Rollout mode `model`", "Rollout mode `true`", "failed", "SURESTEP (all)",
                 "mean of these ratios"):
        assert text in table
    with open(out / "raw.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["config", "mode", "method", "metric", "value", "missing"]
    assert all(r["missing"] == "" for r in rows)
    assert len(rows) == 2 * 2 * 2 * (len(METRICS) + 2)
    assert {r["metric"] for r in rows} == {*METRICS, "grasp_success", "observed"}
    assert {r["method"] for r in rows} == {"baseline", "gradient"}
    assert all(np.isfinite(float(r["value"])) for r in rows)
    with open(out / "solves.csv") as fh:
        solves = list(csv.DictReader(fh))
    assert list(solves[0]) == ["config", "method", "success", "status", "solve_time_s",
                               "iterations"]
    assert len(solves) == 4
    assert (out / "boxplot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    first = (out / "progress.jsonl").read_text().splitlines()
    assert sorted(json.loads(line)["config"] for line in first) == [0, 1]
    # the grasp success share is the share of rollouts within both tolerances (recomputed from the
    # errors)
    spec = load_evaluation(EVAL)
    for line in first:
        rec = json.loads(line)
        for mode in ("model", "true"):
            for m in ("baseline", "gradient"):
                pos, ori = (np.array(rec["pos_errors"][mode][m]),
                            np.array(rec["ori_errors"][mode][m]))
                assert len(pos) == len(ori) == 5
                want = np.mean((pos <= spec.grasp_position) & (ori <= spec.grasp_angle))
                assert rec["success"][mode][m] == pytest.approx(want)
                assert 0.0 <= rec["detected"][mode][m] <= 1.0
    for text in ("Simulated Table II", "82 %", "pos med", "Tr ML p90", "pos max [mm]"):
        assert text in table

    # a finished directory is not overwritten by accident
    with pytest.raises(SurestepError, match="--resume"):
        _run(base + ["--configs", "2"])
    # an interrupted write leaves a torn line: it is dropped, and only config 2 is run
    with open(out / "progress.jsonl", "a") as fh:
        fh.write('{"config": 2, "solv')
    calls = count_evaluated()
    capsys.readouterr()
    assert _run(base + ["--configs", "3", "--resume"]) == 0
    assert calls == [2]
    lines = (out / "progress.jsonl").read_text().splitlines()
    assert lines[:2] == first and json.loads(lines[2])["config"] == 2
    assert "| gradient |" in capsys.readouterr().out
    with open(out / "solves.csv") as fh:
        assert len(list(csv.DictReader(fh))) == 6
    # resuming with other settings is refused
    with pytest.raises(SurestepError, match="rollouts"):
        _run([*base[:3], "7", *base[4:], "--configs", "3", "--resume"])


def test_worker_processes_give_the_same_numbers(tmp_path):
    """`--jobs 2` (spawned worker processes, each with its own set-up) reproduces the in-process run
    exactly."""
    common = ["evaluate", str(EVAL), "--configs", "2", "--rollouts", "4", "--methods", "baseline",
              "--quiet", "--rollout-mode", "true"]
    assert _run(common + ["--output-dir", str(tmp_path / "one")]) == 0
    assert _run(common + ["--output-dir", str(tmp_path / "two"), "--jobs", "2"]) == 0
    assert (tmp_path / "one" / "raw.csv").read_text() == (tmp_path / "two" / "raw.csv").read_text()


def test_bad_arguments_are_user_errors(tmp_path):
    """Unknown methods and impossible counts raise SurestepError (the CLI's exit code 2)."""
    with pytest.raises(SurestepError, match="allowed"):
        _run(["evaluate", str(EVAL), "--methods", "magic", "--output-dir", str(tmp_path / "a"),
              "--quiet"])
    with pytest.raises(SurestepError, match="rollouts"):
        _run(["evaluate", str(EVAL), "--rollouts", "1", "--output-dir", str(tmp_path / "b"),
              "--quiet"])
    with pytest.raises(ProblemError, match="no such file"):
        _run(["evaluate", str(tmp_path / "nope.yaml"), "--output-dir", str(tmp_path / "c"),
              "--quiet"])


def test_robust_statistics_are_numpys():
    """Median and 90th percentile of the per-configuration ratios beside their mean; pooled rollout
    errors."""
    ys = [1.0, 2.0, 3.0, 10.0, 4.0]
    recs = [{"metrics": {"model": {"baseline": {k: 2.0 for k in METRICS},
                                   "x": {k: y for k in METRICS}}},
             "pos_errors": {"model": {"x": [y, 2 * y]}},
             "success": {"model": {"x": 0.5 if y < 5 else 0.0}}}
            for y in ys]
    st = evaluation_report.relative_stats(recs, ("baseline", "x"),
                                          ("model",))["model"]["x"]["pos_err_mean"]
    r = np.array(ys) / 2.0
    assert st == {"mean": pytest.approx(r.mean()), "median": pytest.approx(np.median(r)),
                  "p90": pytest.approx(np.percentile(r, 90)), "n": 5}
    assert st["median"] < st["mean"]  # one heavy configuration pulls the mean, not the median
    pooled = evaluation_report.pooled(recs, "pos_errors", "model", "x")
    assert sorted(pooled) == sorted(ys + [2 * y for y in ys])
    assert evaluation_report.success_share(recs, "model", "x") == (pytest.approx(0.4), 5)


def test_evaluation_file_detection_grasp_and_gradient_keys(tmp_path):
    """`detection`, `grasp` and `gradient` (over the base problem's) are read strictly, with stated
    defaults."""
    spec = load_evaluation(EVAL)
    assert spec.detection is not None and spec.grasp_position == 0.005 and spec.grasp_angle == 0.2
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str((EVAL.parent / tree["base"]).resolve())
    tree.update(detection={"margin": 0.05, "falloff": 0.1}, grasp={"position": 0.003},
                gradient={"preset": "paper"})
    path = tmp_path / "e.yaml"
    path.write_text(yaml.safe_dump(tree))
    spec = load_evaluation(path)
    assert ((spec.detection.margin, spec.detection.falloff, spec.grasp_position)
            == (0.05, 0.1, 0.003))
    assert spec.base.gradient.optimizer == "torch" and spec.base.gradient.trace_scale == 1e3
    tree["detection"] = {"enabled": False}
    path.write_text(yaml.safe_dump(tree))
    assert load_evaluation(path).detection is None
    for bad, key in (({"detection": {"margin": 0.3, "falloff": 0.3}}, "detection.falloff"),
                     ({"grasp": {"angle": -1}}, "grasp.angle"),
                     ({"gradient": {"preset": "x"}}, "gradient.preset"),
                     ({"detection": {"radius": 1}}, "radius")):
        t = {**tree, **bad}
        path.write_text(yaml.safe_dump(t))
        with pytest.raises(ProblemError) as exc:
            load_evaluation(path)
        assert "e.yaml" in str(exc.value) and key in str(exc.value)


@pytest.mark.parametrize("value", ["-0.1", ".nan", ".inf", "'a'", "true", "0.49", "[0.1]"])
def test_bad_detection_falloff_is_one_line_exit_2_naming_the_key(tmp_path, value):
    """`surestep evaluate` with a bad `detection.falloff` (negative, not finite, not a number, or
    with the margin past half the image) stops before any work: one line naming the file and the
    key, exit 2, no traceback."""
    import subprocess
    import sys

    text = EVAL.read_text()
    assert "  falloff: 0.0 " in text
    tree = yaml.safe_load(text.replace("  falloff: 0.0 ", f"  falloff: {value} "))
    tree["base"] = str((EVAL.parent / tree["base"]).resolve())
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(tree))
    res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "evaluate", str(path),
                          "--configs", "1", "--rollouts", "2", "--methods", "baseline", "--quiet",
                          "--output-dir", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert (len(lines) == 1 and "bad.yaml" in lines[0]
            and "detection.falloff" in lines[0]), res.stderr
    assert not (tmp_path / "o").exists()


def test_sweep_expands_into_runs(tmp_path):
    """A sweep file's runs and grid become evaluate runs with their own derived files and a
    summary."""
    from surestep_ocp.evaluation.sweep import load_sweep, run_sweep

    sweep = tmp_path / "s.yaml"
    sweep.write_text(yaml.safe_dump({
        "evaluation": str(EVAL), "configs": 1, "rollouts": 2, "rollout_mode": "true",
        "methods": ["baseline"], "runs": [{"name": "noisy", "noise": {"V_f0": 0.04}}],
        "grid": {"detection.falloff": [0.0, 0.1]}}))
    s = load_sweep(sweep)
    assert [r["name"] for r in s["runs"]] == ["noisy", "detection.falloff=0.0",
                                              "detection.falloff=0.1"]
    table = run_sweep(sweep, tmp_path / "out", progress=False)
    for name in ("noisy", "detection.falloff=0.0", "detection.falloff=0.1"):
        assert (tmp_path / "out" / name / "table.md").is_file()
        assert f"| {name} | true | baseline | 1.000 |" in table
    assert load_evaluation(tmp_path / "out" / "detection.falloff=0.1"
                           / "evaluation.yaml").detection.falloff == 0.1
    noisy = load_evaluation(tmp_path / "out" / "noisy" / "evaluation.yaml")
    assert (noisy.base.noise.V_f0 == pytest.approx(0.04 * np.eye(6))
            or np.allclose(noisy.base.noise.V_f0, 0.04))
    for bad, key in (({"runs": [{"name": "a"}, {"name": "a"}]}, "runs[1].name"),
                     ({"colour": 1}, "colour"), ({"runs": []}, "runs")):
        sweep.write_text(yaml.safe_dump({"evaluation": str(EVAL), **bad}))
        with pytest.raises(ProblemError) as exc:
            load_sweep(sweep)
        assert key in str(exc.value)


def test_raw_csv_says_why_a_value_is_missing(tmp_path):
    """A method that produced no plan has empty values in raw.csv and the solver's status beside
    them (no NaN)."""
    from surestep_ocp.evaluation.evaluation_report import write_outputs

    out = tmp_path / "run"
    assert _run(["evaluate", str(EVAL), "--rollouts", "3", "--seed", "0", "--output-dir", str(out),
                 "--configs", "1", "--methods", "baseline", "--quiet", "--rollout-mode",
                 "model"]) == 0
    rec = json.loads((out / "progress.jsonl").read_text().splitlines()[0])
    rec["solves"]["ocp"] = {"success": False, "status": "error: UnreachablePose: no IK",
                            "solve_time_s": 0.1, "iterations": 0, "evaluated": False}
    header = json.loads((out / "run.json").read_text())
    write_outputs([rec], out, ["baseline", "ocp"], ["model"], header, load_evaluation(EVAL))
    with open(out / "raw.csv") as fh:
        rows = list(csv.DictReader(fh))
    missing = [r for r in rows if r["method"] == "ocp"]
    assert (missing and all(r["value"] == "" and r["missing"] == "error: UnreachablePose: no IK"
                            for r in missing))
    assert all(r["missing"] == "" and np.isfinite(float(r["value"])) for r in rows
               if r["method"] == "baseline")


# An evaluation file's own `limits:` (replacing its base problem's).


def write_evaluation(tmp_path, base=None, **keys):
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str(base or (EVAL.parent / tree["base"]).resolve())
    tree.update(keys)
    path = tmp_path / "e.yaml"
    path.write_text(yaml.safe_dump(tree))
    return path


def test_an_evaluation_file_sets_its_own_limits(tmp_path, write_problem):
    # inherited from needle_regrasp_paper_pace.yaml
    assert not load_evaluation(EVAL).base.limits.enforce
    spec = load_evaluation(write_evaluation(tmp_path, limits={"enforce": True, "tool_speed": 0.05,
                                                              "joint_velocity": {"yaw": 0.3}}))
    lim = spec.base.limits
    assert lim.enforce and lim.tool_speed == 0.05 and lim.joint_velocity == (("yaw", 0.3),)
    sampler = ConfigurationSampler(spec)
    assert sampler.problem(sampler.sample(0, 1)).limits == lim  # every configuration's problem
    # a base problem that enforces them, an evaluation file that does not: the evaluation's section
    # replaces it
    base = write_problem(lambda t: t.update(limits={"enforce": True, "tool_speed": 0.2}),
                         "enforcing")
    assert load_evaluation(write_evaluation(tmp_path, base=base)).base.limits.enforce
    spec = load_evaluation(write_evaluation(tmp_path, base=base, limits={"enforce": False}))
    assert not spec.base.limits.enforce and spec.base.limits.tool_speed is None


@pytest.mark.parametrize("section, key", [({"enforce": "yes"}, "limits.enforce"),
                                          ({"joint_velocity": {"elbow": 1.0}},
                                           "limits.joint_velocity.elbow"),
                                          ({"tool_speed": -1}, "limits.tool_speed"),
                                          ({"rcm": 0.04}, "limits.rcm"),
                                          ([1, 2], "limits")])
def test_bad_limits_in_an_evaluation_file_are_named_errors(tmp_path, section, key):
    path = write_evaluation(tmp_path, limits=section)
    with pytest.raises(ProblemError) as exc:
        load_evaluation(path)
    msg = str(exc.value)
    assert "e.yaml" in msg and key in msg and len(msg.splitlines()) == 1, msg
