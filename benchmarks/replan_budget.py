"""The re-plan's iteration budget within the limits: episodes of the default problem against a
simulated tracker per budget (`Planner(replan_iterations=...)`), re-plan times against what the
plans are for (the tracker's final covariance and position error).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/replan_budget.py [--episodes 8] \\
        [--budgets 12 6 4] [--first-mu MU] [--output replan_budget.md]

Writes benchmarks/results/replan_budget.md; the last line is `replan_budget: <budget>=<median ms>
...`.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402


def episode(problem, budget: int, seed: int) -> tuple[list[float], int, float, float, int]:
    """(re-plan times [ms], failures, the tracker's final Tr(Sigma), its final position error [mm],
    steps the goal moved later) of one episode."""
    planner = h.Planner(problem, replan_iterations=budget)
    tracker = h.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=seed)
    ms, fails, k = [], 0, 0
    while k + 1 < planner.horizon:
        k += 1
        mean, cov = tracker.move_to(planner.plan.poses[k - planner.step])
        plan = planner.replan(mean, cov, step=k)
        ms.append(plan.replan.time_s * 1e3)
        fails += not plan.success
    tracker.move_to(planner.plan.poses[-1])
    error = float(np.linalg.norm(tracker.true_pose[:3] - planner.setup.x_goal[:3]) * 1e3)
    later = planner.horizon - planner.setup.ocp.horizon
    return ms, fails, float(np.trace(tracker.covariance)), error, later


def main() -> None:
    ap = h.parser(__doc__)
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--budgets", type=int, nargs="+", default=[12, 6, 4])
    ap.add_argument("--first-mu", type=float, default=None,
                    help="the re-plans' first barrier parameter (default: the Planner's REPLAN_MU)")
    ap.add_argument("--output", default="replan_budget.md")
    args = ap.parse_args()
    first_mu = h.replan_first_mu(args.first_mu)
    problem = h.load_problem(h.DEFAULT_PROBLEM)
    rows, medians = [], {}
    for budget in args.budgets:
        runs = [episode(problem, budget, seed) for seed in range(args.episodes)]
        ms = [t for r in runs for t in r[0]]
        s = h.stats(ms)
        medians[str(budget)] = f"{s.median:.1f}"
        rows.append((budget, f"{s.median:.1f} / {s.p90:.1f} / {s.worst:.1f}",
                     f"{sum(r[1] for r in runs)} of {len(ms)}",
                     f"{np.mean([r[2] for r in runs]):.3e}",
                     f"{np.mean([r[3] for r in runs]):.2f} mm", max(r[4] for r in runs)))
        print(*rows[-1], flush=True)
    lines = ["# The re-plan's iteration budget within the limits", "",
             (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/replan_budget.py --episodes "
              f"{args.episodes} --budgets {' '.join(map(str, args.budgets))}"
              + (f" --first-mu {args.first_mu:g}" if args.first_mu is not None else "")
              + f"` (the re-plans' first barrier parameter {first_mu:g}): the default "
              "problem, "
              f"seeds 0-{args.episodes - 1} per budget (docs/realtime.md)."), "",
             *h.table(["budget", "re-plan median / p90 / worst [ms]", "kept the previous plan",
                       "tracker's final Tr(Sigma), mean", "final position error, mean",
                       "most steps later"], rows), ""]
    text = "\n".join(lines + [h.last_line("replan_budget", h.key_values(**medians))]) + "\n"
    h.write_result(args.output, text)
    print(text)


if __name__ == "__main__":
    main()
