"""The evaluation with and without the motion limits enforced, side by side (issue 14, item 6).

    OPENBLAS_NUM_THREADS=1 .venv/bin/surestep sweep problems/evaluations/motion_limits.yaml
        --output-dir out/motion_limits --jobs 2
    .venv/bin/python benchmarks/motion_limits_evaluation.py [--sweep-dir out/motion_limits]

Reads each run's `table.md` (written by `surestep evaluate` inside the sweep) and writes
benchmarks/results/evaluation_motion_limits.md: per rollout mode and method, the three runs'
relative rows (to the baseline of the same run) and absolute final errors (median, 90th percentile
and worst [mm]), the grasp share, the failed plans and the solve time; then the sweep's own summary.
"""

from __future__ import annotations

import harness as h

from pathlib import Path  # noqa: E402

ROOT = h.ROOT
RUNS = ("paper-pace", "t40-free", "t40-enforced")
LABEL = {"paper-pace": "20 x 0.05 s, reported", "t40-free": "40 x 0.05 s, reported",
         "t40-enforced": "40 x 0.05 s, enforced"}


def tables(path: Path) -> dict[str, dict[str, dict[str, dict[str, str]]]]:
    """{mode: {"rel" | "abs": {method: {column: cell}}}} from one `table.md`."""
    out, mode, header, kind = {}, None, None, None
    for line in path.read_text().splitlines():
        if line.startswith("## Rollout mode"):
            mode, header = line.split("`")[1], None
            out[mode] = {"rel": {}, "abs": {}}
        elif mode and line.startswith("| method |"):
            header = [c.strip() for c in line.strip("|").split("|")]
            kind = "abs" if "pos max [mm]" in header else ("rel" if "grasp" in header else None)
        elif mode and header and kind and line.startswith("| ") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if len(cells) == len(header):
                out[mode][kind].setdefault(cells[0], dict(zip(header, cells)))
        elif not line.startswith("|"):
            header = None if line.strip() else header
    return out


def main() -> None:
    ap = h.parser(__doc__)
    ap.add_argument("--sweep-dir", type=Path, default=ROOT / "out" / "motion_limits")
    args = ap.parse_args()
    data = {run: tables(args.sweep_dir / run / "table.md") for run in RUNS}
    lines = ["# The evaluation with the motion limits enforced, beside the unconstrained rows", "",
             ("`OPENBLAS_NUM_THREADS=1 .venv/bin/surestep sweep "
              "problems/evaluations/motion_limits.yaml --output-dir out/motion_limits --jobs 2`, "
              "then `.venv/bin/python benchmarks/motion_limits_evaluation.py` (100 "
              "configurations x 50 rollouts, seed 0; relative columns: mean over configurations of "
              "the ratio to the baseline of the same run; `failed`: plans that are not a success, "
              "here the baseline's and the gradient variant's over the enforced limits, rolled "
              "out as they are)"), ""]
    for mode in ("model", "true"):
        lines += [f"## Rollout mode `{mode}`", "",
                  *h.table(["method", "steps, limits", "Tr ML mean", "pos mean", "pos med [mm]",
                            "pos p90 [mm]", "pos max [mm]", "ori max [mrad]", "grasp", "failed",
                            "solve time [s]"])]
        methods = list(data[RUNS[0]][mode]["rel"])
        for m in methods:
            for run in RUNS:
                rel, ab = data[run][mode]["rel"].get(m), data[run][mode]["abs"].get(m)
                if rel is None or ab is None:
                    continue
                lines.append(f"| {m} | {LABEL[run]} | {rel['Tr ML mean']} | {rel['pos mean']} | "
                             f"{ab['pos med [mm]']} | {ab['pos p90 [mm]']} | {ab['pos max [mm]']} "
                             f"| {ab['ori max [mrad]']} | {rel['grasp']} | {rel['failed']} | "
                             f"{rel['solve time [s]']} |")
        lines.append("")
    summary = args.sweep_dir / "sweep.md"
    if summary.is_file():
        lines += ["## The sweep's summary (`out/motion_limits/sweep.md`)", "",
                  summary.read_text().strip(), ""]
    text = "\n".join(lines)
    h.write_result("evaluation_motion_limits.md", text)
    print(text)


if __name__ == "__main__":
    main()
