"""The played curve's limit rows against the finite-difference rows (limits.CURVE_ROWS "curve" /
"steps").

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/curve_rows.py [--configs 24] [--horizon 40]
        [--step-s 0.05]

The default problem (needle_regrasp.yaml at the given horizon and pace, `--repeats` solves per mode,
median time) and the first `--configs` evaluation configurations
(problems/evaluations/evaluation.yaml, seed 0, at the same horizon and pace), each solved by the OCP
(`ocp`, the CLI's method) with `limits.enforce: true` under both kinds of rows, then exported by
`surestep export`'s time parametrisation (`time_parametrise`, timing auto: the planned curve when it
is within every limit, else toppra). Reported per plan: status, Tr(Sigma_T), the solver's own time
(`solve_time_s`, builds excluded), the export's timing and duration. Writes
benchmarks/results/curve_rows.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import platform  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

MODES = ("steps", "curve")


def solve(prob, mode: str, repeats: int = 1):
    h.set_curve_rows(mode)
    setup = h.setup(prob)
    sols = h.repeat(lambda: h.method(setup, "ocp"), max(1, repeats))
    sol = sols[-1]
    row = {"status": sol.status, "ok": sol.success, "trace": sol.trace_final,
           "solve_s": h.median(s.solve_time_s for s in sols)}
    if sol.success:
        q, _ = h.within_position_limits(np.array(sol.q, float), setup.robot)
        traj = h.time_parametrise(q, prob.timing.step_s, h.problem_limits(setup), robot=setup.robot,
                                  tool_frame=setup.robot.frame)
        row.update(timing=traj.timing, export_s=traj.duration)
    return row


def main() -> None:
    ap = h.parser(__doc__, configs=24, output=h.RESULTS / "curve_rows.md")
    ap.add_argument("--horizon", type=int, default=40)
    ap.add_argument("--step-s", type=float, default=0.05)
    ap.add_argument("--repeats", type=int, default=5,
                    help="solves of the default problem per mode (median time)")
    args = ap.parse_args()
    t0 = time.perf_counter()

    def enforced(p):
        return replace(p, horizon=args.horizon, limits=replace(p.limits, enforce=True),
                       timing=replace(p.timing, step_s=args.step_s))

    base = enforced(h.load_problem(h.PAPER_PACE_PROBLEM))
    cases = [("default", base, args.repeats)] + [
        (f"config {i}", enforced(p), 1) for i, p in h.configurations(h.sampler(), args.configs)]
    results = {m: [] for m in MODES}
    for mode in MODES:
        # not needed for correctness (the key holds CURVE_ROWS): frees the other mode's NLPs
        h.clear_solver_cache()
        for name, prob, reps in cases:
            results[mode].append(solve(prob, mode, reps))
            r = results[mode][-1]
            print(f"{mode:6s} {name:10s} {r['status']:28s} Tr {r['trace']:.4e} solve "
                  f"{r['solve_s']:.3f} s export {r.get('timing', '-')} "
                  f"{r.get('export_s', float('nan')):.3f} s",
                  flush=True)
    planned = args.horizon * args.step_s
    lines = [(f"# Limit rows on the played curve against finite differences (T = {args.horizon}, "
              f"{args.step_s:g} s per step, planned {planned:g} s)"), "",
             ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/curve_rows.py --configs "
              f"{args.configs} --horizon {args.horizon} --step-s {args.step_s:g} --repeats "
              f"{args.repeats}` ({time.perf_counter() - t0:.0f} s; {platform.node()}, 2 cores "
              "shared with other agents' jobs: times are noisy). The default problem's solve time "
              f"is the median of {args.repeats} solves; the configurations' one solve each (the "
              "first solve of each mode, the default problem's, builds and compiles the NLP; "
              "`solve` excludes builds)."), "",
             *h.table(["plan", "steps: status", "Tr", "solve [s]", "export [s] (timing)",
                       "curve: status", "Tr", "solve [s]", "export [s] (timing)",
                       "Tr curve / steps", "solve curve / steps"])]
    ratios, tratios = [], []
    for k, (name, _, _) in enumerate(cases):
        a, b = results["steps"][k], results["curve"][k]
        rt = b["trace"] / a["trace"] if a["ok"] and b["ok"] else None
        rs = b["solve_s"] / a["solve_s"] if a["ok"] and b["ok"] else None
        if rt is not None and name != "default":
            ratios.append(rt)
            tratios.append(rs)
        cell = lambda r: (f"{r['status']} | {r['trace']:.4e} | {r['solve_s']:.3f} | "
                          + (f"{r['export_s']:.3f} ({r['timing']})" if r["ok"] else "-"))
        lines.append(f"| {name} | {cell(a)} | {cell(b)} | {'-' if rt is None else f'{rt:.3f}'} | "
                     f"{'-' if rs is None else f'{rs:.2f}'} |")
    lines.append("")
    for mode in MODES:
        rs = results[mode][1:]
        ok = [r for r in rs if r["ok"]]
        sol_t = [r["solve_s"] for r in rs]
        played = sum(r.get("timing") == "planned" for r in ok)
        exp = [r["export_s"] for r in ok]
        lines.append(f"- {mode}: {len(ok)}/{len(rs)} configurations within the limits; solve "
                     f"median {h.median(sol_t):.3f} s, worst {max(sol_t):.3f} s; exported at the "
                     f"planned pace {played}/{len(ok)}; export duration median "
                     f"{h.median(exp):.3f} s, worst {max(exp) if exp else float('nan'):.3f} s "
                     f"(planned {planned:g} s)")
    if ratios:
        lines.append(f"- both converged on {len(ratios)}: Tr curve / steps median "
                     f"{h.median(ratios):.3f}, worst {max(ratios):.3f}, geometric mean "
                     f"{h.geomean(ratios):.3f}; solve time curve / steps median "
                     f"{h.median(tratios):.2f}, worst {max(tratios):.2f}")
    h.write_result(args.output, "\n".join(lines) + "\n")
    print("\n".join(lines[-3:]))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
