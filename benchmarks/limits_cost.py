"""What enforcing the motion limits costs the OCP, on the evaluation's configurations.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/limits_cost.py [--configs 100] [--seed 0]
        [--steps 0.05 0.1 0.2]

Per configuration of problems/evaluations/evaluation.yaml (T = 20) and per step time `timing.step_s`
(with `tracker_hz = 1 / step_s`: one observation per waypoint, the paper's belief model whatever the
pace, so only the limits change with the step): the OCP (the default strategy) with
`limits.enforce: false` and `true` from the same initial guess, and the straight-line baseline; the
share that converged (enforced: a success, so every limit met, `limits.py`), Tr(Sigma_T) of the
enforced plan over the unconstrained OCP's and over the baseline's (on the converged ones), the
median and worst solve times, and how often Newton's plan already met the limits (no IPOPT needed).
Writes benchmarks/results/limits_cost.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import time  # noqa: E402
from dataclasses import replace  # noqa: E402

geomean = h.geomean


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0)
    ap.add_argument("--steps", type=float, nargs="+", default=[0.05, 0.1, 0.2])
    args = ap.parse_args()
    sampler = h.sampler()
    summaries, detail = [], []
    t_start = time.perf_counter()
    for step in args.steps:
        n_ok = n_free_ok = n_newton = n_base_ok = 0
        vs_free, vs_base, t_free, t_lim, fail_status = [], [], [], [], {}
        for c, problem in h.configurations(sampler, args.configs, args.seed):
            prob = replace(problem, timing=h.timing_spec(step))
            free_setup = h.setup(replace(prob, limits=h.limits_spec(False)))
            lim_setup = h.setup(replace(prob, limits=h.limits_spec(True)))
            init = h.initial_guess(free_setup)
            free = h.ocp(free_setup, init)
            lim = h.ocp(lim_setup, init)
            base = h.method(free_setup, "baseline")
            base_ok = h.plan_report(free_setup.robot, base.q, step, h.problem_limits(free_setup),
                                    free_setup.robot.frame).ok
            n_base_ok += base_ok
            n_free_ok += free.success
            t_free.append(free.solve_time_s)
            t_lim.append(lim.solve_time_s)
            att = lim.attempts
            n_newton += bool(att) and att[0].solver == "newton" and att[0].kept
            if lim.success:
                n_ok += 1
                if free.success:
                    vs_free.append(lim.trace_final / free.trace_final)
                vs_base.append(lim.trace_final / base.trace_final)
            else:
                key = lim.status if lim.status != "Motion_Limits_Violated" else \
                    f"Motion_Limits_Violated ({lim.run.solver_status})"
                fail_status[key] = fail_status.get(key, 0) + 1
            detail.append(f"| {step:g} | {c} | {free.trace_final:.4e} | {lim.trace_final:.4e} | "
                          f"{base.trace_final:.4e} | {'yes' if base_ok else 'no'} | "
                          f"{free.solve_time_s:.3f} | {lim.solve_time_s:.3f} | {lim.status} | "
                          f"{lim.run.hessian or ''} |")
            print(detail[-1], flush=True)
        n = args.configs
        fails = ", ".join(f"{k}: {v}" for k, v in sorted(fail_status.items())) or "-"
        summaries.append(
            f"| {step:g} | {n_free_ok}/{n} | {n_ok}/{n} | {geomean(vs_free):.2f} "
            f"({min(vs_free, default=float('nan')):.2f}-{max(vs_free, default=float('nan')):.2f}) "
            f"| {geomean(vs_base):.2f} ({min(vs_base, default=float('nan')):.2f}-"
            f"{max(vs_base, default=float('nan')):.2f}) | {n_base_ok}/{n} "
            f"| {h.median(t_free) * 1e3:.0f} / {max(t_free) * 1e3:.0f} "
            f"| {h.median(t_lim) * 1e3:.0f} / {max(t_lim) * 1e3:.0f} | {n_newton} | {fails} |")
        print(summaries[-1], flush=True)
    head = h.table(["step_s", "unconstrained converged", "enforced converged (all limits met)",
                    "enforced Tr / unconstrained Tr, geo. mean (range)",
                    "enforced Tr / baseline Tr, geo. mean (range)", "baseline within the limits",
                    "unconstrained solve, median / worst [ms]",
                    "enforced solve, median / worst [ms]", "enforced: Newton's plan already within",
                    "enforced failures"])
    text = "\n".join([
        "# What the motion limits cost the OCP", "",
        ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/limits_cost.py --configs "
         f"{args.configs} --seed {args.seed} --steps {' '.join(f'{s:g}' for s in args.steps)}` "
         f"({time.perf_counter() - t_start:.0f} s on this machine)"), "",
        ("Evaluation configurations (problems/evaluations/evaluation.yaml, T = 20), one "
         "observation per waypoint (the paper's belief model at every pace: tracker_hz = 1 / "
         "step_s); default limits (URDF velocities, the dVRK's move_jp accelerations, tool 0.1 m/s "
         "and pi/2 rad/s, 45 mm from the RCM), the plan at rest before and after. Ratios over the "
         "configurations where both converged; solve times exclude the one-off build and "
         "compile of each NLP."), "", *head, *summaries, "",
        "## Per configuration", "",
        *h.table(["step_s", "config", "unconstrained Tr", "enforced Tr", "baseline Tr",
                  "baseline within", "unconstrained [s]", "enforced [s]", "enforced status",
                  "enforced attempts"], detail)]) + "\n"
    h.write_result("limits_cost.md", text)
    print("\n".join(head + summaries))


if __name__ == "__main__":
    main()
