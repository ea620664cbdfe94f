"""Time to a sure grasp in the simulated Table II: every method grasps on evidence, not on a clock.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/closed_loop.py [--rollouts 200] [--seed 0]
        [--confidence 0.95] [--tracker-noise auto|mean|expected|iterated] [--problems FILE ...]

Each scenario (default: the Table II types, problems/type*.yaml; any problem file through
`--problems`, nothing is tuned per file) runs at the robot's pace with `goal.confidence` asked
and the cap `timing.max_duration` (default twice the duration): the straight-line baseline as fast
as the limits allow, the OCP planned once to the confidence (`ocp-robot-pace`) and re-planned at
every frame by every rollout (`ocp-mpc`); each rollout grasps at the first step onto the goal whose
tracker belief predicts the confidence, dwelling at the goal under observation until then, or at
the cap (surestep_ocp/evaluation/sure_grasp.py). Per scenario, method and mode (`model` / `true`):
measured success, mean predicted success (calibration), time to grasp (median, p90), share capped,
NEES. Writes benchmarks/results/closed_loop.md and docs/time_to_grasp.png; the last line is
`closed-loop: grasp_model=... grasp_true=... grasp_true_min=... calibration_max=...
time_median_s=... time_ratio_baseline=... time_ratio_worst=... capped=... replans=...
replan_median_ms=... replan_worst_ms=... violations=...` (the `ocp-mpc` figures).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import numpy as np  # noqa: E402

PAPER = "Paper (Table II, real dVRK, 60 regrasps over the four types, grasp at a fixed time): " \
        "SURESTEP 82 %, baseline 18 %."


def figure(res: dict, path) -> None:
    """Success against time to grasp (mode `true`, all scenarios pooled): per method, the share of
    rollouts that have grasped successfully by time t."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for m in h.SURE_METHODS:
        t = np.concatenate([r[m]["true"]["times_s"] for r in res.values()])
        hit = np.concatenate([r[m]["true"]["hit"] for r in res.values()])
        grid = np.linspace(0, t.max() * 1.02, 200)
        ax.plot(grid, [np.mean(hit & (t <= g)) for g in grid], label=m)
    ax.set_xlabel("time to grasp [s]")
    ax.set_ylabel("successful grasps by then (mode true)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".part.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)
    plt.close(fig)


def tables(res: dict, args) -> list[str]:
    head = ["scenario", "method", "success model / true", "predicted model / true",
            "time to grasp median / p90 [s] (true)", "capped (true)", "NEES median (model / true)"]
    rows = []
    for label, r in res.items():
        for m in h.SURE_METHODS:
            c = r[m]
            rows.append([label, m, f"{c['model']['success']:.0%} / {c['true']['success']:.0%}",
                         f"{c['model']['predicted']:.0%} / {c['true']['predicted']:.0%}",
                         f"{c['true']['time_median_s']:.2f} / {c['true']['time_p90_s']:.2f}",
                         f"{c['true']['capped']:.0%}",
                         f"{c['model']['nees_median']:.1f} / {c['true']['nees_median']:.1f}"])
    plans = [[label, r["plan"]["shortest"], r["plan"]["steps"], f"{r['plan']['predicted']:.3f}",
              "yes" if r["plan"]["reached"] else f"no; {needed(r['plan'], r['cap_steps'])}",
              r["baseline_steps"], r["cap_steps"]] for label, r in res.items()]
    rp = [[label] + [f"{sum(s[k] for s in r['ocp-mpc']['replans'].values())}"
                     for k in ("replans", "failed")] + [constrained(r)]
          + [f"{sum(s['held'] for s in r['ocp-mpc']['replans'].values())}",
             ", ".join(f"{c}: {n}" for c, n in sum_causes(r).items()) or "none",
             " / ".join(f"{r['ocp-mpc'][mode]['missed_after_failure']}, "
                        f"{r['ocp-mpc'][mode]['missed_after_hold']}" for mode in h.ROLLOUT_MODES),
             f"{r['ocp-mpc']['violations']}"] for label, r in res.items()]
    return [f"Rollouts: {args.rollouts} per scenario, method and mode; confidence "
            f"{args.confidence}; tracker noise `{args.tracker_noise}`.", "",
            *h.table(head, rows), "", PAPER, "",
            "The plans (robot's pace, 0.05 s a step): the OCP's shortest horizon reaching the "
            "confidence with the detector's observations (its prediction; `no`: not reached "
            "within the cap, the most confident plan), the horizon planned (not below the "
            "problem's), the baseline's fewest steps within the limits, the cap:", "",
            *h.table(["scenario", "shortest", "planned", "predicted", "reached",
                      "baseline steps", "cap steps"], plans), "",
            "`ocp-mpc`'s re-plans (both modes): a failed one keeps the previous plan (by cause); "
            "where the tracker's estimate puts the goal beyond a joint limit, a constrained one "
            "registers the nearest estimate within reach under its belief (in brackets: those "
            "beyond the chi-square 99 % gate, squared Mahalanobis distance over 16.8, where the "
            "belief puts the goal out of reach; the largest distance), a held one the previous "
            "camera registration; missed grasps of rollouts that had a failed / held re-plan "
            "(model; true):", "",
            *h.table(["scenario", "re-plans", "failed", "constrained", "held",
                      "causes of failures",
                      "misses after a failure, after a hold (model / true)",
                      "executed samples beyond a limit"], rp)]


