"""Plans within the motion limits at tracker rate: the interior-point Newton method against IPOPT, cold and in a
20 Hz re-planning loop.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py [--configs 100] [--seed 0]

Cold: the default problem (problems/needle_regrasp.yaml: 40 steps of 50 ms, the limits enforced) and the first
`--configs` configurations of problems/evaluations/evaluation.yaml at the same horizon, pace and limits, each solved
by `solver.name: interior` (the interior-point method, IPOPT as its fallback) and by IPOPT (`solver.name: ipopt`,
the reference and today's default) in the same run; the solve times (builds cached and not counted), the interior
attempt's own status, iterations and time, and Tr(Sigma_T) of both.
The 20 Hz loop (re-plans from the executed curve's state) is not measured yet: those re-plans do not converge
(docs/realtime.md); its fields in the last line read `na`. Writes benchmarks/results/realtime.md; the last line is
`realtime: cold_median_ms=... cold_worst_ms=... replan_median_ms=na replan_worst_ms=na infeasible=na
violations=na`.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

from dataclasses import replace  # noqa: E402



def cold(args) -> tuple[list[str], dict]:
    """Every cold problem by both solvers: table lines and the figures."""
    problems = [("default", h.load_problem(h.DEFAULT_PROBLEM))]
    base = problems[0][1]
    for c, p in h.configurations(h.sampler(), args.configs, args.seed, horizon=base.horizon):
        problems.append((str(c), replace(p, timing=base.timing, limits=base.limits)))
    rows, ours, ref, worse, failed, disagree, alone, own_ok = [], [], [], [], [], [], [], 0
    for name, prob in problems:
        setup = h.setup(h.with_solver(prob, name="interior"))
        h.ocp(setup)  # builds (and compiles) outside the timed solves
        sol = h.ocp(setup)
        ipopt = h.ocp(h.with_solver(setup, name="ipopt"))
        own = sol.attempts[0]
        alone.append(own.solve_time_s * 1e3)
        own_ok += own.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        ours.append(sol.solve_time_s * 1e3)
        ref.append(ipopt.solve_time_s * 1e3)
        rel = sol.trace_final / ipopt.trace_final - 1 if ipopt.success and sol.success else float("nan")
        if sol.success and ipopt.success and rel > 1e-6:
            worse.append((name, rel))
        if not sol.success:
            failed.append((name, sol.status, ipopt.status))
            if ipopt.success:
                disagree.append(name)
        rows.append((name, sol.status, f"{ours[-1]:.1f}", own.status, own.iterations, f"{alone[-1]:.1f}",
                     ipopt.status, f"{ref[-1]:.1f}", f"{rel:.1e}"))
        print(name, sol.status, f"{ours[-1]:.1f} ms", ipopt.status, f"{ref[-1]:.1f} ms", f"rel {rel:.1e}", flush=True)
    so, sr, sa = h.stats(ours), h.stats(ref), h.stats(alone)
    lines = ["## Cold, within the limits (T = 40, 50 ms steps)", "",
             f"{len(problems)} problems: the default and {args.configs} evaluation configurations (seed {args.seed}).",
             f"solver.name: interior (IPOPT its fallback): median {so.median:.1f} ms, p90 {so.p90:.1f} ms, worst {so.worst:.1f} ms; IPOPT in the "
             f"same run: median {sr.median:.1f} ms, worst {sr.worst:.1f} ms (IPOPT / ours, medians: "
             f"{sr.median / so.median:.1f}x). Not solved: {len(failed)} ({', '.join(f'{n}: {s} (IPOPT {i})' for n, s, i in failed) or 'none'}); "
             f"of those, solved by IPOPT: {len(disagree)}. Tr(Sigma_T) more than 1e-6 above IPOPT's: {len(worse)} "
             f"({', '.join(f'{n}: {r:.1e}' for n, r in worse) or 'none'}). The interior-point attempt alone: "
             f"converged on {own_ok} of {len(problems)}, median {sa.median:.1f} ms, worst {sa.worst:.1f} ms.", "",
             *h.table(["problem", "status", "ms (with fallback)", "interior attempt", "its iterations", "its ms",
                       "IPOPT status", "IPOPT ms", "Tr / IPOPT's - 1"], rows), ""]
    return lines, {"cold_median_ms": so.median, "cold_worst_ms": so.worst, "cold_failed": len(failed),
                   "cold_disagree": len(disagree), "cold_worse": len(worse)}


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0)
    args = ap.parse_args()
    lines = ["# Plans within the motion limits at tracker rate", "",
             f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py --configs {args.configs} --seed "
             f"{args.seed}` (one BLAS thread; builds cached, not counted).", ""]
    block, figs = cold(args)
    lines += block
    lines += ["## The 20 Hz loop within the limits", "",
              "Not measured: re-plans from the executed curve's state do not converge yet (docs/realtime.md).", ""]
    last = h.last_line("realtime", h.key_values(
        cold_median_ms=f"{figs['cold_median_ms']:.1f}", cold_worst_ms=f"{figs['cold_worst_ms']:.1f}",
        replan_median_ms="na", replan_worst_ms="na", infeasible="na", violations="na"))
    text = "\n".join(lines + [last]) + "\n"
    h.write_result("realtime.md", text)
    print(text)


if __name__ == "__main__":
    main()
