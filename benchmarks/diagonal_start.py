"""A 6x6-recursion model solved two ways, in the same run: the default strategy against Newton from
the diagonal model's plan only.

    .venv/bin/python benchmarks/diagonal_start.py [--model correlated|full|joint] [--configs 100]

The default strategy (`solve_ocp`) runs Newton from the straight line, then the diagonal model's
plan (every base covariance replaced by its diagonal, no joint-space term: the fast scalar path) as
a gated second start. The alternative solves the diagonal model, then runs the 6x6 Newton once from
its plan (a descent from it, so never above it). Per configuration: both times (set-up included,
builds not) and the ratio of the objectives. BLAS is pinned to one thread. Writes
benchmarks/results/diagonal_start_<model>.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from general_models import JOINT_SIGMA, correlated_depth, full_depth  # noqa: E402

MODELS = {"correlated": {"V_d0": correlated_depth()}, "full": {"V_d0": full_depth()},
          "joint": {"joint_sigma": JOINT_SIGMA}}


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0)
    ap.add_argument("--model", choices=list(MODELS), default="correlated")
    args = ap.parse_args()
    sampler = h.sampler()
    t_default, t_diag, ratio, lines = [], [], [], []
    for c, base in h.configurations(sampler, args.configs, args.seed):
        setup = h.setup(replace(base, noise=replace(base.noise, **MODELS[args.model])))
        init = h.initial_guess(setup)
        if c == 0:  # builds
            h.ocp(setup, init)
            h.ocp(h.diagonal_model(setup), init)
        t0 = time.perf_counter()
        a = h.ocp(setup, init)
        t1 = time.perf_counter()
        plan = h.ocp(h.diagonal_model(setup), init)
        b = h.newton(setup).solve(setup, h.guess(plan.q, "diagonal model's plan"),
                                  tol=setup.ocp.solver.tol,
                                  max_iter=setup.ocp.solver.surrogate_max_iter)
        t2 = time.perf_counter()
        t_default.append(t1 - t0)
        t_diag.append(t2 - t1)
        ratio.append(b.objective / a.objective)
        lines.append(f"| {c} | {1e3 * (t1 - t0):.1f} | {1e3 * (t2 - t1):.1f} | {b.status} | "
                     f"{ratio[-1]:.6f} |")
        print(lines[-1], flush=True)
    r = np.array(ratio)
    summary = (f"median {1e3 * h.median(t_default):.1f} ms (default) against "
               f"{1e3 * h.median(t_diag):.1f} ms (diagonal start), worst "
               f"{1e3 * max(t_default):.1f} / {1e3 * max(t_diag):.1f} ms; diagonal start worse (> "
               f"1e-6) on {int(np.sum(r > 1 + 1e-6))}/{len(r)}, better on "
               f"{int(np.sum(r < 1 - 1e-6))}, largest ratio {r.max():.4f}")
    text = "\n".join([f"# Newton from the diagonal model's plan ({args.model})", "",
                      (f"`.venv/bin/python benchmarks/diagonal_start.py --model {args.model} "
                       f"--configs {args.configs} --seed {args.seed}` "
                       "(OPENBLAS_NUM_THREADS=1)"), "", summary, "",
                      *h.table(["configuration", "default [ms]", "diagonal start [ms]",
                                "its status", "objective ratio"], lines)]) + "\n"
    h.write_result(f"diagonal_start_{args.model}.md", text)
    print(summary)


if __name__ == "__main__":
    main()
