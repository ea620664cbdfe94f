"""Trace one rollout of the standard evaluation step by step (issue 16: the worst `true`-mode
rollout).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/worst_rollout.py [--config 73]
        [--method ocp-expected] [--mode true] [--rollout 38] [--rollouts 50] [--seed 0]
        [--output benchmarks/results/worst_rollout.md]

Re-plans configuration `--config` of problems/evaluations/evaluation.yaml with `--method` exactly as
`surestep evaluate` does (same sampler, same generator `default_rng([seed, config, mode index])`,
same `rollout(...)` call, `--rollouts` rollouts), keeps the paths, and then replays rollout
`--rollout` alone in plain NumPy from the same normal draws (tests/numpy_rollout.py: numpy_ekf.py's
noise formulas, scipy rotations, its own detection and gating code): the replay must reproduce the
package's true and estimated path (a check of the rollout's formulas, frames and gating on this very
rollout). Per step it prints the planned step, the motion noise std and which of its two terms
(`|dp|^2 W_p0`, `angle^2 W_o0`; both multiples of the 6x6 identity, so both perturb the position)
makes it, the true pose's depth and image position, whether it was detected, the observation noise,
the estimate error and the distance to the plan and to the goal.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import os  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

ROOT = h.ROOT
sys.path.insert(0, str(ROOT / "tests"))
import numpy_rollout  # noqa: E402

MODES, rollout = h.ROLLOUT_MODES, h.rollout


def main(argv=None) -> int:
    ap = h.parser(None)
    ap.add_argument("--evaluation", default=str(h.EVALUATION))
    ap.add_argument("--config", type=int, default=73)
    ap.add_argument("--method", default="ocp-expected")
    ap.add_argument("--mode", default="true", choices=MODES)
    ap.add_argument("--rollout", type=int, default=38)
    ap.add_argument("--rollouts", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--output", default=None)
    a = ap.parse_args(argv)

    spec = h.evaluation(a.evaluation)
    setup = h.config_setup(h.sampler(spec), a.seed, a.config)
    sol = h.method(setup, a.method, {})
    poses = np.asarray(sol.poses, float)
    model, cam, noise = setup.eval_model, setup.eval_model.camera, setup.eval_model.noise
    rng = np.random.default_rng([a.seed, a.config, MODES.index(a.mode)])
    ro = rollout(model, sol.poses, setup.x_goal, a.rollouts, rng, a.mode, keep_paths=True,
                 detection=spec.detection)
    k, T = a.rollout, len(poses) - 1
    # the same draws again: per step n x 6 for w, then n x 6 for v (rollout's documented order)
    rng = np.random.default_rng([a.seed, a.config, MODES.index(a.mode)])
    z_w, z_v = numpy_rollout.draws(rng, a.rollouts, T, k)
    det = spec.detection
    reps = numpy_rollout.replay(poses, noise, cam, a.mode, z_w, z_v,
                                (det.margin, det.min_depth, det.max_depth))
    rows = []
    for r in reps:
        dp, p_tr = r["dp"], r["true"][:3]
        rows.append(dict(t=r["t"], step_mm=1e3 * np.linalg.norm(dp), angle=r["angle"],
                         w_dp_mm=1e3 * np.sqrt(dp @ dp * noise.W_p0[0, 0]),
                         w_ang_mm=1e3 * r["angle"] * np.sqrt(noise.W_o0[0, 0]),
                         w_std_mm=1e3 * np.sqrt(r["cW"]), w_mm=1e3 * np.linalg.norm(r["w"][:3]),
                         depth=p_tr[2], uv=numpy_rollout.pixel(p_tr, cam),
                         z_uv=numpy_rollout.pixel(r["z_p"], cam) if r["z_p"][2] > 0
                         else (np.nan, np.nan), seen=r["seen"], V_std_mm=1e3 * np.sqrt(r["cV"]),
                         gain=r["gain"], true=r["true"], est=r["est"],
                         est_err_mm=1e3 * np.linalg.norm(p_tr - r["est"][:3]),
                         off_plan_mm=1e3 * np.linalg.norm(p_tr - poses[r["t"] + 1, :3]),
                         sig_std_mm=1e3 * np.sqrt(r["sigma"][0, 0])))
    true_dev = max(np.abs(r["true"][:3] - ro.true_path[k, r["t"] + 1, :3]).max() for r in rows)
    est_dev = max(np.abs(r["est"][:3] - ro.estimate_path[k, r["t"] + 1, :3]).max() for r in rows)
    seen_same = all(r["seen"] == ro.detected[k, r["t"]] for r in rows)
    final_mm = 1e3 * np.linalg.norm(rows[-1]["true"][:3] - setup.x_goal[:3])

    out = []
    pr = out.append
    pr(f"# Rollout trace: configuration {a.config}, `{a.method}`, mode `{a.mode}`, rollout {k} "
       f"of {a.rollouts}\n")
    ev = ("" if Path(a.evaluation).resolve()
          == (ROOT / "problems/evaluations/evaluation.yaml").resolve()
          else f" --evaluation {os.path.relpath(a.evaluation)}")
    pr(f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/worst_rollout.py{ev} --config "
       f"{a.config} --method {a.method} --mode {a.mode} --rollout {k} --rollouts {a.rollouts} "
       f"--seed {a.seed}`\n")
    pr(f"Plan: status {sol.status}, Tr(Sigma_T) = {sol.trace_final:.3e}; start "
       f"{np.round(setup.x_start, 4).tolist()}, goal {np.round(setup.x_goal, 4).tolist()} (camera "
       "frame, m / axis-angle rad).\n")
    pr(f"Package rollout: final position error {1e3 * ro.pos_err[k]:.1f} mm (rank "
       f"{int((ro.pos_err > ro.pos_err[k]).sum()) + 1} of {a.rollouts}; median of the {a.rollouts} "
       f"{1e3 * np.median(ro.pos_err):.1f} mm), {int(ro.detected[k].sum())} of {T} steps detected.")
    pr(f"NumPy replay from the same draws: final error {final_mm:.1f} mm; largest difference from "
       f"the package's paths {1e3 * true_dev:.2e} mm (true), {1e3 * est_dev:.2e} mm (estimate); "
       f"detections identical: {seen_same}.\n")
    pr("Columns: step = |p_t+1 - p_mu_t| commanded [mm], angle = commanded rotation [rad]; W std = "
       "sqrt of the motion noise's position variance [mm] and its two terms `|dp| sqrt(W_p0)`, "
       "`angle sqrt(W_o0)`; |w_p| = the drawn position noise [mm], |z_w| = its standard normals' "
       "norm (position part; chi with 3 degrees of freedom); depth [m], (u, v) = true pixel / "
       "image size; det = observation used (a measured pixel outside the detectable region is "
       "gated); V std = the observation noise std the measurement was drawn with [mm] (mode true: "
       "at the true pose when it is detectable, else at the waypoint, unused); K = EKF gain "
       "(position); est err = |p_true - p_mu| after the step [mm]; off plan = |p_true - p_t+1| "
       "[mm]; Sigma std = sqrt(Sigma_xx) [mm].\n")
    out += h.table(["t->t+1", "step [mm]", "angle [rad]", "W std [mm]", "dp term", "angle term",
                    "abs w_p [mm]", "abs z_w", "depth [m]", "(u, v)", "measured (u, v)", "det",
                    "V std [mm]", "K", "est err [mm]", "off plan [mm]",
                    "Sigma std [mm]"])
    for r in rows:
        pr(f"| {r['t']}->{r['t'] + 1} | {r['step_mm']:.1f} | {r['angle']:.3f} | "
           f"{r['w_std_mm']:.1f} | {r['w_dp_mm']:.1f} | {r['w_ang_mm']:.1f} | {r['w_mm']:.1f} | "
           f"{np.linalg.norm(z_w[r['t'], :3]):.2f} | {r['depth']:.3f} | ({r['uv'][0]:.2f}, "
           f"{r['uv'][1]:.2f}) | ({r['z_uv'][0]:.2f}, {r['z_uv'][1]:.2f}) | "
           f"{'yes' if r['seen'] else 'no'} | {r['V_std_mm']:.1f} | {r['gain']:.3f} | "
           f"{r['est_err_mm']:.1f} | {r['off_plan_mm']:.1f} | {r['sig_std_mm']:.1f} |")
    pr("")
    plan_steps = np.linalg.norm(np.diff(poses[:, :3], axis=0), axis=1)
    plan_ang = (Rotation.from_rotvec(poses[:-1, 3:]).inv()
                * Rotation.from_rotvec(poses[1:, 3:])).magnitude()
    pr("Planned steps [mm]: " + ", ".join(f"{1e3 * s:.1f}" for s in plan_steps))
    pr("Planned rotations [rad]: " + ", ".join(f"{s:.3f}" for s in plan_ang))
    geo = (Rotation.from_rotvec(setup.x_start[3:]).inv()
           * Rotation.from_rotvec(setup.x_goal[3:])).magnitude()
    pr(f"Sum of the planned rotations {plan_ang.sum():.3f} rad; geodesic angle start -> goal "
       f"{geo:.3f} rad (the straight line's per-step rotation {geo / T:.3f} rad, motion-noise std "
       f"from it {1e3 * geo / T * np.sqrt(noise.W_o0[0, 0]):.1f} mm).")
    pr("Plan depths [m]: " + ", ".join(f"{z:.3f}" for z in poses[:, 2]))
    text = "\n".join(out) + "\n"
    print(text)
    if a.output:
        h.write_result(Path(a.output), text)
    ok = true_dev < 1e-9 and est_dev < 1e-9 and seen_same
    print(h.last_line("worst_rollout", h.key_values(final_mm=f"{1e3 * ro.pos_err[k]:.1f}",
                                                    replay_mm=f"{final_mm:.1f}", replay_ok=ok)))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
