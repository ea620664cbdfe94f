"""The OCP's slowest configurations beside its median, on every configuration of the evaluation,
with the gradient variant's time measured in the same run.

    .venv/bin/python benchmarks/worst_case.py [--configs 100] [--seed 0] [--horizons 20 40]

Per horizon, each configuration of problems/evaluations/evaluation.yaml is solved with the default
strategy (`solve_ocp` from the straight line's IK; builds are cached and not counted) and by the
gradient variant. Reported:
median, 95th percentile and worst OCP time, worst / median, the five slowest configurations with the
attempts that ran, how many kept their start (and why), and the trace of every plan against the
straight line's. Each plan's trace is checked against tests/numpy_ekf.py (an independent NumPy EKF
on the stored poses). BLAS one thread. Writes benchmarks/results/worst_case.md; the last line is
`worst_case: T=<T> median_ms=<ms> worst_ms=<ms> worst_over_median=<x> kept=<n> ...` per horizon.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import sys  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(h.ROOT / "tests"))
import numpy_ekf  # noqa: E402


def ekf_trace(setup, poses) -> float:
    n = setup.ocp.noise
    return float(np.trace(numpy_ekf.propagate(np.asarray(poses), n, setup.ocp.intrinsics,
                                              guard=n.cosine_guard**2)[0][-1]))


def run(sampler, seed: int, configs: int, T: int) -> dict:
    rows = []
    for c, problem in h.configurations(sampler, configs, seed, horizon=T):
        setup = h.setup(problem)
        base = h.baseline(setup)
        sol = h.ocp(setup)
        grad = h.gradient(setup)
        attempts = "; ".join(f"{a.label}: {a.status} ({a.iterations} it)" for a in sol.attempts)
        rows.append({"c": c, "ms": sol.solve_time_s * 1e3, "grad_ms": grad.solve_time_s * 1e3,
                     "status": sol.status, "ratio": sol.trace_final / base.trace_final,
                     "attempts": attempts,
                     "ekf": abs(ekf_trace(setup, sol.poses) / sol.trace_final - 1)})
        print(f"T={T} {c:3d} {sol.status} {rows[-1]['ms']:.1f} ms (gradient "
              f"{rows[-1]['grad_ms']:.1f} ms) Tr/baseline {rows[-1]['ratio']:.3f} "
              f"| {attempts}", flush=True)
    return {"T": T, "rows": rows}


def summary(r: dict) -> tuple[list[str], str]:
    rows, T = r["rows"], r["T"]
    t, g = h.stats(x["ms"] for x in rows), h.stats(x["grad_ms"] for x in rows)
    med, worst, vs_grad = t.median, t.worst, h.ratio_of_medians([x["ms"] for x in rows],
                                                                [x["grad_ms"] for x in rows])
    kept = [x for x in rows if x["status"] == "Initial_Guess_Kept"]
    failed = [x for x in rows if x["status"] not in ("Solve_Succeeded", "Initial_Guess_Kept")]
    slow = sorted(rows, key=lambda x: -x["ms"])[:5]
    lines = [f"## T = {T}", "",
             (f"OCP: median {med:.1f} ms, p95 {t.p95:.1f} ms, worst {worst:.1f} ms (worst / median "
              f"{t.worst_over_median:.1f}); gradient variant median {g.median:.1f} ms, worst "
              f"{g.worst:.1f} ms (OCP / gradient, medians: {vs_grad:.2f}). Tr(Sigma_T) / straight "
              f"line: median {h.median(x['ratio'] for x in rows):.3f}, worst "
              f"{max(x['ratio'] for x in rows):.3f}. Kept their start: {len(kept)}; failed: "
              f"{len(failed)}; largest relative difference from the NumPy EKF's trace: "
              f"{max(x['ekf'] for x in rows):.1e}."), "",
             *h.table(["slowest", "time [ms]", "status", "attempts"],
                      [(x["c"], f"{x['ms']:.1f}", x["status"], x["attempts"]) for x in slow]), ""]
    if kept or failed:
        lines += ["Kept or failed: " + "; ".join(f"{x['c']}: {x['status']} ({x['attempts']})"
                                                 for x in kept + failed), ""]
    last = h.key_values(T=T, median_ms=f"{med:.1f}", worst_ms=f"{worst:.1f}",
                        worst_over_median=f"{t.worst_over_median:.1f}", kept=len(kept),
                        failed=len(failed), ratio_vs_gradient=f"{vs_grad:.2f}")
    return lines, last


def main() -> None:
    args = h.parser(__doc__, configs=100, seed=0, horizons=[20, 40],
                    horizons_nargs="*").parse_args()
    sampler = h.sampler()
    lines, lasts = ["# The OCP's worst case beside its median", "",
                    (f"`.venv/bin/python benchmarks/worst_case.py --configs {args.configs} --seed "
                     f"{args.seed} --horizons {' '.join(map(str, args.horizons))}` "
                     "(OPENBLAS_NUM_THREADS=1; builds cached, not counted)."), ""], []
    for T in args.horizons:
        block, last = summary(run(sampler, args.seed, args.configs, T))
        lines += block
        lasts.append(last)
    text = "\n".join(lines + [h.last_line("worst_case", *lasts)]) + "\n"
    h.write_result("worst_case.md", text)
    print(text)


if __name__ == "__main__":
    main()
