"""Re-plan at tracker rate: a Planner against a simulated 20 Hz tracker (the model's noise and EKF).

At each frame the tool reaches the plan's next waypoint, the tracker reports its mean and
covariance, and the planner plans the rest of the way over the steps left (warm-started, no
solver built in the loop).

    .venv/bin/python examples/replan_loop.py [--horizon 20] [--seed 0]
"""

import argparse
import time

import numpy as np

import surestep_ocp as ss

ap = argparse.ArgumentParser()
ap.add_argument("--horizon", type=int, default=20)
ap.add_argument("--seed", type=int, default=0)
args = ap.parse_args()

problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(args.horizon)
planner = ss.Planner(problem)  # builds one solver per horizon left, then plans once
print(f"built {len(planner.builds)} solvers in {planner.build_time_s:.2f} s; first plan "
      f"Tr(Sigma_T) = {planner.plan.trace_final:.3e}")
tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=args.seed)
times = []
for k in range(1, planner.horizon):
    mean, covariance = tracker.move_to(planner.plan.poses[k - planner.step])  # 1/20 s later
    t0 = time.perf_counter()
    plan = planner.replan(mean, covariance, step=k)  # camera_pose=... when the endoscope moves
    times.append(time.perf_counter() - t0)
    print(f"step {k:2d}: {plan.horizon:2d} steps left, {plan.status}, {times[-1] * 1e3:5.1f} ms, "
          f"planned Tr(Sigma_T) = {plan.trace_final:.3e}")
tracker.move_to(planner.plan.poses[-1])
error = np.linalg.norm(tracker.true_pose[:3] - planner.plan.positions[-1]) * 1e3
print(f"re-plan median {np.median(times) * 1e3:.1f} ms, worst {max(times) * 1e3:.1f} ms; "
      f"final position error {error:.2f} mm, "
      f"Tr(Sigma_T) of the tracker {np.trace(tracker.covariance):.3e}")
