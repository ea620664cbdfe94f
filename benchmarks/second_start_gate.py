"""The second start's gate at long horizons: the OCP on a correlated-V_d0 model against the full solve of its
diagonal model, evaluated in the model (never above it), with the solve times.

    .venv/bin/python benchmarks/second_start_gate.py T CONFIGS      (docs/general_models.md: 80 10 and 40 20)

Per evaluation configuration (seed 0): status, time, final objective / the diagonal model's plan's objective, the
gate's status and whether the second start ran (`ahead`); last line: how many above, median and worst time.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation  # noqa: E402
from surestep_ocp.problem.setup import build_setup  # noqa: E402
from surestep_ocp.solvers.methods import ocp_initial_guess  # noqa: E402
from surestep_ocp.solvers.ocp import _objective_at, diagonal_model_setup, solve_ocp  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    T, n = int(sys.argv[1]), int(sys.argv[2])
    V = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
    V[0, 2] = V[2, 0] = 2e-2
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations" / "evaluation.yaml"))
    above, times = 0, []
    for c in range(n):
        p = sampler.problem(sampler.sample(0, c))
        setup = build_setup(replace(p, horizon=T, noise=replace(p.noise, V_d0=V)))
        sol = solve_ocp(setup, ocp_initial_guess(setup))
        times.append(sol.solve_time_s)
        approx = diagonal_model_setup(setup)
        ref = _objective_at(setup, sol, solve_ocp(approx, ocp_initial_guess(approx)))
        above += sol.objective > ref * (1 + 1e-6)
        gate = sol.extras["second_start"]
        print(c, sol.status, f"{sol.solve_time_s * 1e3:.0f} ms", f"objective / diagonal plan's {sol.objective / ref:.4f}",
              gate.get("status"), gate.get("ahead"), flush=True)
    print(f"above the diagonal plan: {above}/{n}; median {np.median(times) * 1e3:.0f} ms, worst {max(times) * 1e3:.0f} ms")


if __name__ == "__main__":
    main()
