"""The OCP's plans against the motion limits, at their planned pace and exported
(`surestep export`).

For configurations 0..N-1 of problems/evaluations/evaluation.yaml (seed 0, T = 20): the OCP plan
(default solver), its limit report at the planned pace (surestep_ocp.model.limits.plan_report), then
the exported trajectory (surestep_ocp.output.export.time_parametrise, within the joint and the
tool's speed limits), checked here from its samples alone: positions within the URDF limits, |dq/dt|
and |dv/dt| between samples within the velocity and acceleration limits, the tool's translation and
rotation between samples (FK) within its speed limits, every waypoint a sample. Writes
benchmarks/results/export_limits.md.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/export_limits.py --configs 100
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import time  # noqa: E402

import numpy as np  # noqa: E402


def main() -> None:
    args = h.parser(None, configs=100, output=h.RESULTS / "export_limits.md",
                    output_flag="--out").parse_args()
    sampler = h.sampler()
    rows = []
    for i in range(args.configs):
        setup = h.config_setup(sampler, 0, i)
        sol = h.method(setup, "ocp")
        q = np.array(sol.q, float)
        step = setup.ocp.timing.step_s
        lim = h.motion_limits(setup.robot.urdf, setup.robot.joint_names)
        rep = h.plan_report(setup.robot, q, step, lim)
        t0 = time.perf_counter()
        qc, _ = h.within_position_limits(q, setup.robot)
        tr = h.time_parametrise(qc, step, lim, robot=setup.robot, tool_frame=setup.robot.frame)
        t_export = time.perf_counter() - t0
        dt = np.diff(tr.times)[:, None]
        dp, dr = h.tool_speeds(setup.robot.urdf, setup.robot.frame, tr.times, tr.q)
        ok = (np.all(tr.q >= setup.robot.lower - 1e-12)
              and np.all(tr.q <= setup.robot.upper + 1e-12)
              and np.all(np.abs(np.diff(tr.q, axis=0)) / dt <= lim.velocity * (1 + 1e-6))
              and np.all(np.abs(np.diff(tr.qd, axis=0)) / dt <= lim.acceleration * (1 + 1e-6))
              and np.allclose(tr.q[tr.waypoint_rows], qc, rtol=0, atol=1e-9))
        tool_ok = bool(dp.max() <= lim.tool_speed * (1 + 1e-6)
                       and dr.max() <= lim.tool_rotation * (1 + 1e-6))
        kinds = {}
        for v in rep.violations:
            kinds[v.kind] = kinds.get(v.kind, 0) + 1
        rows.append({"i": i, "violations": len(rep.violations), "kinds": kinds,
                     "vel_ratio": max(rep.velocity_ratio),
                     "acc_ratio": max(rep.acceleration_ratio),
                     "tool_mm_s": 1e3 * rep.peak_tool_speed_m_s,
                     "rcm_mm": 1e3 * (rep.min_rcm_distance_m or 0), "duration": tr.duration,
                     "planned": step * (len(q) - 1), "scale": min(tr.scales.values()),
                     "export_s": t_export, "ok": bool(ok), "tool_ok": tool_ok,
                     "export_mm_s": 1e3 * dp.max(), "export_rad_s": dr.max(),
                     "tries_scaled": {k: v < 1 for k, v in tr.scales.items()}})
        print(f"{i:3d} viol {len(rep.violations):3d} v/lim {rows[-1]['vel_ratio']:6.2f} "
              f"dur {tr.duration:6.2f} s tool {1e3 * dp.max():5.1f} mm/s {dr.max():.2f} rad/s "
              f"scale {rows[-1]['scale']:.3f} export {t_export:.2f} s ok {ok} {tool_ok}",
              flush=True)
    n = len(rows)
    dur = np.array([r["duration"] for r in rows])
    planned = rows[0]["planned"]
    kinds_total: dict[str, int] = {}
    for r in rows:
        for k, c in r["kinds"].items():
            kinds_total[k] = kinds_total.get(k, 0) + (c > 0)
    lines = [
        (f"# OCP plans against the motion limits ({n} configurations of "
         "problems/evaluations/evaluation.yaml, seed 0, T = 20, step_s "
         f"{rows[0]['planned'] / 20:g} s)"),
        "",
        "`.venv/bin/python benchmarks/export_limits.py --configs " + str(n) + "`",
        "",
        *h.table(["quantity", "value"]),
        ("| plans breaking some limit at the planned pace | "
         f"{sum(r['violations'] > 0 for r in rows)} / {n} |"),
    ]
    for k in sorted(kinds_total):
        lines.append(f"| ... of which {k} | {kinds_total[k]} |")
    lines += [
        ("| peak joint velocity / limit at the planned pace: median, max | "
         f"{np.median([r['vel_ratio'] for r in rows]):.2f}, "
         f"{max(r['vel_ratio'] for r in rows):.2f} |"),
        ("| peak tool speed at the planned pace [mm/s]: median, max | "
         f"{np.median([r['tool_mm_s'] for r in rows]):.0f}, "
         f"{max(r['tool_mm_s'] for r in rows):.0f} |"),
        ("| min distance of the shaft end from the RCM [mm] | "
         f"{min(r['rcm_mm'] for r in rows):.1f} |"),
        f"| exported trajectories within every joint limit (checked from the samples) | "
        f"{sum(r['ok'] for r in rows)} / {n} |",
        (f"| exported trajectories within the tool's speed limits ({1e3 * lim.tool_speed:g} mm/s, "
         f"{lim.tool_rotation:.3g} rad/s; FK between samples) | "
         f"{sum(r['tool_ok'] for r in rows)} / {n} |"),
        ("| exported peak tool speed [mm/s]: median, max | "
         f"{np.median([r['export_mm_s'] for r in rows]):.1f}, "
         f"{max(r['export_mm_s'] for r in rows):.1f} |"),
        ("| exported peak tool rotation [rad/s]: median, max | "
         f"{np.median([r['export_rad_s'] for r in rows]):.3f}, "
         f"{max(r['export_rad_s'] for r in rows):.3f} |"),
        (f"| exported duration [s] (planned {planned:g} s): median, max | {np.median(dur):.2f}, "
         f"{dur.max():.2f} |"),
        ("| smallest limit scale handed to toppra: median, min | "
         f"{np.median([r['scale'] for r in rows]):.3f}, {min(r['scale'] for r in rows):.3f} |"),
        "| exports whose joint velocity / joint acceleration / tool limits were scaled down | "
        + " / ".join(str(sum(r["tries_scaled"][k] for r in rows))
                     for k in ("joint_velocity", "joint_acceleration", "tool_speed")) + " |",
        ("| export time per plan [s]: median, max | "
         f"{np.median([r['export_s'] for r in rows]):.2f}, "
         f"{max(r['export_s'] for r in rows):.2f} |"),
        "",
        f"Measured on a machine shared with other jobs (2 cores); {time.strftime('%Y-%m-%d')}.",
        "",
    ]
    h.write_result(args.out, "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
