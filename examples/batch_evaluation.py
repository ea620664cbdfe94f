"""A small batch evaluation: a few goals and noise levels, every method, one CSV row per solve.

    .venv/bin/python examples/batch_evaluation.py [--horizon 20] [--output-dir out/batch]
"""

import argparse
import csv
from pathlib import Path

import surestep_ocp as ss

ap = argparse.ArgumentParser()
ap.add_argument("--horizon", type=int, default=20)
ap.add_argument("--methods", nargs="+", default=["baseline", "gradient", "ocp"])
ap.add_argument("--output-dir", default="out/batch")
args = ap.parse_args()

base = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(args.horizon)
goals = {"right edge": [0.045, 0.005, 0.115, 0.60, 0.10, 1.40],
         "centre": [0.0, 0.0, 0.12, 0.40, 0.40, 1.53]}
rows = []
for goal_name, goal in goals.items():
    for V_d0 in (0.1, 0.01):  # depth noise scale (the paper's is 0.1)
        problem = base.with_goal(pose=goal).with_noise(V_d0=V_d0)
        for method in args.methods:
            sol = ss.solve(problem, method)
            rows.append({"goal": goal_name, "V_d0": V_d0, "method": method, "success": sol.success,
                         "trace_final": sol.trace_final, "solve_time_s": sol.solve_time_s})
            print(" ".join(f"{v:.3e}" if isinstance(v, float) else str(v)
                           for v in rows[-1].values()))
out = Path(args.output_dir)
out.mkdir(parents=True, exist_ok=True)
with open(out / "batch.csv", "w", newline="") as fh:
    writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
print(f"wrote {out / 'batch.csv'}")
