"""The projected Newton solver (`solver.name: newton`) against IPOPT (the default) on the evaluation's configurations.

    .venv/bin/python benchmarks/newton_vs_ipopt.py [--configs 100] [--seed 0]

Per configuration of problems/evaluations/evaluation.yaml (T = 20): both solvers from the same initial guess; prints how
often they reach the same plan (Tr(Sigma_T) within 1e-6 relative), a lower or a higher one, how often
Newton needed the IPOPT fallback, and the median times. Writes benchmarks/results/newton_vs_ipopt.md.
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace
from pathlib import Path

from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.solvers.ocp import solve_ocp
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.output.solution import write_text_atomic

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations" / "evaluation.yaml"))
    same = lower = higher = fallback = failed = 0
    t_ipopt, t_newton, rows = [], [], []
    for c in range(args.configs):
        setup = build_setup(sampler.problem(sampler.sample(args.seed, c)))
        init = ocp_initial_guess(setup)
        ipopt = solve_ocp(setup, init)
        newton = solve_ocp(replace(setup, problem=replace(setup.problem, solver=replace(setup.problem.solver,
                                                                                        name="newton"))), init)
        ratio = newton.trace_final / ipopt.trace_final
        same += abs(ratio - 1) <= 1e-6
        lower += ratio < 1 - 1e-6
        higher += ratio > 1 + 1e-6
        fallback += newton.extras["attempts"][0]["kept"] is False
        failed += not newton.success
        t_ipopt.append(ipopt.solve_time_s)
        t_newton.append(newton.solve_time_s)
        rows.append(f"| {c} | {ipopt.trace_final:.6e} | {newton.trace_final:.6e} | {ratio:.6f} | {ipopt.solve_time_s:.4f} "
                    f"| {newton.solve_time_s:.4f} | {newton.extras['hessian']} | {newton.status} |")
        print(rows[-1], flush=True)
    n = args.configs
    summary = (f"{n} configurations (seed {args.seed}, T = 20): same plan (Tr within 1e-6) {same}, Newton lower {lower}, "
               f"Newton higher {higher}; Newton fell back to IPOPT on {fallback}, failed {failed}. Median solve time: "
               f"IPOPT {statistics.median(t_ipopt) * 1e3:.1f} ms, Newton {statistics.median(t_newton) * 1e3:.1f} ms.")
    text = "\n".join(["# Newton against IPOPT", "", f"`.venv/bin/python benchmarks/newton_vs_ipopt.py --configs {n} "
                      f"--seed {args.seed}`", "", summary, "",
                      "| config | IPOPT Tr | Newton Tr | Newton / IPOPT | IPOPT time [s] | Newton time [s] | Newton attempts "
                      "| Newton status |", "|---|---|---|---|---|---|---|---|", *rows]) + "\n"
    write_text_atomic(ROOT / "benchmarks" / "results" / "newton_vs_ipopt.md", text)
    print(summary)


if __name__ == "__main__":
    main()
