"""The OCP's plans against the motion limits, at their planned pace and exported (`surestep export`).

For configurations 0..N-1 of problems/evaluations/evaluation.yaml (seed 0, T = 20): the OCP plan
(default solver), its limit report at the planned pace (surestep_ocp.limits.plan_report), then the
exported trajectory (surestep_ocp.export.time_parametrise), checked here from its samples alone:
positions within the URDF limits, |dq/dt| and |dv/dt| between samples within the velocity and
acceleration limits, every waypoint a sample. Writes benchmarks/results/export_limits.md.

    .venv/bin/python benchmarks/export_limits.py --configs 100
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from surestep_ocp.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.export import time_parametrise
from surestep_ocp.limits import motion_limits, plan_report
from surestep_ocp.methods import run_method

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--configs", type=int, default=100)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "export_limits.md"))
    args = ap.parse_args()
    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations" / "evaluation.yaml"))
    rows = []
    for i in range(args.configs):
        setup = sampler.setup_of(sampler.sample(0, i))
        sol = run_method(setup, "ocp")
        q = np.array(sol.q, float)
        step = setup.problem.timing.step_s
        lim = motion_limits(setup.robot.urdf, setup.robot.joint_names)
        rep = plan_report(setup.robot, q, step, lim)
        t0 = time.perf_counter()
        tr = time_parametrise(q, step, lim)
        t_export = time.perf_counter() - t0
        dt = np.diff(tr.times)[:, None]
        ok = (np.all(tr.q >= setup.robot.lower - 1e-12) and np.all(tr.q <= setup.robot.upper + 1e-12)
              and np.all(np.abs(np.diff(tr.q, axis=0)) / dt <= lim.velocity * (1 + 1e-6))
              and np.all(np.abs(np.diff(tr.qd, axis=0)) / dt <= lim.acceleration * (1 + 1e-6))
              and np.allclose(tr.q[tr.waypoint_rows], q, rtol=0, atol=1e-9))
        kinds = {}
        for v in rep["violations"]:
            kinds[v["kind"]] = kinds.get(v["kind"], 0) + 1
        rows.append({"i": i, "violations": len(rep["violations"]), "kinds": kinds,
                     "vel_ratio": max(rep["velocity_ratio"]), "acc_ratio": max(rep["acceleration_ratio"]),
                     "tool_mm_s": 1e3 * rep["peak_tool_speed_m_s"], "rcm_mm": 1e3 * (rep["min_rcm_distance_m"] or 0),
                     "duration": tr.duration, "planned": step * (len(q) - 1), "scale": tr.scale,
                     "export_s": t_export, "ok": bool(ok)})
        print(f"{i:3d} viol {len(rep['violations']):3d} v/lim {rows[-1]['vel_ratio']:6.2f} "
              f"dur {tr.duration:6.2f} s scale {tr.scale:.2f} export {t_export:.2f} s ok {ok}", flush=True)
    n = len(rows)
    dur = np.array([r["duration"] for r in rows])
    planned = rows[0]["planned"]
    kinds_total: dict[str, int] = {}
    for r in rows:
        for k, c in r["kinds"].items():
            kinds_total[k] = kinds_total.get(k, 0) + (c > 0)
    lines = [
        f"# OCP plans against the motion limits ({n} configurations of problems/evaluations/evaluation.yaml, "
        f"seed 0, T = 20, step_s {rows[0]['planned'] / 20:g} s)",
        "",
        "`.venv/bin/python benchmarks/export_limits.py --configs " + str(n) + "`",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| plans breaking some limit at the planned pace | {sum(r['violations'] > 0 for r in rows)} / {n} |",
    ]
    for k in sorted(kinds_total):
        lines.append(f"| ... of which {k} | {kinds_total[k]} |")
    lines += [
        f"| peak joint velocity / limit at the planned pace: median, max | "
        f"{np.median([r['vel_ratio'] for r in rows]):.2f}, {max(r['vel_ratio'] for r in rows):.2f} |",
        f"| peak tool speed at the planned pace [mm/s]: median, max | "
        f"{np.median([r['tool_mm_s'] for r in rows]):.0f}, {max(r['tool_mm_s'] for r in rows):.0f} |",
        f"| min distance of the shaft end from the RCM [mm] | {min(r['rcm_mm'] for r in rows):.1f} |",
        f"| exported trajectories within every joint limit (checked from the samples) | "
        f"{sum(r['ok'] for r in rows)} / {n} |",
        f"| exported duration [s] (planned {planned:g} s): median, max | {np.median(dur):.2f}, {dur.max():.2f} |",
        f"| limit scale handed to toppra: 1 / 0.98 / lower | {sum(r['scale'] == 1 for r in rows)} / "
        f"{sum(r['scale'] == 0.98 for r in rows)} / {sum(r['scale'] < 0.98 for r in rows)} |",
        f"| export time per plan [s]: median, max | {np.median([r['export_s'] for r in rows]):.2f}, "
        f"{max(r['export_s'] for r in rows):.2f} |",
        "",
    ]
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
