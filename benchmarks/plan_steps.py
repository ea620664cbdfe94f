"""The largest single steps of each method's plan on evaluation configurations: where large rollout
errors start.

    .venv/bin/python benchmarks/plan_steps.py [--configs 26 79 98 38]
        [--methods baseline ocp ocp-no-orientation]

Per configuration of problems/evaluations/evaluation.yaml (seed 0) and method: Tr(Sigma_T) of the
plan (evaluation model, all components), the total and the largest per-step rotation [rad]
(geodesic, scipy), the largest per-step translation [mm] and the smallest depth [m]. The paper's
motion noise `|dp|^2 W_p0 + angle^2 W_o0` with W_o0 = 1e-3 times the 6x6 identity gives a step of
angle a a position std of 32 a mm, so these steps are what the true-mode rollouts' largest errors
come from (docs/evaluation.md). Prints a Markdown table.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402


def main() -> None:
    ap = h.parser(__doc__, seed=0)
    ap.add_argument("--configs", type=int, nargs="+", default=[26, 79, 98, 38])
    ap.add_argument("--methods", nargs="+", default=["baseline", "ocp", "ocp-no-orientation"])
    a = ap.parse_args()
    sampler = h.sampler()
    print("\n".join(h.table(["config", "method", "Tr(Sigma_T)", "rotation total [rad]",
                             "largest step [rad]",
                              "largest step [mm]", "min depth [m]"])))
    for c in a.configs:
        setup = h.setup(h.config_problem(sampler, a.seed, c))
        for m in a.methods:
            sol = h.method(setup, m)
            P = np.asarray(sol.poses, float)
            R = Rotation.from_rotvec(P[:, 3:])
            turn = (R[:-1].inv() * R[1:]).magnitude()
            move = 1e3 * np.linalg.norm(np.diff(P[:, :3], axis=0), axis=1)
            print(f"| {c} | {m} | {sol.trace_final:.3e} | {turn.sum():.2f} | {turn.max():.2f} | "
                  f"{move.max():.0f} | {P[:, 2].min():.3f} |", flush=True)


if __name__ == "__main__":
    main()
