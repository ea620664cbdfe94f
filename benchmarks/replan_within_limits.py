"""Re-planning within the motion limits (experimental): one `Planner` episode on the default problem
with `solver.name: interior` against a simulated tracker, re-planning at every waypoint from the
executed curve's state.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/replan_within_limits.py [--seed 0]

Per re-plan: its status, iterations and time (builds apart), and whether the previous plan was kept.
Writes benchmarks/results/replan_within_limits.md; the last line is `replan_within_limits:
converged=<n> of=<n> median_ms=<ms> worst_ms=<ms> first_kept=<step>` (times of the converged
re-plans).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread



def main() -> None:
    ap = h.parser(__doc__, seed=0)
    args = ap.parse_args()
    problem = h.load_problem(h.DEFAULT_PROBLEM).with_solver(name="interior")
    planner = h.Planner(problem)
    tracker = h.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=args.seed)
    rows, ok_ms, first_kept = [], [], None
    k = 0
    while k + 1 < planner.horizon:
        k += 1
        mean, cov = tracker.move_to(planner.plan.poses[k - planner.step])
        plan = planner.replan(mean, cov, step=k)
        r = plan.replan
        ms = r.time_s * 1e3
        if plan.success:
            ok_ms.append(ms)
        elif first_kept is None:
            first_kept = k
        rows.append((k, plan.status, plan.iterations, f"{ms:.1f}",
                     "yes" if r.kept_previous else "no"))
        print(*rows[-1], flush=True)
    s = h.stats(ok_ms) if ok_ms else None
    lines = ["# Re-planning within the motion limits (experimental)", "",
             ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/replan_within_limits.py "
              f"--seed {args.seed}`: the default problem with `solver.name: interior`, one episode "
              "against a simulated tracker, a re-plan at every waypoint from the executed curve's "
              "state (docs/realtime.md)."), "",
             f"Converged: {len(ok_ms)} of {len(rows)}"
             + (f", median {s.median:.1f} ms, worst {s.worst:.1f} ms" if s else "") + ".", "",
             *h.table(["step", "status", "iterations", "ms", "previous plan kept"], rows), ""]
    last = h.last_line("replan_within_limits", h.key_values(
        converged=len(ok_ms), of=len(rows), median_ms=f"{s.median:.1f}" if s else "na",
        worst_ms=f"{s.worst:.1f}" if s else "na", first_kept=first_kept))
    text = "\n".join(lines + [last]) + "\n"
    h.write_result("replan_within_limits.md", text)
    print(text)


if __name__ == "__main__":
    main()
