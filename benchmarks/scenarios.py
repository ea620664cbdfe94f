"""Run `surestep compare` on every scenario file and print one table of Tr(Sigma_T) per method.

    .venv/bin/python benchmarks/scenarios.py [--output-dir out/scenarios] [--reuse]

`--reuse` only reads existing `<dir>/<scenario>/comparison.json` files.
Writes benchmarks/results/scenarios.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from surestep_ocp.solution import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ["needle_regrasp", "type1_easy", "type1_medium", "type1_hard", "type2_needle_arm_moves",
             "type3_camera_moves_once", "type4_camera_moves", "ur5_fixed_camera"]
METHODS = ["baseline", "gradient", "gradient-no-pose-loss", "ocp", "ocp-from-gradient"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output-dir", default=str(ROOT / "out" / "scenarios"))
    ap.add_argument("--reuse", action="store_true")
    args = ap.parse_args()
    out = Path(args.output_dir)
    head = "| scenario | " + " | ".join(f"{m} Tr(Σ_T)" for m in METHODS) + " | OCP / baseline | OCP time [s] |"
    lines = [head, "|" + "---|" * (len(METHODS) + 3)]
    for name in SCENARIOS:
        d = out / name
        if not args.reuse:
            subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "compare", str(ROOT / "problems" / f"{name}.yaml"),
                            "--output-dir", str(d)], check=False)
        rows = {r["method"]: r for r in json.loads((d / "comparison.json").read_text())["methods"]}
        cells = [f"{rows[m]['trace_final']:.2e}" + ("" if rows[m]["success"] else " (failed)") for m in METHODS]
        ocp = rows["ocp"]
        lines.append(f"| {name} | " + " | ".join(cells) +
                     f" | {ocp['trace_final'] / rows['baseline']['trace_final']:.3f} | {ocp['solve_time_s']:.2f} |")
    text = "\n".join(lines) + "\n"
    write_text_atomic(ROOT / "benchmarks" / "results" / "scenarios.md", text)
    print(text)


if __name__ == "__main__":
    main()
