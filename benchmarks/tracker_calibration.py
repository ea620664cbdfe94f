"""The tracker's calibration: predicted against measured grasp success per tracker noise form.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/tracker_calibration.py [--rollouts 300]
        [--seed 0] [--problems FILE ...]

Each scenario (default: Type 1 medium, Type 1 hard, Type 2) at the robot's pace (`robot_pace`):
the OCP's plan and the baseline, each run open loop in both rollout modes with the evaluation's
detector, grasping at the plan's end; per tracker noise form (`mean`, `expected`, `iterated`,
evaluation/rollout.py) the measured success, the mean predicted success (the tracker's own
Sigma_T-1|T-1 + W) and the NEES of the final error (6 when consistent). Writes
benchmarks/results/tracker_calibration.md; the last line is `tracker-calibration: worst_mean=...
worst_expected=... worst_auto=...` (the largest |predicted - measured| over scenarios, plans and
modes; `auto`: `mean` in `model` mode, `expected` in `true` mode).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402

FORMS = ("mean", "expected", "iterated")
DEFAULT = ["type1_medium.yaml", "type1_hard.yaml", "type2_needle_arm_moves.yaml"]


def main() -> None:
    ap = h.parser(__doc__, seed=0, output="tracker_calibration.md")
    ap.add_argument("--rollouts", type=int, default=300)
    ap.add_argument("--problems", nargs="+", default=None)
    args = ap.parse_args()
    files = [h.Path(f) for f in args.problems] if args.problems else [h.PROBLEMS / f
                                                                       for f in DEFAULT]
    rows, gap = [], {f: [] for f in (*FORMS, "auto")}
    for k, f in enumerate(files):
        s = h.setup(h.robot_pace(h.load_problem(f)))
        for m in ("baseline", "ocp"):
            poses = np.asarray(h.method(s, m).poses, float)
            for mi, mode in enumerate(h.ROLLOUT_MODES):
                for form in FORMS:
                    ro = h.rollout(s.eval_model, poses, poses[-1], args.rollouts,
                                   np.random.default_rng([args.seed, k, mi]), mode,
                                   detection=h.Detection(), changes=s.camera_changes(),
                                   grasp=h.GraspRule(), tracker_noise=form)
                    hit = h.within(ro.pos_err, ro.ori_err, 0.005, 0.2).mean()
                    v = h.nees(ro.final_error, ro.sigma_final)
                    d = abs(ro.predicted.mean() - hit)
                    gap[form].append(d)
                    if form == ("mean" if mode == "model" else "expected"):
                        gap["auto"].append(d)
                    rows.append([f.stem, m, mode, form, f"{hit:.1%}", f"{ro.predicted.mean():.1%}",
                                 f"{np.median(v):.1f}", f"{np.mean(v):.1f}"])
                    print(*rows[-1], flush=True)
    last = h.last_line("tracker-calibration", h.key_values(
        **{f"worst_{f}": f"{max(g):.3f}" for f, g in gap.items()}))
    cmd = (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/tracker_calibration.py "
           f"--rollouts {args.rollouts} --seed {args.seed}` (one BLAS thread)")
    text = "\n".join(["# The tracker's calibration per noise form", "", cmd, "",
                      *h.table(["scenario", "plan", "mode", "tracker noise", "measured",
                                "predicted", "NEES median", "NEES mean"], rows), "", last, ""])
    h.write_result(str(args.output), text)
    print(text)


if __name__ == "__main__":
    main()
