"""The closed loop at the robot's pace: belief-space MPC (`ocp-mpc`) in the simulated Table II.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/closed_loop.py [--rollouts 200] [--seed 0]

Every scenario type (problems/type*.yaml) as `python -m surestep_ocp.evaluation.table2` runs it: the
baseline, the paper's preset gradient and the OCP planned once at the paper's pace, and the type at
the robot's pace (twice the steps of 0.05 s, the camera moves at the same times, the limits
enforced) planned once (`ocp-robot-pace`) and re-planned at every frame by every rollout from its
own belief (`ocp-mpc`, surestep_ocp/evaluation/closed_loop.py); `--rollouts` rollouts per method,
type and mode. Each MPC rollout's executed motion (every plan from its start to the next one's) is
checked against the limits by finite differences and Pinocchio's kinematics. Writes
benchmarks/results/closed_loop.md and docs/closed_loop_error.png (one rollout's executed error
against time, Type 1 medium, mode `true`); the last line is `closed-loop: grasp_model=...
grasp_true=... replans=... replan_median_ms=... replan_worst_ms=... violations=...`.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402

METHODS = ("baseline", "gradient-paper", "ocp")


def main() -> None:
    ap = h.parser(__doc__, seed=0)
    ap.add_argument("--rollouts", type=int, default=200)
    ap.add_argument("--figure", default=str(h.ROOT / "docs" / "closed_loop_error.png"))
    args = ap.parse_args()
    text, res = h.success_table(h.PROBLEMS, args.rollouts, args.seed, methods=METHODS,
                                replan_rollouts=0, keep_paths=True)
    h.error_figure(res, h.Path(args.figure))
    mpc = [row["ocp-mpc"] for row in res.values()]
    grasp = {mode: float(np.mean([c[mode] for c in mpc])) for mode in h.ROLLOUT_MODES}
    rp = [r for c in mpc for r in c["replans"].values()]
    s = h.stats([ms for r in rp for ms in r["times_ms"]])  # every re-plan of the run
    last = h.last_line("closed-loop", h.key_values(
        grasp_model=f"{grasp['model']:.3f}", grasp_true=f"{grasp['true']:.3f}",
        replans=sum(r["replans"] for r in rp), replan_median_ms=f"{s.median:.1f}",
        replan_worst_ms=f"{s.worst:.1f}",
        violations=sum(c["violations"] for c in mpc)))
    cmd = (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/closed_loop.py --rollouts "
           f"{args.rollouts} --seed {args.seed}` (one BLAS thread)")
    out = f"# The closed loop in the simulated Table II\n\n{cmd}\n\n{text}\n\n{last}\n"
    h.write_result("closed_loop.md", out)
    print(out)


if __name__ == "__main__":
    main()
