"""Run `surestep compare` on every scenario file and print one table of Tr(Sigma_T) per method.

    .venv/bin/python benchmarks/scenarios.py [--output-dir out/scenarios] [--reuse]
        [--limits [--step-s S] [--horizon T]]

`--reuse` only reads existing `<dir>/<scenario>/comparison.json` files.
`--limits`: each scenario with `limits: {enforce: true}` (the default limits) at `--step-s` seconds
per step (default: the file's, 0.05) with one observation per waypoint (`tracker_hz = 1 / step_s`)
and `--horizon` steps (default: the file's; the default problem's 40 is the pace its limits allow),
written beside the results as `<dir>/<scenario>.yaml`; a plan that breaks a limit is a failure (the
gradient variants do not honour limits; the baseline takes more steps where it must, said in its
comparison). Writes benchmarks/results/scenarios.md (with --limits
scenarios_limits_step<S>[_T<T>].md).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import yaml  # noqa: E402

ROOT, SCENARIOS = h.ROOT, h.SCENARIOS
METHODS = ["baseline", "gradient", "gradient-no-pose-loss", "ocp", "ocp-from-gradient"]


def main() -> None:
    ap = h.parser(__doc__)
    ap.add_argument("--output-dir", default=str(ROOT / "out" / "scenarios"))
    ap.add_argument("--reuse", action="store_true")
    ap.add_argument("--limits", action="store_true",
                    help="enforce the motion limits (module docstring)")
    ap.add_argument("--step-s", type=float,
                    help="seconds per step with --limits (default: the file's)")
    ap.add_argument("--horizon", type=int, help="steps with --limits (default: the file's)")
    args = ap.parse_args()
    suffix = ("" if not args.limits else f"_limits_step{args.step_s or 0.05:g}"
              + (f"_T{args.horizon}" if args.horizon else ""))
    out = Path(args.output_dir + suffix)
    lines = h.table(["scenario", *(f"{m} Tr(Σ_T)" for m in METHODS), "OCP / baseline",
                     "OCP time [s]"])
    for name in SCENARIOS:
        d = out / name
        problem = h.scenario_file(name)
        if args.limits:
            problem = with_limits(problem, out / f"{name}.yaml", args.step_s, args.horizon)
        if not args.reuse:
            subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "compare", str(problem),
                            "--output-dir", str(d)], check=False)
        rows = {r["method"]: r for r in json.loads((d / "comparison.json").read_text())["methods"]}
        cells = [f"{rows[m]['trace_final']:.2e}" + ("" if rows[m]["success"] else " (failed)")
                 for m in METHODS]
        ocp = rows["ocp"]
        lines.append(f"| {name} | " + " | ".join(cells) +
                     f" | {ocp['trace_final'] / rows['baseline']['trace_final']:.3f} | "
                     f"{ocp['solve_time_s']:.2f} |")
    if args.limits:
        lines = [f"Limits enforced (`limits: {{enforce: true}}`, default limits) at step_s "
                 f"{args.step_s or 0.05:g} s"
                 + (f" and T = {args.horizon}" if args.horizon else "")
                 + (", one observation per waypoint; `(failed)`: the plan breaks a limit or the "
                    "solver found none within them. Machine shared with other jobs (2 cores)."), "",
                 "`.venv/bin/python benchmarks/scenarios.py --limits"
                 f"{f' --step-s {args.step_s:g}' if args.step_s else ''}"
                 f"{f' --horizon {args.horizon}' if args.horizon else ''}`",
                 "", *lines]
    text = "\n".join(lines) + "\n"
    h.write_result(f"scenarios{suffix}.md", text)
    print(text)


def with_limits(problem: Path, dest: Path, step_s: float | None,
                horizon: int | None = None) -> Path:
    """`problem` with `limits: {enforce: true}` (and the pace `step_s`, one observation per
    waypoint; `horizon` steps) at `dest`."""
    tree = yaml.safe_load(problem.read_text())
    if horizon is not None:
        tree["horizon"] = horizon
    tree["limits"] = {**(tree.get("limits") or {}), "enforce": True}
    if step_s is not None:
        tree["timing"] = {"step_s": step_s, "tracker_hz": 1.0 / step_s}
    dest.parent.mkdir(parents=True, exist_ok=True)
    return h.write_result(Path(dest), yaml.safe_dump(tree, sort_keys=False))


if __name__ == "__main__":
    main()
