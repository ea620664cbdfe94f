"""Newton's secant end-game against the plain surrogate, on the same configurations in the same run.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/secant_endgame.py [--configs 100] [--models ...] [--repeats 3]

For each model (benchmarks/general_models.py's names, plus `paper T=40`: the scalar recursion beyond the exact
end-game's size) and each of the first `--configs` evaluation configurations (seed 0, T = 20 unless named), the
projected Newton solver (`NewtonSolver.run`, from the straight line's IK, the problem's tol) with and without the
secant correction, interleaved, `--repeats` times each (the minimum time kept). Reported: iterations, Newton time
(median, p95, worst), the objective's relative difference (both runs converge to a projected gradient below tol) and
how many runs converged. Writes benchmarks/results/secant_endgame.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from general_models import MODELS, variant

from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.output.solution import write_text_atomic
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.solvers.ocp import newton_solver

ROOT = Path(__file__).resolve().parents[1]
EXTRA = {"paper T=40": (MODELS["paper"][0], "auto", 40)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--models", nargs="*", default=["correlated V_d0", "full V_d0", "joint-space", "paper T=40"])
    args = ap.parse_args()
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations" / "evaluation.yaml"))
    rows = []
    for name in args.models:
        noise, form, T = EXTRA[name] if name in EXTRA else (*MODELS[name], None)
        res = {False: {"it": [], "t": [], "ok": 0, "f": []}, True: {"it": [], "t": [], "ok": 0, "f": []}}
        for c in range(args.configs):
            setup = build_setup(variant(sampler.problem(sampler.sample(0, c)), noise, form, T))
            init, solver, tol = ocp_initial_guess(setup), newton_solver(setup), setup.problem.solver.tol
            best = {False: None, True: None}
            for _ in range(args.repeats):
                for sec in (False, True):
                    r = solver.run(setup, init, tol=tol, max_iter=300, use_secant=sec)
                    if best[sec] is None or r.solve_time_s < best[sec].solve_time_s:
                        best[sec] = r
            for sec, r in best.items():
                res[sec]["it"].append(r.iterations)
                res[sec]["t"].append(r.solve_time_s * 1e3)
                res[sec]["ok"] += r.status == "Solve_Succeeded"
                res[sec]["f"].append(r.objective)
            print(f"{name} {c:3d}: surrogate {best[False].iterations} it {best[False].solve_time_s * 1e3:.1f} ms "
                  f"{best[False].status} | secant {best[True].iterations} it ({best[True].secant_steps} secant) "
                  f"{best[True].solve_time_s * 1e3:.1f} ms {best[True].status}", flush=True)
        f0, f1 = np.array(res[False]["f"]), np.array(res[True]["f"])
        rel = (f1 - f0) / np.abs(f0)
        for sec in (False, True):
            t, it = np.array(res[sec]["t"]), np.array(res[sec]["it"])
            tail = (f"{np.median(res[True]['t']) / np.median(res[False]['t']):.2f} | {rel.min():+.1e} / {rel.max():+.1e} |"
                    if sec else " | |")
            rows.append(f"| {name} | {'secant end-game' if sec else 'surrogate only'} | {res[sec]['ok']}/{args.configs} | "
                        f"{np.median(it):.0f} | {it.sum()} | {np.median(t):.1f} | {np.percentile(t, 95):.1f} | "
                        f"{t.max():.1f} | {tail}")
    text = "\n".join([
        "# Newton's secant end-game against the surrogate alone", "",
        f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/secant_endgame.py --configs {args.configs} --repeats "
        f"{args.repeats} --models {' '.join(repr(m) for m in args.models)}` (Newton only, from the straight line; "
        "minimum of the repeats per configuration; both variants interleaved in the same run)", "",
        "| model | Newton | converged | median iterations | total iterations | median [ms] | p95 [ms] | worst [ms] | "
        "median time, secant / surrogate | objective, secant vs surrogate (rel., min / max) |",
        "|---|---|---|---|---|---|---|---|---|---|", *rows]) + "\n"
    write_text_atomic(ROOT / "benchmarks" / "results" / "secant_endgame.md", text)
    print(text)


if __name__ == "__main__":
    main()
