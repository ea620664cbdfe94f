"""The projected Newton solver (`solver.name: newton`) against IPOPT (the default) on the
evaluation's configurations.

    .venv/bin/python benchmarks/newton_vs_ipopt.py [--configs 100] [--seed 0]

Per configuration of problems/evaluations/evaluation.yaml (T = 20): both solvers from the same
initial guess; prints how often they reach the same plan (Tr(Sigma_T) within 1e-6 relative), a lower
or a higher one, how often Newton needed the IPOPT fallback, and the median times. Writes
benchmarks/results/newton_vs_ipopt.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread


def main() -> None:
    args = h.parser(__doc__, configs=100, seed=0).parse_args()
    sampler = h.sampler()
    same = lower = higher = fallback = failed = 0
    t_ipopt, t_newton, rows = [], [], []
    for c, problem in h.configurations(sampler, args.configs, args.seed):
        setup = h.setup(problem)
        init = h.initial_guess(setup)
        ipopt = h.ocp(setup, init)
        newton = h.ocp(h.with_solver(setup, name="newton"), init)
        ratio = newton.trace_final / ipopt.trace_final
        same += abs(ratio - 1) <= 1e-6
        lower += ratio < 1 - 1e-6
        higher += ratio > 1 + 1e-6
        fallback += newton.attempts[0].kept is False
        failed += not newton.success
        t_ipopt.append(ipopt.solve_time_s)
        t_newton.append(newton.solve_time_s)
        rows.append(f"| {c} | {ipopt.trace_final:.6e} | {newton.trace_final:.6e} | {ratio:.6f} | "
                    f"{ipopt.solve_time_s:.4f} | {newton.solve_time_s:.4f} | "
                    f"{newton.run.hessian} | {newton.status} |")
        print(rows[-1], flush=True)
    n = args.configs
    summary = (f"{n} configurations (seed {args.seed}, T = 20): same plan (Tr within 1e-6) {same}, "
               f"Newton lower {lower}, Newton higher {higher}; Newton fell back to IPOPT on "
               f"{fallback}, failed {failed}. Median solve time: IPOPT "
               f"{h.median(t_ipopt) * 1e3:.1f} ms, Newton {h.median(t_newton) * 1e3:.1f} ms.")
    text = "\n".join(["# Newton against IPOPT", "",
                      f"`.venv/bin/python benchmarks/newton_vs_ipopt.py --configs {n} "
                      f"--seed {args.seed}`", "", summary, "",
                      *h.table(["config", "IPOPT Tr", "Newton Tr", "Newton / IPOPT",
                                "IPOPT time [s]", "Newton time [s]", "Newton attempts",
                                "Newton status"], rows)]) + "\n"
    h.write_result("newton_vs_ipopt.md", text)
    print(summary)


if __name__ == "__main__":
    main()
