"""Re-plan at tracker rate within the dVRK's motion limits: a Planner against a simulated 20 Hz
tracker.

At each frame the robot has played the current plan's curve up to the next waypoint, the tracker
reports the tool's mean and covariance, and the planner plans the rest of the way from the robot's
moving state (joints, velocities, accelerations), within every limit, warm-started from the previous
plan (no solver built in the loop).

    .venv/bin/python examples/replan_loop.py [--problem FILE] [--seed 0] [--interpreted]
"""

import argparse

import numpy as np

import surestep_ocp as ss

ap = argparse.ArgumentParser()
ap.add_argument("--problem", default="problems/needle_regrasp.yaml")
ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--interpreted", action="store_true",
                help="no derivatives compiled to C (no compile on first use)")
args = ap.parse_args()

problem = ss.load_problem(args.problem)
# builds the solver of every horizon left, then plans
planner = ss.Planner(problem.with_solver(codegen=False) if args.interpreted else problem)
print(f"built in {planner.build_time_s:.2f} s; first plan {planner.plan.status}, "
      f"Tr(Sigma_T) = {planner.plan.trace_final:.3e}")
tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=args.seed)
times, k = [], 0
# the goal is waypoint `planner.horizon` (later if a correction needed more time)
while k + 1 < planner.horizon:
    k += 1
    mean, covariance = tracker.move_to(planner.plan.poses[k - planner.step])  # 1/20 s later
    plan = planner.replan(mean, covariance, step=k)  # camera_pose=... when the endoscope moves
    times.append(plan.replan.time_s)
    kept = (" (previous plan kept)" if plan.replan.kept_previous
            else " (registration held)" if plan.replan.registration_held else "")
    print(f"step {k:2d}: {plan.horizon:2d} steps left, {plan.status}, "
          f"{times[-1] * 1e3:5.1f} ms{kept}")
tracker.move_to(planner.plan.poses[-1])
error = np.linalg.norm(tracker.true_pose[:3] - planner.plan.positions[-1]) * 1e3
print(f"re-plan median {np.median(times) * 1e3:.1f} ms, worst {max(times) * 1e3:.1f} ms; goal "
      f"reached at step {planner.horizon} "
      f"({planner.horizon - planner.setup.ocp.horizon} later than planned); "
      f"final position error {error:.2f} mm")
