"""The default problem (problems/needle_regrasp.yaml) with its motion limits enforced, at several
paces.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/default_limits.py
        [--cases 0.05:20:20 0.1:20:20 ...]

Each case is `step_s:horizon:tracker_hz[:acc_scale]` (tracker_hz 0: 1 / step_s, one observation per
step) (acc_scale: the enforced plan made with the joint acceleration limits times it, then checked
and exported with the full ones). Per case: the OCP (`ocp`, the CLI's method: its initial guess, the
problem's solver settings) with `limits.enforce: false` and `true`, and the straight-line baseline,
all on the same belief model (the case's timing: `step_s * tracker_hz` observations per step), so
the traces compare plans, not models. Reported: status, Tr(Sigma_T), the enforced trace over the
unconstrained one, solve time (one run each; the NLP's build and compile excluded where the solver
reports it: `solve_time_s`), the largest tool step [mm] and joint steps of each plan, whether it
meets every limit at its planned pace (`limits.py`), and its exported trajectory's duration
(`surestep export`'s time parametrisation, toppra, within the joint and tool limits) against the
planned `horizon * step_s`. Writes benchmarks/results/default_limits.md.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
ROTARY = ["yaw", "pitch", "roll", "wrist_pitch", "wrist_yaw"]


def plan_row(setup, sol, step, export_lim=None):
    q = np.array(sol.q, float)
    robot, lim = setup.robot, export_lim or h.problem_limits(setup)
    rep = h.plan_report(robot, q, step, lim, robot.frame)
    names = list(lim.joint_names)
    dq = np.abs(np.diff(q, axis=0))
    rot = max(dq[:, names.index(n)].max() for n in ROTARY)
    ins = dq[:, names.index("insertion")].max()
    tool_mm = 1e3 * np.array(rep.tool_speed_per_step_m_s) * step
    qq, _ = h.within_position_limits(q, robot)
    t0 = time.perf_counter()
    traj = h.time_parametrise(qq, step, lim, robot=robot, tool_frame=robot.frame)
    return {
        "ok": rep.ok, "n_viol": len(rep.violations), "tool_max_mm": float(tool_mm.max()),
        "tool_steps_mm": tool_mm, "rot_max": float(rot), "ins_max_mm": 1e3 * float(ins),
        "vel_ratio": max(rep.velocity_ratio), "acc_ratio": max(rep.acceleration_ratio),
        "tool_ratio": rep.peak_tool_speed_m_s / lim.tool_speed,
        "export_s": float(traj.duration), "planned_s": step * (len(q) - 1),
        "export_time": time.perf_counter() - t0,
    }


def main() -> None:
    ap = h.parser(__doc__, output=h.RESULTS / "default_limits.md")
    ap.add_argument("--problem", default=str(h.PAPER_PACE_PROBLEM))
    ap.add_argument("--cases", nargs="+",
                    default=["0.05:20:20", "0.06:20:0", "0.07:20:0", "0.08:20:0", "0.1:20:20",
                             "0.1:20:10", "0.05:30:20", "0.05:40:20", "0.05:40:20:0.5"])
    ap.add_argument("--repeats", type=int, default=1,
                    help="solves per method and case; the solve time is their median")
    args = ap.parse_args()
    base_prob = h.load_problem(args.problem)
    rows, steps_lines = [], []
    t_start = time.perf_counter()
    for case in args.cases:
        parts = case.split(":")
        step, horizon, hz = (float(x) for x in parts[:3])
        # 0: one observation per step whatever the pace (a step must span whole frames)
        hz = hz or 1.0 / step
        acc_scale = float(parts[3]) if len(parts) > 3 else 1.0
        timing = {"step_s": step, "tracker_hz": hz}
        res = {}
        export_lim = None
        for tag, enforce, method in (("free", False, "ocp"), ("lim", True, "ocp"),
                                     ("base", False, "baseline")):
            limits = {"enforce": enforce}
            # plan with a margin on the accelerations, export with the full ones
            if enforce and acc_scale != 1.0:
                full = h.problem_limits(h.setup(base_prob.with_horizon(int(horizon))))
                limits["joint_acceleration"] = {n: float(a) * acc_scale for n, a in
                                                zip(full.joint_names, full.acceleration)}
                export_lim = full
            # with_sections reads the problem again, so the noise is divided by the case's frames
            # per step
            setup = h.setup(base_prob.with_sections(horizon=int(horizon), timing=timing,
                                                    limits=limits))
            sol, wall = h.timed(lambda: h.method(setup, method))
            again = h.repeat(lambda: h.method(setup, method), args.repeats - 1)
            solve_times = [sol.solve_time_s] + [r.solve_time_s for r in again]
            r = plan_row(setup, sol, step, export_lim) if all(x is not None for x in sol.q) else {}
            r.update(status=sol.status, success=sol.success, tr=sol.trace_final,
                     solve=h.median(solve_times), wall=wall,
                     attempts=[a.label for a in sol.attempts])
            res[tag] = r
            print(case, tag, {k: v for k, v in r.items() if k != "tool_steps_mm"}, flush=True)
        f, l, b = res["free"], res["lim"], res["base"]
        label = f"{step:g} | {int(horizon)} | {hz:.4g} ({step * hz:.3g}) | {step * horizon:g}" + (
            f" (accelerations x{acc_scale:g} in the plan)" if acc_scale != 1.0 else "")
        for tag, r in (("unconstrained", f), ("enforced", l), ("baseline", b)):
            ratio = f"{r['tr'] / f['tr']:.2f}" if tag != "unconstrained" else "1"
            rows.append(
                f"| {label} | {tag} | {r['status']} | {r['tr']:.4e} | {ratio} | {r['solve']:.3f} / "
                f"{r['wall']:.2f} | {r['tool_max_mm']:.1f} | {r['rot_max']:.3f} | "
                f"{r['ins_max_mm']:.1f} | {r['vel_ratio']:.2f} / {r['acc_ratio']:.2f} / "
                f"{r['tool_ratio']:.2f} | {'yes' if r['ok'] else 'no'} | {r['export_s']:.3f} / "
                f"{r['planned_s']:.3f} |")
            steps_lines.append(f"| {label} | {tag} | "
                               + ", ".join(f"{x:.1f}" for x in r["tool_steps_mm"]) + " |")
    text = "\n".join([
        "# The default problem with its motion limits enforced", "",
        ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/default_limits.py --cases "
         f"{' '.join(args.cases)}{f' --repeats {args.repeats}' if args.repeats > 1 else ''}` "
         f"({time.perf_counter() - t_start:.0f} s; {platform.node()}, 2 cores shared with other "
         "jobs: times are one run each and noisy)"), "",
        (f"Problem: {Path(args.problem).name} with the case's `timing` and `horizon`; every row of "
         "a case on the same belief model (observations per step = step_s x tracker_hz, in "
         "brackets), so a trace ratio compares plans. `solve` is the solver's own time (NLP build "
         "and compile excluded; the median of --repeats solves), `wall` the first whole method "
         "call (build included). Joint steps: the largest |q_t+1 - q_t| over the rotary joints "
         "[rad] and the insertion [mm]. Peaks: the largest joint velocity / acceleration / tool "
         "speed over its limit at the planned pace (from and to rest). Export: the duration of "
         "the time-optimal trajectory within every joint and tool limit (`surestep export`), "
         "against the planned horizon x step_s."), "",
        *h.table(["step_s", "T", "tracker_hz (obs/step)", "planned [s]", "plan", "status",
                  "Tr(Sigma_T)", "Tr / unconstrained", "solve / wall [s]", "largest tool step [mm]",
                  "largest rotary step [rad]",
                  "largest insertion step [mm]", "peak v / a / tool over limit", "within limits",
                  "export / planned [s]"], rows), "",
        "## Tool step per planned step [mm]", "",
        *h.table(["step_s", "T", "tracker_hz", "planned [s]", "plan", "steps"],
                 steps_lines)]) + "\n"
    h.write_result(args.output, text)
    print(text)


if __name__ == "__main__":
    main()
