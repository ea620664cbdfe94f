"""Solve speed of the OCP against the paper's gradient variant, measured in the same run.

For N random configurations of problems/evaluations/evaluation.yaml at T in {10, 20, 40}: wall
time, iterations and Tr(Sigma_T) of the OCP (`solve_ocp`: IPOPT with the problem's
settings, i.e. the surrogate Hessian with the exact-Hessian polish; the OCP time
includes the IK of its initial guess and the set-up of each IPOPT call) and of the
gradient variant (L-BFGS, 50 iterations, pose loss). Also the warm re-solve: the camera moves by
3 mm and 2 degrees, and the T = 20 OCP is re-solved from the previous solution's primal and dual
values.

Build times (CasADi expression graphs and IPOPT set-up, paid once per structure and
horizon and cached) are reported separately and are not in the solve times.

    .venv/bin/python benchmarks/solve_speed.py [--instances 20] [--horizons 10 20 40]
        [--codegen | --no-codegen] [--tol 1e-6] [--hessian auto|exact|surrogate|gauss-newton]
        [--solver ipopt|newton] [--limits [--step-s S]]

`--limits`: the OCP with `limits.enforce: true` (the default limits,
docs/motion_limits_and_export.md, "Motion limits"), at `--step-s` seconds per step (default 0.05)
with one observation per waypoint (`tracker_hz = 1 / step_s`, the paper's belief model at any
pace); the gradient variant does not honour limits (its plan is only
checked, and fails them). Writes solve_speed_limits*.md.

By default the problem's `solver.codegen` (auto: the OCP's derivatives are compiled to C
when a C compiler is found; the compile is a build cost, reported with the builds);
`--codegen` / `--no-codegen` force it. The gradient variant's time is its L-BFGS run; its
waypoints' IK (to get joints, which the OCP returns) is reported beside it, not added to
the ratio. Writes benchmarks/results/solve_speed.md (solve_speed_codegen.md,
solve_speed_interpreted.md with the flags); the last printed line is
`T=20 time_ratio=... trace_share=... warm_ms=... growth_40_20=...`.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import argparse  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402


def camera_nudge(setup, rng):
    """The same setup seen from a camera moved by 3 mm and 2 degrees."""
    D = np.eye(4)
    axis = rng.normal(size=3)
    D[:3, :3] = h.np_exp(np.deg2rad(2.0) * axis / np.linalg.norm(axis))
    d = rng.normal(size=3)
    D[:3, 3] = 0.003 * d / np.linalg.norm(d)
    return setup.seen_from(setup.camera_pose @ D)


def run(instances: int, horizons: list[int], seed: int, codegen: bool | None = None,
        tol: float | None = None, hessian: str | None = None, solver_name: str | None = None,
        step_s: float | None = None) -> tuple[str, str]:
    """`step_s` given: the limits enforced at that pace (module docstring)."""
    spec = h.evaluation()
    solver = replace(spec.base.solver, codegen=spec.base.solver.codegen if codegen is None
                     else codegen, tol=spec.base.solver.tol if tol is None else tol,
                     hessian=hessian or spec.base.solver.hessian,
                     name=solver_name or spec.base.solver.name)
    spec = replace(spec, base=replace(spec.base, solver=solver))
    if step_s is not None:
        spec = replace(spec, base=replace(spec.base, limits=h.limits_spec(True),
                                          timing=h.timing_spec(step_s)))
    rows, summary = [], {}
    warm_ms, builds, cold_resolves = [], {}, 0
    rng = np.random.default_rng(seed)
    for T in horizons:
        spec_T = replace(spec, base=replace(spec.base, horizon=T), horizon=T)
        sampler = h.sampler(spec_T)
        ratios, wins, t_ocp, t_grad, fails, alone, iters, t_grad_ik = [], 0, [], [], 0, 0, [], []
        t_free, tr_vs_free = [], []
        for i, problem in h.configurations(sampler, instances, seed):
            setup = h.setup(problem)
            init, init_s = h.timed(lambda: h.initial_guess(setup))
            ocp, warm = h.ocp_warm(setup, init)
            if step_s is not None:  # the unconstrained OCP beside it, same start and pace
                free = h.ocp(h.setup(replace(problem, limits=h.limits_spec(False))), init)
                t_free.append(free.solve_time_s + init_s)
                if ocp.success and free.success:
                    tr_vs_free.append(ocp.trace_final / free.trace_final)
            grad = h.gradient(setup, pose_loss=True)
            # the IK of the initial guess is part of the OCP's work
            ocp_time = ocp.solve_time_s + init_s
            ratios.append(ocp_time / grad.solve_time_s)
            wins += ocp.trace_final <= grad.trace_final
            fails += not ocp.success
            alone += ocp.run.hessian == ocp.attempts[0].label != "exact"
            t_ocp.append(ocp_time)
            t_grad.append(grad.solve_time_s)
            t_grad_ik.append(grad.solve_time_s + grad.extras["ik_time_s"])
            iters.append(ocp.iterations)
            rows.append((T, i, ocp_time, ocp.iterations, ocp.status, ocp.run.hessian,
                         ocp.trace_final, ocp.run.constraint_violation, grad.solve_time_s,
                         grad.iterations, grad.trace_final))
            if T == 20:
                moved = camera_nudge(setup, rng)
                again, _ = h.ocp_warm(moved, init, warm=warm)  # warm None (a kept start): cold
                cold_resolves += warm is None
                warm_ms.append(again.solve_time_s * 1e3)
            print(f"T={T} #{i}: ocp {ocp_time:.3f} s ({ocp.iterations} it, {ocp.status}, "
                  f"{ocp.run.hessian}) tr {ocp.trace_final:.3e} | gradient "
                  f"{grad.solve_time_s:.3f} s tr {grad.trace_final:.3e}",
                  flush=True)
        builds[T] = sum(tr.build_time_s for tr in h.transcriptions(T))
        summary[T] = {"time_ratio": h.median(ratios), "trace_share": wins / instances,
                      "ocp_median_s": h.median(t_ocp), "grad_median_s": h.median(t_grad),
                      "failures": fails, "alone": alone / instances, "iters": h.median(iters),
                      "grad_ik_median_s": h.median(t_grad_ik),
                      "compiled": any(tr.codegen for tr in h.transcriptions(T)),
                      "free_median_s": h.median(t_free), "tr_vs_free": h.geomean(tr_vs_free),
                      "n_vs_free": len(tr_vs_free)}
    growth = ((summary[40]["ocp_median_s"] / summary[20]["ocp_median_s"])
              if {20, 40} <= set(summary) else float("nan"))
    warm = h.median(warm_ms)
    lines = ["# Solve speed: OCP against the gradient variant (same run)", "",
             (f"`.venv/bin/python benchmarks/solve_speed.py --instances {instances} --horizons "
              f"{' '.join(map(str, horizons))}"
              f"{ {None: '', True: ' --codegen', False: ' --no-codegen'}[codegen]}"
              f"{f' --tol {tol:g}' if tol is not None else ''}"
              f"{f' --hessian {hessian}' if hessian else ''}"
              f"{f' --solver {solver_name}' if solver_name else ''}"
              f"{f' --limits --step-s {step_s:g}' if step_s is not None else ''}`"), "",
             *([] if step_s is None else [
                 ("Limits enforced (`limits.enforce: true`, default limits) at step_s "
                  f"{step_s:g} s with one observation per waypoint; a failure is a plan that does "
                  "not meet them (mostly Infeasible_Problem_Detected). The gradient variant does "
                  "not honour them. Machine shared with other jobs (2 cores)."), ""]),
             *h.table(["T", "median time OCP / gradient", "share OCP Tr <= gradient Tr",
                       "median OCP time [s]", "median gradient time [s]",
                       "median gradient + IK of its waypoints [s]", "median OCP iterations",
                       "OCP failures", "share solved by the first Hessian alone", "OCP compiled",
                       "OCP builds (once) [s]"],
                      [(T, f"{s['time_ratio']:.2f}", f"{s['trace_share']:.2f}",
                        f"{s['ocp_median_s']:.3f}", f"{s['grad_median_s']:.3f}",
                        f"{s['grad_ik_median_s']:.3f}", f"{s['iters']:g}", s["failures"],
                        f"{s['alone']:.2f}", "yes" if s["compiled"] else "no", f"{builds[T]:.1f}")
                       for T, s in summary.items()])]
    if step_s is not None:
        lines += ["",
                  "The unconstrained OCP in the same run (same configurations, start and pace):",
                  "",
                  *h.table(["T", "median OCP time, enforced [s]", "unconstrained [s]",
                            "enforced / unconstrained",
                            "Tr enforced / unconstrained, geo. mean (both converged)"],
                           [(T, f"{s['ocp_median_s']:.3f}", f"{s['free_median_s']:.3f}",
                             f"{s['ocp_median_s'] / s['free_median_s']:.1f}",
                             f"{s['tr_vs_free']:.2f} ({s['n_vs_free']})")
                            for T, s in summary.items()])]
    how = ("warm-started from the previous solution: IPOPT's primal-dual point or Newton's joints"
           + ("" if not cold_resolves
              else f"; cold on {cold_resolves} of {len(warm_ms)} instances, where the "
              "previous solve kept its start and has no warm-start point"))
    lines += ["",
              (f"Warm re-solve at T = 20 after a 3 mm / 2 deg camera move ({how}): "
               f"median {warm:.1f} ms."),
              f"Growth of the median OCP time from T = 20 to T = 40: {growth:.2f}x.", "",
              *h.table(["T", "instance", "OCP time [s]", "OCP iters", "OCP status",
                        "OCP Hessian(s)", "OCP Tr", "OCP max constraint violation",
                        "gradient time [s]", "gradient iters", "gradient Tr"],
                       [(r[0], r[1], f"{r[2]:.3f}", r[3], r[4], r[5], f"{r[6]:.3e}", f"{r[7]:.1e}",
                         f"{r[8]:.3f}", r[9], f"{r[10]:.3e}") for r in rows])]
    s20 = summary.get(20, {"time_ratio": float("nan"), "trace_share": float("nan")})
    last = h.key_values(T=20, time_ratio=f"{s20['time_ratio']:.2f}",
                        trace_share=f"{s20['trace_share']:.2f}", warm_ms=f"{warm:.1f}",
                        growth_40_20=f"{growth:.2f}")
    return "\n".join(lines) + "\n", last


def main() -> None:
    ap = h.parser(__doc__, configs=20, configs_flag="--instances", seed=0, horizons=[10, 20, 40])
    ap.add_argument("--codegen", action=argparse.BooleanOptionalAction, default=None,
                    help="compile the OCP's derivatives, or not (default: the problem's "
                         "solver.codegen, auto)")
    ap.add_argument("--tol", type=float,
                    help="IPOPT tolerance instead of the problem's solver.tol (1e-8)")
    ap.add_argument("--solver", choices=("auto", "ipopt", "newton"),
                    help="solver.name instead of the problem's (ipopt); newton: projected Newton, "
                         "IPOPT as fallback")
    ap.add_argument("--hessian", choices=("auto", "exact", "surrogate", "gauss-newton"),
                    help="solver.hessian instead of the problem's (auto)")
    ap.add_argument("--limits", action="store_true", help="the OCP with the motion limits enforced")
    ap.add_argument("--step-s", type=float, default=0.05,
                    help="seconds per step with --limits (default 0.05)")
    args = ap.parse_args()
    step = args.step_s if args.limits else None
    text, last = run(args.instances, args.horizons, args.seed, args.codegen, args.tol, args.hessian,
                     args.solver, step)
    name = ("solve_speed" + {None: "", True: "_codegen", False: "_interpreted"}[args.codegen]
            + (f"_tol{args.tol:g}" if args.tol else "")
            + (f"_{args.hessian}" if args.hessian else "")
            + (f"_{args.solver}" if args.solver else "")
            + (f"_limits_step{step:g}" if step is not None else "") + ".md")
    h.write_result(name, text)
    print(text)
    print(last)


if __name__ == "__main__":
    main()
