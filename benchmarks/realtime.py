"""Plans within the motion limits at tracker rate: the interior-point Newton method against IPOPT,
cold and in a 20 Hz re-planning loop.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py [--configs 100] [--seed 0]

Cold: the default problem (problems/needle_regrasp.yaml: 40 steps of 50 ms, the limits enforced) and
the first `--configs` configurations of problems/evaluations/evaluation.yaml at the same horizon,
pace and limits, each solved by `solver.name: interior` (the interior-point method, IPOPT as its
fallback) and by IPOPT (`solver.name: ipopt`, the reference and today's default) in the same run;
the solve times (builds cached and not counted), the interior attempt's own status, iterations and
time, and Tr(Sigma_T) of both.
The 20 Hz loop: `--episodes` episodes of a `Planner` on the default problem (`solver.name:
interior`) against a simulated tracker (seeds 0, 1, ...), a re-plan at every waypoint from the
executed curve's state; per re-plan its time (builds apart) and whether it succeeded; per episode
the executed motion (every plan from its start until the next one's, sampled every millisecond)
checked against the limits by finite differences and Pinocchio's kinematics (violations: samples
beyond a limit by more than the differencing error). Writes benchmarks/results/realtime.md; the last
line is `realtime: cold_median_ms=... cold_worst_ms=... replan_median_ms=... replan_worst_ms=...
infeasible=... violations=...`.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from surestep_ocp.model.limits import evaluate_curve  # noqa: E402

H = 1e-3  # [s] sampling of the executed motion



def cold(args) -> tuple[list[str], dict]:
    """Every cold problem by both solvers: table lines and the figures."""
    problems = [("default", h.load_problem(h.DEFAULT_PROBLEM))]
    base = problems[0][1]
    for c, p in h.configurations(h.sampler(), args.configs, args.seed, horizon=base.horizon):
        problems.append((str(c), replace(p, timing=base.timing, limits=base.limits)))
    rows, ours, ref, worse, failed, disagree, alone, own_ok = [], [], [], [], [], [], [], 0
    for name, prob in problems:
        setup = h.setup(h.with_solver(prob, name="interior"))
        h.ocp(setup)  # builds (and compiles) outside the timed solves
        sol = h.ocp(setup)
        ipopt = h.ocp(h.with_solver(setup, name="ipopt"))
        own = sol.attempts[0]
        alone.append(own.solve_time_s * 1e3)
        own_ok += own.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        ours.append(sol.solve_time_s * 1e3)
        ref.append(ipopt.solve_time_s * 1e3)
        rel = (sol.trace_final / ipopt.trace_final - 1 if ipopt.success and sol.success
               else float("nan"))
        if sol.success and ipopt.success and rel > 1e-6:
            worse.append((name, rel))
        if not sol.success:
            failed.append((name, sol.status, ipopt.status))
            if ipopt.success:
                disagree.append(name)
        rows.append((name, sol.status, f"{ours[-1]:.1f}", own.status, own.iterations,
                     f"{alone[-1]:.1f}", ipopt.status, f"{ref[-1]:.1f}", f"{rel:.1e}"))
        print(name, sol.status, f"{ours[-1]:.1f} ms", ipopt.status, f"{ref[-1]:.1f} ms",
              f"rel {rel:.1e}", flush=True)
    so, sr, sa = h.stats(ours), h.stats(ref), h.stats(alone)
    lines = ["## Cold, within the limits (T = 40, 50 ms steps)", "",
             (f"{len(problems)} problems: the default and {args.configs} evaluation "
              f"configurations (seed {args.seed})."),
             (f"solver.name: interior (IPOPT its fallback): median {so.median:.1f} ms, "
              f"p90 {so.p90:.1f} ms, worst {so.worst:.1f} ms; IPOPT in the "
              f"same run: median {sr.median:.1f} ms, worst {sr.worst:.1f} ms "
              f"(IPOPT / ours, medians: {sr.median / so.median:.1f}x). "
              f"Not solved: {len(failed)} "
              f"({', '.join(f'{n}: {s} (IPOPT {i})' for n, s, i in failed) or 'none'}); "
              f"of those, solved by IPOPT: {len(disagree)}. "
              f"Tr(Sigma_T) more than 1e-6 above IPOPT's: {len(worse)} "
              f"({', '.join(f'{n}: {r:.1e}' for n, r in worse) or 'none'}). "
              f"The interior-point attempt alone: "
              f"converged on {own_ok} of {len(problems)}, median {sa.median:.1f} ms, "
              f"worst {sa.worst:.1f} ms."), "",
             *h.table(["problem", "status", "ms (with fallback)", "interior attempt",
                       "its iterations", "its ms", "IPOPT status", "IPOPT ms",
                       "Tr / IPOPT's - 1"], rows), ""]
    return lines, {"cold_median_ms": so.median, "cold_worst_ms": so.worst,
                   "cold_failed": len(failed), "cold_disagree": len(disagree),
                   "cold_worse": len(worse)}


def executed(pieces, dt: float) -> np.ndarray:
    """Joint samples every H seconds of the executed motion: each plan (start step, joints, start
    state) from its start until the next one's."""
    out = []
    for i, (k, q, start) in enumerate(pieces):
        end = pieces[i + 1][0] if i + 1 < len(pieces) else k + len(q) - 1
        t = np.arange(round((end - k) * dt / H) + (i + 1 == len(pieces))) * H
        out.append(evaluate_curve(q, dt, t, start=start)[0])
    return np.vstack(out)


