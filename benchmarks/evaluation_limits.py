"""The Monte-Carlo evaluation with the motion limits enforced, beside the same run without them.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/evaluation_limits.py [--configs 100]
        [--rollouts 50] [--step-s 0.1] [--methods baseline,gradient,ocp] [--jobs 1] [--reuse]

problems/evaluations/evaluation.yaml with its base problem given `limits: {enforce: true}` (the
default limits) and `timing: {step_s: S, tracker_hz: 1 / S}` (one observation per waypoint: the
paper's belief model, so only the limits differ), written to out/evaluation_limits/, evaluated with
`surestep evaluate` in both rollout modes; then the unconstrained evaluation of the same
configurations and methods. The methods other than the OCP do not honour limits: their plans are
rolled out and counted as failed. Writes benchmarks/results/evaluation_100x50_limits.md (the OCP's
rows side by side, then both tables).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

ROOT, EVAL = h.ROOT, h.EVALUATION
OUT = ROOT / "out" / "evaluation_limits"


def files(step_s: float) -> Path:
    """The enforced base problem and the evaluation file that uses it; returns the evaluation
    file."""
    base = yaml.safe_load(h.PAPER_PACE_PROBLEM.read_text())
    base["limits"] = {"enforce": True}
    base["timing"] = {"step_s": step_s, "tracker_hz": 1.0 / step_s}
    h.write_result(OUT / "needle_regrasp_limits.yaml", yaml.safe_dump(base, sort_keys=False))
    text = EVAL.read_text()
    if "base: ../needle_regrasp_paper_pace.yaml" not in text:
        raise SystemExit(f"{EVAL}: its base is no longer ../needle_regrasp.yaml; update "
                         "this script")
    return h.write_result(OUT / "evaluation_limits.yaml",
                             text.replace("base: ../needle_regrasp_paper_pace.yaml",
                                          "base: needle_regrasp_limits.yaml"))


def ocp_rows(table: str) -> dict[str, str]:
    """The OCP's relative row per rollout mode of a `surestep evaluate` table.md."""
    rows, mode = {}, None
    for line in table.splitlines():
        if line.startswith("## Rollout mode"):
            mode = line.split("`")[1]
        elif mode and line.startswith("| ocp |") and mode not in rows:
            rows[mode] = line
    return rows


def main() -> None:
    ap = h.parser(__doc__, configs=100)
    ap.add_argument("--rollouts", type=int, default=50)
    ap.add_argument("--step-s", type=float, default=0.1)
    ap.add_argument("--methods", default="baseline,gradient,ocp")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--reuse", action="store_true", help="only read the existing tables")
    args = ap.parse_args()
    runs = {"enforced": files(args.step_s), "unconstrained": EVAL}
    took = {}
    for name, spec in runs.items():
        t0 = time.perf_counter()
        if not args.reuse:
            subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "evaluate", str(spec),
                            "--configs", str(args.configs), "--rollouts", str(args.rollouts),
                            "--methods", args.methods,
                            "--rollout-mode", "both", "--jobs", str(args.jobs), "--quiet",
                            "--output-dir", str(OUT / name)], check=True)
        took[name] = time.perf_counter() - t0
    tables = {name: (OUT / name / "table.md").read_text() for name in runs}
    head = next(line for line in tables["enforced"].splitlines() if line.startswith("| method |"))
    lines = [(f"# Evaluation with the motion limits enforced ({args.configs} x {args.rollouts}, "
              "both rollout modes)"),
             "",
             "`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/evaluation_limits.py --configs "
             f"{args.configs} --rollouts {args.rollouts} --step-s {args.step_s:g} "
             f"--methods {args.methods}`"
             + ("" if args.reuse
                else f" ({took['enforced']:.0f} s enforced, {took['unconstrained']:.0f} s "
                     "unconstrained; a machine shared with other jobs, 2 cores)"), "",
             (f"Enforced: the base problem with `limits: {{enforce: true}}` and step_s "
              f"{args.step_s:g} s, one observation per waypoint (the paper's belief model, as the "
              "unconstrained run), so the two runs differ by the limits only. Methods other than "
              "the OCP do not honour the limits: their plans are rolled out as they are and "
              "counted in `failed`. Relative to the baseline of the same run:"), "",
             head, "|" + "---|" * (head.count("|") - 1)]  # the evaluation's own header
    for mode in ("model", "true"):
        for name in runs:
            row = ocp_rows(tables[name]).get(mode, "")
            lines.append(row.replace("| ocp |", f"| ocp {name}, mode {mode} |", 1))
    for name in runs:
        lines += ["", f"## {name.capitalize()} run (`{runs[name].relative_to(ROOT)}`)", "",
                  tables[name].split("\n", 1)[1]]
    h.write_result(f"evaluation_{args.configs}x{args.rollouts}_limits.md", "\n".join(lines) + "\n")
    print("\n".join(lines[:14 + 4]))


if __name__ == "__main__":
    main()