def needed(plan: dict, cap: int) -> str:
    """What a confidence the cap does not allow would need (the search with twice the cap)."""
    if plan.get("needed_steps") is None:
        return (f"not within {2 * cap} steps either (best {plan.get('needed_predicted', 0):.3f})")
    return f"needs {plan['needed_steps']} steps ({plan['needed_steps'] * 0.05:.2f} s at 0.05 s)"


def constrained(r: dict) -> str:
    """`ocp-mpc`'s constrained registrations over both modes, the largest squared Mahalanobis
    distance in brackets."""
    s = r["ocp-mpc"]["replans"].values()
    worst = max((v["constrained_d2_max"] for v in s if v["constrained_d2_max"] is not None),
                default=None)
    n = sum(v["constrained"] for v in s)
    beyond = sum(v["constrained_beyond_gate"] for v in s)
    return f"{n}" + ("" if worst is None else f" ({beyond}; {worst:.1f})")


def sum_causes(r: dict) -> dict:
    out: dict = {}
    for s in r["ocp-mpc"]["replans"].values():
        for c, n in s["causes"].items():
            out[c] = out.get(c, 0) + n
    return out


def main() -> None:
    ap = h.parser(__doc__, seed=0, output="closed_loop.md")
    ap.add_argument("--rollouts", type=int, default=200)
    ap.add_argument("--confidence", type=float, default=0.95)
    ap.add_argument("--tracker-noise", choices=("auto", "mean", "expected", "iterated"),
                    default="auto")
    ap.add_argument("--problems", nargs="+", default=None)
    ap.add_argument("--figure", default=str(h.ROOT / "docs" / "time_to_grasp.png"))
    args = ap.parse_args()
    files = ([h.Path(f) for f in args.problems] if args.problems
             else [h.PROBLEMS / f for _, f in h.TYPES])
    labels = dict((f, n) for n, f in h.TYPES)
    res = {}
    for k, f in enumerate(files):
        label = labels.get(f.name, f.stem) if not args.problems else f.stem
        res[label] = h.scenario_rows(h.load_problem(f), k, args.rollouts, args.seed,
                                     args.confidence, tracker_noise=args.tracker_noise)
        c = res[label]["ocp-mpc"]
        print(label, *(f"{m}: {res[label][m]['true']['success']:.2f}" for m in h.SURE_METHODS),
              f"mpc time {c['true']['time_median_s']:.2f} s", flush=True)
    figure(res, h.Path(args.figure))
    mpc = {label: r["ocp-mpc"] for label, r in res.items()}
    succ = {mode: [c[mode]["success"] for c in mpc.values()] for mode in h.ROLLOUT_MODES}
    calib = max(abs(c[mode]["predicted"] - c[mode]["success"]) for c in mpc.values()
                for mode in h.ROLLOUT_MODES)
    ratios = [r["ocp-mpc"]["true"]["time_median_s"] / r["baseline"]["true"]["time_median_s"]
              for r in res.values()]
    times = [t for c in mpc.values() for mode in h.ROLLOUT_MODES for t in c[mode]["times_s"]]
    capped = np.mean([c[mode]["capped"] for c in mpc.values() for mode in h.ROLLOUT_MODES])
    rp = [s for c in mpc.values() for s in c["replans"].values()]
    s = h.stats([ms for r in rp for ms in r["times_ms"]])
    last = h.last_line("closed-loop", h.key_values(
        grasp_model=f"{np.mean(succ['model']):.3f}", grasp_true=f"{np.mean(succ['true']):.3f}",
        grasp_true_min=f"{min(succ['true']):.3f}", calibration_max=f"{calib:.3f}",
        time_median_s=f"{np.median(times):.2f}", time_ratio_baseline=f"{h.geomean(ratios):.3f}",
        time_ratio_worst=f"{max(ratios):.3f}", capped=f"{capped:.3f}",
        replans=sum(r["replans"] for r in rp), replan_median_ms=f"{s.median:.1f}",
        replan_worst_ms=f"{s.worst:.1f}", violations=sum(c["violations"] for c in mpc.values())))
    extra = f" --problems {' '.join(map(str, args.problems))}" if args.problems else ""
    cmd = (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/closed_loop.py --rollouts "
           f"{args.rollouts} --seed {args.seed} --confidence {args.confidence} --tracker-noise "
           f"{args.tracker_noise}{extra}` (one BLAS thread)")
    out = "\n".join(["# Time to a sure grasp in the simulated Table II", "", cmd, "",
                     *tables(res, args), "", "![success against time to grasp]"
                     "(../../docs/time_to_grasp.png)", "", last, ""])
    h.write_result(str(args.output), out)
    print(out)


if __name__ == "__main__":
    main()
