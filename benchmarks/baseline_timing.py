"""The baseline within enforced limits: in the problem's steps or lengthened, against toppra.

For configurations 0..N-1 of problems/evaluations/evaluation.yaml (seed 0) at each horizon, with
the default limits enforced (the evaluation's 0.05 s per step): the baseline (`solve_baseline`: the
straight line at a time law within the limits, in the problem's steps, else in the fewest steps
found), its status and time law, its duration against toppra's time-optimal motion along the same
line (`time_optimal_law`: rest to rest within the joint and tool limits; no law is faster), that
law's own played curve in the whole steps of its duration (rounded up), and the baseline's solve
time. Writes benchmarks/results/baseline_timing.md.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/baseline_timing.py --configs 100 \\
        --horizons 20 40
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import collections  # noqa: E402
import math  # noqa: E402
from dataclasses import replace  # noqa: E402

STEP_S = 0.05  # the evaluation's


def pair(st, xs) -> str:
    return f"{st.median:.2f} / {st.worst:.2f}" if xs else "-"


def main() -> None:
    args = h.parser(__doc__, configs=100, seed=0, horizons=[20, 40],
                    output=h.RESULTS / "baseline_timing.md").parse_args()
    smp = h.sampler()
    horizons = " ".join(map(str, args.horizons))
    lines = [f"# {__doc__.splitlines()[0]}", "",
             "`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/baseline_timing.py "
             f"--configs {args.configs} --seed {args.seed} --horizons {horizons}`", "",
             "Per horizon T (steps of 0.05 s): how many baselines run in the problem's T steps, "
             "how many are lengthened (their duration / the problem's: median, worst; against "
             "toppra's time-optimal duration along the same line: median, worst), the failures, "
             "the time laws chosen; for the lengthened ones, toppra's law played in the whole "
             "steps of its own duration: its played curve's largest peak / limit (median, worst; "
             "over 1: not within); the baseline's solve time (the search included).", ""]
    groups, rows = [], []
    for T in args.horizons:
        kept = lengthened = failed = 0
        stretch, over_optimal, optimal_played, times = [], [], [], []
        laws = collections.Counter()
        for _, prob in h.configurations(smp, args.configs, args.seed, T):
            setup = h.setup(replace(prob, limits=h.limits_spec(True)))
            sol = h.baseline(setup)
            law = sol.extras["time_law"]
            times.append(sol.solve_time_s)
            laws[law["law"]] += 1
            if not sol.success:
                failed += 1
            elif law["steps"] == T:
                kept += 1
            else:
                lengthened += 1
                stretch.append(law["duration_s"] / law["problem_duration_s"])
                over_optimal.append(law["duration_s"] / law["time_optimal_s"])
                duration, optimal = h.time_optimal_law(setup, h.problem_limits(setup))
                played = h.played_line(setup, math.ceil(duration / STEP_S - 1e-9), optimal)
                optimal_played.append(max(v for v in played["peak_ratios"].values()
                                          if v is not None))
        s, o = h.stats(stretch), h.stats(over_optimal)
        p, t = h.stats(optimal_played), h.stats(times)
        rows.append([T, f"{T * STEP_S:g}", kept, lengthened, failed, pair(s, stretch),
                     pair(o, over_optimal), pair(p, optimal_played),
                     ", ".join(f"{k} {v}" for k, v in laws.most_common()),
                     f"{1e3 * t.median:.0f} / {1e3 * t.worst:.0f}"])
        groups.append(h.key_values(
            T=T, kept=kept, lengthened=lengthened, failed=failed,
            stretch_median=f"{s.median:.3f}" if stretch else "nan",
            over_optimal_median=f"{o.median:.3f}" if over_optimal else "nan"))
    lines += h.table(["T", "problem's duration [s]", "in T steps", "lengthened", "failed",
                      "lengthened: duration / problem's", "lengthened: duration / toppra's",
                      "toppra's law in its own steps: played peak / limit", "time laws",
                      "solve [ms] (median / worst)"], rows)
    h.write_result(args.output, "\n".join(lines) + "\n")
    print(h.last_line("baseline_timing", *groups))


if __name__ == "__main__":
    main()
