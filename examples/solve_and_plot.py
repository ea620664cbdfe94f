"""Solve one problem with the OCP and the straight line, and plot Tr(Sigma_t) and
the image-plane path.

    .venv/bin/python examples/solve_and_plot.py [--horizon 20] [--output-dir out/example]
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

import surestep_ocp as ss

ap = argparse.ArgumentParser()
ap.add_argument("--horizon", type=int, default=20)
ap.add_argument("--output-dir", default="out/example")
args = ap.parse_args()

problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(args.horizon)
# [m], axis-angle [rad], camera frame
problem = problem.with_goal(pose=[0.045, 0.005, 0.115, 0.60, 0.10, 1.40])
fig, (ax_tr, ax_uv) = plt.subplots(1, 2, figsize=(10, 4))
for method in ("baseline", "ocp"):
    sol = ss.solve(problem, method)
    print(f"{method:9s} {sol.status:16s} Tr(Sigma_T) = {sol.trace_final:.3e}  "
          f"({sol.solve_time_s * 1e3:.1f} ms)")
    ax_tr.semilogy(sol.times, [c.trace() for c in sol.covariances], label=method)
    # [m], camera frame: the pinhole projection (u, v) = (fx x / z + cx, fy y / z + cy)
    p = sol.positions
    cam = problem.camera.intrinsics
    ax_uv.plot(cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy, "o-",
               label=method)
ax_tr.set(xlabel="time [s]", ylabel="Tr(Sigma_t) [m^2 + rad^2, mixed]")
ax_uv.set(xlabel="u [px]", ylabel="v [px]", xlim=(0, cam.width), ylim=(cam.height, 0))
ax_tr.legend(), ax_uv.legend()
out = Path(args.output_dir)
out.mkdir(parents=True, exist_ok=True)
fig.savefig(out / "solve_and_plot.png", dpi=100)
print(f"wrote {out / 'solve_and_plot.png'}")
