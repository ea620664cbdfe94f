"""The second start's gate at long horizons: the OCP on a correlated-V_d0 model against the full
solve of its diagonal model, evaluated in the model (never above it), with the solve times.

    .venv/bin/python benchmarks/second_start_gate.py T CONFIGS
        (docs/general_models.md: 80 10 and 40 20)

Per evaluation configuration (seed 0): status, time, final objective / the diagonal model's plan's
objective, the gate's status and whether the second start ran (`ahead`); last line: how many above,
median and worst time.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import sys  # noqa: E402
from dataclasses import replace  # noqa: E402

from general_models import correlated_depth  # noqa: E402


def main() -> None:
    T, n = int(sys.argv[1]), int(sys.argv[2])
    V = correlated_depth()
    above, times = 0, []
    for c, p in h.configurations(h.sampler(), n, 0, horizon=T):
        setup = h.setup(replace(p, noise=replace(p.noise, V_d0=V)))
        sol = h.ocp(setup)
        times.append(sol.solve_time_s)
        ref = h.objective_at(setup, sol, h.ocp(h.diagonal_model(setup)))
        above += sol.objective > ref * (1 + 1e-6)
        gate = sol.run.second_start
        print(c, sol.status, f"{sol.solve_time_s * 1e3:.0f} ms",
              f"objective / diagonal plan's {sol.objective / ref:.4f}", gate and gate.status,
              gate and gate.ahead, flush=True)
    t = h.stats(times)
    print(f"above the diagonal plan: {above}/{n}; median {t.median * 1e3:.0f} ms, worst "
          f"{t.worst * 1e3:.0f} ms")


if __name__ == "__main__":
    main()
