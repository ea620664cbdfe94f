"""Newton's secant end-game against the plain surrogate, on the same configurations in the same run.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/secant_endgame.py [--configs 100]
        [--models ...] [--repeats 3]

For each model (benchmarks/general_models.py's names, plus `paper T=40`: the scalar recursion beyond
the exact end-game's size) and each of the first `--configs` evaluation configurations (seed 0,
T = 20 unless named), the projected Newton solver (`NewtonSolver.run`, from the straight line's IK,
the problem's tol) with and without the secant correction, interleaved, `--repeats` times each (the
minimum time kept). Reported: iterations, Newton time (median, p95, worst), the objective's relative
difference (both runs converge to a projected gradient below tol) and how many runs converged.
Writes benchmarks/results/secant_endgame.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402

from general_models import MODELS, variant  # noqa: E402
EXTRA = {"paper T=40": (MODELS["paper"][0], "auto", 40)}


def main() -> None:
    ap = h.parser(__doc__, configs=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--models", nargs="*",
                    default=["correlated V_d0", "full V_d0", "joint-space", "paper T=40"])
    args = ap.parse_args()
    sampler = h.sampler()
    rows = []
    for name in args.models:
        noise, form, T = EXTRA[name] if name in EXTRA else (*MODELS[name], None)
        res = {False: {"it": [], "t": [], "ok": 0, "f": []},
               True: {"it": [], "t": [], "ok": 0, "f": []}}
        for c, problem in h.configurations(sampler, args.configs):
            setup = h.setup(variant(problem, noise, form, T))
            init, solver, tol = h.initial_guess(setup), h.newton(setup), setup.ocp.solver.tol
            runs = {False: [], True: []}
            for _ in range(args.repeats):  # interleaved
                for sec in (False, True):
                    runs[sec].append(solver.run(setup, init, tol=tol, max_iter=300, use_secant=sec))
            best = {sec: min(rs, key=lambda r: r.solve_time_s) for sec, rs in runs.items()}
            for sec, r in best.items():
                res[sec]["it"].append(r.iterations)
                res[sec]["t"].append(r.solve_time_s * 1e3)
                res[sec]["ok"] += r.status == "Solve_Succeeded"
                res[sec]["f"].append(r.objective)
            print(f"{name} {c:3d}: surrogate {best[False].iterations} it "
                  f"{best[False].solve_time_s * 1e3:.1f} ms {best[False].status} | secant "
                  f"{best[True].iterations} it ({best[True].secant_steps} secant) "
                  f"{best[True].solve_time_s * 1e3:.1f} ms {best[True].status}", flush=True)
        f0, f1 = np.array(res[False]["f"]), np.array(res[True]["f"])
        rel = (f1 - f0) / np.abs(f0)
        for sec in (False, True):
            t, it = h.stats(res[sec]["t"]), np.array(res[sec]["it"])
            tail = (f"{h.ratio_of_medians(res[True]['t'], res[False]['t']):.2f} | {rel.min():+.1e} "
                    f"/ {rel.max():+.1e} |"
                    if sec else " | |")
            rows.append(f"| {name} | {'secant end-game' if sec else 'surrogate only'} | "
                        f"{res[sec]['ok']}/{args.configs} | {np.median(it):.0f} | {it.sum()} | "
                        f"{t.median:.1f} | {t.p95:.1f} | {t.worst:.1f} | {tail}")
    text = "\n".join([
        "# Newton's secant end-game against the surrogate alone", "",
        ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/secant_endgame.py --configs "
         f"{args.configs} --repeats {args.repeats} --models "
         f"{' '.join(repr(m) for m in args.models)}` (Newton only, from the straight line; minimum "
         "of the repeats per configuration; both variants interleaved in the same run)"), "",
        *h.table(["model", "Newton", "converged", "median iterations", "total iterations",
                  "median [ms]", "p95 [ms]", "worst [ms]", "median time, secant / surrogate",
                  "objective, secant vs surrogate (rel., min / max)"],
                 rows)]) + "\n"
    h.write_result("secant_endgame.md", text)
    print(text)


if __name__ == "__main__":
    main()
