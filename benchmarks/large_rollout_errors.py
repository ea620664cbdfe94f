"""What the evaluation's largest final errors have in common (issue 16): every rollout of the OCP
methods above a threshold, with the step that threw it and the term of the motion noise that made
that step's draw.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/large_rollout_errors.py [--evaluation FILE]
        [--configs 100] [--rollouts 50] [--seed 0] [--methods ocp ocp-expected] [--threshold 0.2]

Plans and rolls out exactly as `surestep evaluate` (same sampler, generators and `rollout` call,
with paths kept). Per rollout above the threshold: the step with the largest motion-noise draw |w_p|
(from the paths: `p_true,t+1 - p_true,t - (p_t+1 - p_mu,t)`), that step's commanded rotation and
the two motion-noise terms (`|dp| sqrt(W_p0)`, `angle sqrt(W_o0)` [mm std]), the last step with an
observation, and whether the true pose ends behind the lens or outside the image. Prints a markdown
table and a summary line.
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

MODES, rollout = h.ROLLOUT_MODES, h.rollout


def main(argv=None) -> int:
    ap = h.parser(None, configs=100, seed=0)
    ap.add_argument("--evaluation", default=str(h.EVALUATION))
    ap.add_argument("--rollouts", type=int, default=50)
    ap.add_argument("--methods", nargs="+", default=["ocp", "ocp-expected"])
    ap.add_argument("--threshold", type=float, default=0.2)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    spec = h.evaluation(a.evaluation)
    smp = h.sampler(spec)
    rows, worst, counts = [], {}, {}
    for c in range(a.configs):
        setup = h.config_setup(smp, a.seed, c)
        model, cam, noise = setup.eval_model, setup.eval_model.camera, setup.eval_model.noise
        cache = {}
        for name in a.methods:
            sol = h.method(setup, name, cache)
            cache[name] = sol
            poses = np.asarray(sol.poses, float)
            for mode in MODES:
                rng = np.random.default_rng([a.seed, c, MODES.index(mode)])
                ro = rollout(model, poses, setup.x_goal, a.rollouts, rng, mode, keep_paths=True,
                             detection=spec.detection)
                key = (name, mode)
                worst[key] = max(worst.get(key, 0.0), float(ro.pos_err.max()))
                counts[key] = counts.get(key, 0) + int((ro.pos_err > a.threshold).sum())
                for k in np.flatnonzero(ro.pos_err > a.threshold):
                    tp, ep = ro.true_path[k], ro.estimate_path[k]
                    w = tp[1:, :3] - tp[:-1, :3] - (poses[1:, :3] - ep[:-1, :3])
                    s = int(np.argmax(np.linalg.norm(w, axis=1)))
                    dp = poses[s + 1, :3] - ep[s, :3]
                    ang = (Rotation.from_rotvec(ep[s, 3:]).inv()
                           * Rotation.from_rotvec(poses[s + 1, 3:])).magnitude()
                    seen = np.flatnonzero(ro.detected[k])
                    pT = tp[-1, :3]
                    u = (cam.fx * pT[0] / pT[2] + cam.cx) / cam.width if pT[2] > 0 else np.nan
                    v = (cam.fy * pT[1] / pT[2] + cam.cy) / cam.height if pT[2] > 0 else np.nan
                    where = ("behind the lens" if pT[2] <= 0 else
                             "outside the image" if not (0 <= u <= 1 and 0 <= v <= 1)
                             else "in the image")
                    rows.append(dict(method=name, mode=mode, config=c, k=int(k),
                                     err=1e3 * ro.pos_err[k], step=s, w=1e3 * np.linalg.norm(w[s]),
                                     angle=ang,
                                     dp_term=1e3 * np.linalg.norm(dp) * np.sqrt(noise.W_p0[0, 0]),
                                     ang_term=1e3 * ang * np.sqrt(noise.W_o0[0, 0]),
                                     last_seen=int(seen[-1]) if len(seen) else -1, n_seen=len(seen),
                                     where=where))
        print(f"config {c}: {len(rows)} rollouts above {a.threshold} m so far", flush=True)
    rows.sort(key=lambda r: -r["err"])
    print("\n`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/large_rollout_errors.py "
          f"--evaluation {Path(a.evaluation).name} --configs {a.configs} --rollouts {a.rollouts} "
          f"--seed {a.seed} --methods {' '.join(a.methods)} --threshold {a.threshold}` "
          f"({time.perf_counter() - t0:.0f} s)\n")
    print("\n".join(h.table(["method", "mode", "worst [mm]", "rollouts above the threshold"])))
    for (name, mode), w in worst.items():
        print(f"| {name} | {mode} | {1e3 * w:.1f} | {counts[(name, mode)]} of "
              f"{a.configs * a.rollouts} |")
    print("\n| method | mode | config | rollout | final error [mm] | step of largest w | abs w_p "
          "[mm] | commanded rotation [rad] | dp term [mm std] | angle term [mm std] | steps "
          "observed | last observed step | true pose at T |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['method']} | {r['mode']} | {r['config']} | {r['k']} | {r['err']:.1f} | "
              f"{r['step']}->{r['step'] + 1} | {r['w']:.1f} | {r['angle']:.3f} | "
              f"{r['dp_term']:.1f} | {r['ang_term']:.1f} | {r['n_seen']} | {r['last_seen']} "
              f"| {r['where']} |")
    if rows:
        ang_dom = sum(r["ang_term"] > r["dp_term"] for r in rows)
        first2 = sum(r["step"] <= 1 for r in rows)
        lost = sum(r["last_seen"] < r["step"] for r in rows)
        print("\n" + h.last_line("large_rollout_errors", h.key_values(
            n=len(rows), angle_term_dominant=ang_dom, largest_draw_in_steps_0_1=first2,
            never_observed_after_it=lost,
            behind_lens=sum(r["where"] == "behind the lens" for r in rows),
            outside_image=sum(r["where"] == "outside the image" for r in rows))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
