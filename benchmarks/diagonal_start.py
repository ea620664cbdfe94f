"""A 6x6-recursion model solved two ways, in the same run: the default strategy against Newton from the diagonal
model's plan only.

    .venv/bin/python benchmarks/diagonal_start.py [--model correlated|full|joint] [--configs 100]

The default strategy (`solve_ocp`) runs Newton from the straight line, then the diagonal model's plan (every base
covariance replaced by its diagonal, no joint-space term: the fast scalar path) as a gated second start. The
alternative solves the diagonal model, then runs the 6x6 Newton once from its plan (a descent from it, so never
above it). Per configuration: both times (set-up included, builds not) and the ratio of the objectives. BLAS is
pinned to one thread. Writes benchmarks/results/diagonal_start_<model>.md.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from general_models import JOINT_SIGMA, correlated_depth, full_depth  # noqa: E402

from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation  # noqa: E402
from surestep_ocp.output.solution import write_text_atomic  # noqa: E402
from surestep_ocp.problem.setup import build_setup  # noqa: E402
from surestep_ocp.solvers.methods import ocp_initial_guess  # noqa: E402
from surestep_ocp.solvers.ocp import InitialGuess, diagonal_model_setup, solve_ocp  # noqa: E402
from surestep_ocp.solvers.solver_setup import newton_solver  # noqa: E402

MODELS = {"correlated": {"V_d0": correlated_depth()}, "full": {"V_d0": full_depth()},
          "joint": {"joint_sigma": JOINT_SIGMA}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=list(MODELS), default="correlated")
    ap.add_argument("--configs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations" / "evaluation.yaml"))
    t_default, t_diag, ratio, lines = [], [], [], []
    for c in range(args.configs):
        base = sampler.problem(sampler.sample(args.seed, c))
        setup = build_setup(replace(base, noise=replace(base.noise, **MODELS[args.model])))
        init = ocp_initial_guess(setup)
        if c == 0:  # builds
            solve_ocp(setup, init)
            solve_ocp(diagonal_model_setup(setup), init)
        t0 = time.perf_counter()
        a = solve_ocp(setup, init)
        t1 = time.perf_counter()
        plan = solve_ocp(diagonal_model_setup(setup), init)
        b = newton_solver(setup).solve(setup, InitialGuess(np.array(plan.q), "diagonal model's plan"),
                                       tol=setup.problem.solver.tol, max_iter=setup.problem.solver.surrogate_max_iter)
        t2 = time.perf_counter()
        t_default.append(t1 - t0)
        t_diag.append(t2 - t1)
        ratio.append(b.objective / a.objective)
        lines.append(f"| {c} | {1e3 * (t1 - t0):.1f} | {1e3 * (t2 - t1):.1f} | {b.status} | {ratio[-1]:.6f} |")
        print(lines[-1], flush=True)
    r = np.array(ratio)
    summary = (f"median {1e3 * np.median(t_default):.1f} ms (default) against {1e3 * np.median(t_diag):.1f} ms "
               f"(diagonal start), worst {1e3 * max(t_default):.1f} / {1e3 * max(t_diag):.1f} ms; diagonal start "
               f"worse (> 1e-6) on {int(np.sum(r > 1 + 1e-6))}/{len(r)}, better on {int(np.sum(r < 1 - 1e-6))}, "
               f"largest ratio {r.max():.4f}")
    text = "\n".join([f"# Newton from the diagonal model's plan ({args.model})", "",
                      f"`.venv/bin/python benchmarks/diagonal_start.py --model {args.model} --configs {args.configs}"
                      f" --seed {args.seed}` (OPENBLAS_NUM_THREADS=1)", "", summary, "",
                      "| configuration | default [ms] | diagonal start [ms] | its status | objective ratio |",
                      "|---|---|---|---|---|", *lines]) + "\n"
    write_text_atomic(ROOT / "benchmarks" / "results" / f"diagonal_start_{args.model}.md", text)
    print(summary)


if __name__ == "__main__":
    main()
