"""The OCP on belief models beyond the paper's constants, against the paper's model in the same run.

    .venv/bin/python benchmarks/general_models.py [--configs 100] [--seed 0]
        [--horizons 20 40 80 160] [--scaling-configs 10]

Per configuration of problems/evaluations/evaluation.yaml (T = 20), each model solved with the
problem's settings (solver.name auto) from the straight line's IK:

- `paper` (reference): the paper's constants, condensed form (the default);
- `paper, lifted`: the same, `solver.covariance: full` (vech(Sigma_t) multiple shooting, IPOPT);
- `full V_d0`: a full 6x6 SPD depth base covariance (random, fixed seed, correlations up to 0.6);
- `correlated V_d0`: the stereo-like depth noise (V_d0[0, 2] = 2e-2 on diag(1e-2, 1e-2, 1e-1, 5e-3
  ...));
- `... + floor`: with the observation noise floor V_min = diag(1e-6, 1e-6, 4e-6, 1e-5, 1e-5, 1e-5);
- `joint-space`: the paper's constants plus the joint-space motion noise `J diag(sigma^2 dq^2) J^T`
  (`noise.joint_motion_sigma`, sigma = 0.05 per joint, 0.02 for the insertion), with and without the
  floor.

`--models NAME ...` runs a subset (`paper` is always run: the reference).

Per row: converged share, median / 95th percentile / worst solve time (set-up included, builds not),
the ratio of medians against `paper`, and `worse`: the share of configurations whose optimum is
worse (Tr above 1e-6 relative) than the paper plan, and than the diagonal approximation's plan
(every base covariance replaced by its diagonal: the fast scalar path), each evaluated in that
model; the last line's `worse_optima` is the latter. Then the solve time of `correlated V_d0`
against T (the first `--scaling-configs` configurations). BLAS is pinned to one thread. Writes
benchmarks/results/general_models.md; the last line is `general: success=<share> median_ms=<ms>
p95_ms=<ms> ratio_vs_condensed=<x> worse_optima=<share>` over the non-paper models.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402
FLOOR = np.diag([1e-6, 1e-6, 4e-6, 1e-5, 1e-5, 1e-5])
# yaw, pitch, insertion, roll, wrist pitch, wrist yaw, jaw
JOINT_SIGMA = (0.05, 0.05, 0.02, 0.05, 0.05, 0.05, 0.0)


def full_depth() -> np.ndarray:
    A = np.random.default_rng(7).normal(size=(6, 6))
    M = A @ A.T + 3 * np.eye(6)
    d = 1 / np.sqrt(np.diag(M))
    return np.diag(np.sqrt([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])) @ (M * np.outer(d, d)) @ np.diag(
        np.sqrt([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3]))


def correlated_depth() -> np.ndarray:
    V = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
    V[0, 2] = V[2, 0] = 2e-2
    return V


MODELS = {
    "paper": ({}, "auto"),
    "paper, lifted": ({}, "full"),
    "paper + floor": ({"V_min": FLOOR}, "auto"),
    "full V_d0": ({"V_d0": full_depth()}, "auto"),
    "correlated V_d0": ({"V_d0": correlated_depth()}, "auto"),
    "correlated V_d0 + floor": ({"V_d0": correlated_depth(), "V_min": FLOOR}, "auto"),
    "correlated V_d0, lifted": ({"V_d0": correlated_depth()}, "full"),
    "joint-space": ({"joint_sigma": JOINT_SIGMA}, "auto"),
    "joint-space + floor": ({"joint_sigma": JOINT_SIGMA, "V_min": FLOOR}, "auto"),
}


def variant(problem, noise: dict, form: str, horizon: int | None = None):
    p = replace(problem, noise=replace(problem.noise, **noise),
                solver=replace(problem.solver, covariance=form))
    return replace(p, horizon=horizon) if horizon else p


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0, horizons=[20, 40, 80, 160], horizons_nargs="*",
                  output=h.RESULTS / "general_models.md")
    ap.add_argument("--scaling-configs", type=int, default=10)
    ap.add_argument("--models", nargs="*", choices=list(MODELS), default=list(MODELS))
    ap.add_argument("--scaling-model", choices=list(MODELS), default="correlated V_d0")
    args = ap.parse_args()
    models = {k: v for k, v in MODELS.items() if k == "paper" or k in args.models}
    sampler = h.sampler()
    res = {name: {"ok": [], "t": [], "tr": [], "worse": [], "worse_diag": [], "kept": [],
                  "form": set()}
           for name in models}
    for c, base in h.configurations(sampler, args.configs, args.seed):
        paper_poses = paper_q = None
        line = [f"{c:3d}"]
        for name, (noise, form) in models.items():
            setup = h.setup(variant(base, noise, form))
            sol = h.ocp(setup)
            r = res[name]
            r["ok"].append(sol.success)
            r["t"].append(sol.solve_time_s)
            r["tr"].append(sol.trace_final)
            r["kept"].append(sol.status == "Initial_Guess_Kept")
            r["form"].add(f"{sol.run.covariance_form} / "
                          f"{sol.run.hessian}".split(" + ")[0])
            if name == "paper":
                paper_poses, paper_q = np.array(sol.poses), np.array(sol.q)
            ref = float(np.trace(setup.eval_model.propagate(paper_poses,
                                                            joint=setup.joint_noises(paper_q))[0][-1]))
            r["worse"].append(sol.trace_final > ref * (1 + 1e-6))
            # its own diagonal approximation: the same solve
            if setup.model.scalar and form == "auto":
                r["worse_diag"].append(False)
            else:
                # the diagonal approximation's condensed plan (the fast scalar path) evaluated in
                # this model
                dplan = h.ocp(h.diagonal_model(h.setup(variant(base, noise, "auto"))))
                dref = float(np.trace(setup.eval_model.propagate(
                    np.array(dplan.poses), joint=setup.joint_noises(np.array(dplan.q)))[0][-1]))
                r["worse_diag"].append(sol.trace_final > dref * (1 + 1e-6))
            line.append(f"{name}: {sol.status} {sol.iterations} it {sol.solve_time_s * 1e3:.1f} ms "
                        f"Tr/paper-plan {sol.trace_final / ref:.4f}")
        print(" | ".join(line), flush=True)

    n = args.configs
    t_paper = h.median(res["paper"]["t"])
    rows = []
    for name, r in res.items():
        t = h.stats(np.array(r["t"]) * 1e3)
        rows.append(f"| {name} | {sum(r['ok'])}/{n} | {sum(r['kept'])} | {t.median:.1f} | "
                    f"{t.p95:.1f} | {t.worst:.1f} | {t.median / (t_paper * 1e3):.2f} | "
                    f"{sum(r['worse'])}/{n} | {sum(r['worse_diag'])}/{n} | "
                    f"{'; '.join(sorted(r['form']))} |")
    scaling = []
    for T in args.horizons:
        times, ok = [], 0
        for c, problem in h.configurations(sampler, args.scaling_configs, args.seed):
            sol = h.ocp(h.setup(variant(problem, MODELS[args.scaling_model][0], "auto", T)))
            times.append(sol.solve_time_s)
            ok += sol.success
        scaling.append((T, h.median(times), max(times), ok))
        print(f"T={T}: median {scaling[-1][1] * 1e3:.1f} ms, worst {scaling[-1][2] * 1e3:.1f} ms, "
              f"{ok}/{args.scaling_configs} converged", flush=True)

    general = [name for name in models if not name.startswith("paper")]
    t_gen = h.stats(np.concatenate([np.array(res[k]["t"]) for k in general]) * 1e3)
    ok_gen = np.mean(np.concatenate([res[k]["ok"] for k in general]))
    worse_gen = np.mean(np.concatenate([res[k]["worse_diag"] for k in general]))
    last = h.last_line("general", h.key_values(
        success=f"{ok_gen:.2f}", median_ms=f"{t_gen.median:.1f}", p95_ms=f"{t_gen.p95:.1f}",
        ratio_vs_condensed=f"{t_gen.median / (t_paper * 1e3):.2f}",
        worse_optima=f"{worse_gen:.2f}"))
    text = "\n".join([
        "# The OCP on general belief models", "",
        f"`.venv/bin/python benchmarks/general_models.py --configs {n} --seed {args.seed} "
        f"--horizons {' '.join(map(str, args.horizons))} --scaling-configs {args.scaling_configs}"
        + ("" if len(models) == len(MODELS)
           else f" --models {' '.join(repr(k) for k in models if k != 'paper')}")
        + f" --scaling-model '{args.scaling_model}'"
        + "` (OPENBLAS_NUM_THREADS=1)", "",
        (f"{n} configurations of problems/evaluations/evaluation.yaml at T = 20; times include the "
         "set-up of each solve, not the builds (compiled once per structure and cached)."), "",
        *h.table(["model", "converged", "kept start", "median [ms]", "p95 [ms]", "worst [ms]",
                  "median / paper", "worse than the paper plan",
                  "worse than the diagonal model's plan", "form / first solver"], rows), "",
        f"Solve time against T (`{args.scaling_model}`, default solver):", "",
        *h.table(["T", "median [ms]", "worst [ms]", "converged"],
                 [(T, f"{m * 1e3:.1f}", f"{w * 1e3:.1f}", f"{ok}/{args.scaling_configs}")
                  for T, m, w, ok in scaling]), "",
        last]) + "\n"
    h.write_result(args.output, text)
    print(text)


if __name__ == "__main__":
    main()
