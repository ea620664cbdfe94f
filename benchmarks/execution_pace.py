"""The evaluation with every plan run no faster than the tool's speed limits, beside the planned
pace (issue 16).

    OPENBLAS_NUM_THREADS=1 .venv/bin/surestep sweep problems/evaluations/execution_pace.yaml
        --output-dir out/execution_pace --jobs 2
    .venv/bin/python benchmarks/execution_pace.py [--sweep-dir out/execution_pace]

Reads each run's `progress.jsonl` and writes benchmarks/results/evaluation_execution_pace.md: per
run, rollout mode and method, the pooled final position errors of every rollout (median, 90th
percentile, worst [mm]), the grasp share, the share of steps observed and the rollout steps per plan
(median / max); first, per run and mode, the worst rollout of all methods against the 0.37 m
diagonal of the evaluation's workspace (docs/evaluation.md).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = h.ROOT
RUNS = ("t20-planned", "t20-limits", "t40-planned", "t40-limits")
WORKSPACE_DIAGONAL_MM = 370.0


def main() -> None:
    ap = h.parser(__doc__)
    ap.add_argument("--sweep-dir", type=Path, default=ROOT / "out" / "execution_pace")
    args = ap.parse_args()
    worst_lines, rows = [], []
    for run in RUNS:
        recs = list(h.read_progress(args.sweep_dir / run / "progress.jsonl").values())
        methods = json.loads((args.sweep_dir / run / "run.json").read_text())["methods"]
        for mode in ("model", "true"):
            worst = (0.0, "", -1)
            for m in methods:
                e = [(x * 1e3, r["config"]) for r in recs for x in r["pos_errors"][mode].get(m, [])]
                err = np.array([x for x, _ in e])
                succ = np.mean([r["success"][mode][m] for r in recs if m in r["success"][mode]])
                obs = np.mean([r["detected"][mode][m] for r in recs if m in r["detected"][mode]])
                steps = [r["solves"][m]["rollout_steps"] for r in recs
                         if "rollout_steps" in r["solves"].get(m, {})]
                k = int(np.argmax(err))
                if err[k] > worst[0]:
                    worst = (float(err[k]), m, e[k][1])
                rows.append(f"| {run} | {mode} | {m} | {np.median(err):.1f} | "
                            f"{np.percentile(err, 90):.1f} | {err[k]:.1f} | {succ:.1%} | {obs:.1%} "
                            f"| {np.median(steps):.0f} / {max(steps)} | {len(recs)} |")
            worst_lines.append(f"| {run} | {mode} | {worst[0]:.1f} | {worst[1]} | {worst[2]} | "
                               f"{'yes' if worst[0] > WORKSPACE_DIAGONAL_MM else 'no'} |")
    lines = ["# The evaluation at the planned pace and at the tool's speed limits", "",
             ("`OPENBLAS_NUM_THREADS=1 .venv/bin/surestep sweep "
              "problems/evaluations/execution_pace.yaml --output-dir out/execution_pace --jobs 2`, "
              "then `.venv/bin/python benchmarks/execution_pace.py`. 100 configurations x 50 "
              "rollouts per mode, seed 0; `limits` runs split every plan step faster than 0.1 m/s "
              "or pi/2 rad/s into equal steps of 0.05 s (`surestep_ocp/evaluation/pacing.py`), the "
              "plans are the same."), "",
             "## The worst rollout of each run (every method)", "",
             *h.table(["run", "mode", "worst final position error [mm]", "method", "configuration",
                       "above the 0.37 m diagonal"], worst_lines), "",
             "## Per method: pooled final position errors of every rollout", "",
             *h.table(["run", "mode", "method", "pos med [mm]", "pos p90 [mm]", "pos max [mm]",
                       "grasp", "observed", "rollout steps (median / max)", "configs"], rows), ""]
    h.write_result("evaluation_execution_pace.md", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