def violations(setup, q: np.ndarray) -> int:
    """Samples of the executed joints beyond a limit: joint bounds, joint velocities and
    accelerations (finite differences), the tool's speed and rotation speed (Pinocchio's kinematics
    every 5 ms); each beyond by more than the differencing error (0.1 % of the velocity limits, 1 %
    of the acceleration ones)."""
    lim, robot = h.problem_limits(setup), setup.robot
    mov = robot.supporting_joints()
    v = np.diff(q, axis=0)[:, mov] / H
    a = np.diff(q, n=2, axis=0)[:, mov] / H**2
    poses = np.array([robot.frame_pose(qi) for qi in q[::5]])
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / (5 * H)
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    turn = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)) / (5 * H)
    return int(np.sum((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
               + np.sum(np.abs(v) > lim.velocity[mov] * 1.001 + 1e-6)
               + np.sum(np.abs(a) > lim.acceleration[mov] * 1.01 + 1e-3)
               + np.sum(speed > lim.tool_speed * 1.001) + np.sum(turn > lim.tool_rotation * 1.001))


def loop(args) -> tuple[list[str], dict]:
    """The 20 Hz loop's episodes: table lines and the figures."""
    setup = h.setup(h.load_problem(h.DEFAULT_PROBLEM).with_solver(name="interior"))
    rows, times, failed, bad, late = [], [], 0, 0, []
    for seed in range(args.episodes):
        episode = h.tracker_loop(setup, seed=seed)  # what `surestep replan` runs
        planner, pieces = episode["planner"], episode["pieces"]
        dt = planner.setup.ocp.timing.step_s
        ep_times = [p.extras["replan"]["time_s"] * 1e3 for p in episode["plans"]]
        ep_failed = episode["summary"]["failed"]
        n_bad = violations(planner.setup, executed(pieces, dt))
        s = h.stats(ep_times)
        late.append(planner.horizon - planner.setup.ocp.horizon)
        rows.append((seed, len(ep_times), ep_failed, f"{s.median:.1f}", f"{s.worst:.1f}", late[-1],
                     n_bad))
        print(*rows[-1], flush=True)
        times += ep_times
        failed += ep_failed
        bad += n_bad
    s = h.stats(times)
    lines = ["## The 20 Hz loop within the limits", "",
             (f"{args.episodes} episodes of the default problem (`solver.name: interior`), "
              f"a re-plan at every waypoint from the executed curve's state: "
              f"{len(times)} re-plans, "
              f"median {s.median:.1f} ms, p90 {s.p90:.1f} ms, worst {s.worst:.1f} ms; "
              f"not succeeded (the previous plan kept): {failed}; "
              f"steps the goal moved later (median, worst): {int(np.median(late))}, {max(late)}; "
              f"executed samples beyond a limit: {bad}."), "",
             *h.table(["seed", "re-plans", "failed", "median ms", "worst ms", "steps later",
                       "violations"], rows),
             ""]
    return lines, {"replan_median_ms": s.median, "replan_worst_ms": s.worst, "infeasible": failed,
                   "violations": bad}


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0)
    ap.add_argument("--episodes", type=int, default=20)
    args = ap.parse_args()
    lines = ["# Plans within the motion limits at tracker rate", "",
             (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py "
              f"--configs {args.configs} --seed {args.seed}` "
              f"(one BLAS thread; builds cached, not counted)."), ""]
    block, figs = cold(args)
    lines += block
    block, lp = loop(args)
    lines += block
    last = h.last_line("realtime", h.key_values(
        cold_median_ms=f"{figs['cold_median_ms']:.1f}",
        cold_worst_ms=f"{figs['cold_worst_ms']:.1f}",
        replan_median_ms=f"{lp['replan_median_ms']:.1f}",
        replan_worst_ms=f"{lp['replan_worst_ms']:.1f}",
        infeasible=lp["infeasible"], violations=lp["violations"]))
    text = "\n".join(lines + [last]) + "\n"
    h.write_result("realtime.md", text)
    print(text)


if __name__ == "__main__":
    main()
