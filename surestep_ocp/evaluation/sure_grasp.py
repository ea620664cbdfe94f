"""Time to a sure grasp: each method at the robot's pace, every rollout grasping on evidence.

A scenario (a problem file at the paper's pace) runs at the robot's pace (`robot_pace`: twice the
steps, the camera moves at the same times, the limits enforced) with `goal.confidence` asked and
the cap `timing.max_duration` (default twice the robot's-pace duration). Each method's rollouts
grasp at the first step onto the goal whose tracker belief predicts the confidence, dwelling at the
goal under observation until then, or at the cap (`grasp_rule.py`):

- `baseline`: the straight line as fast as the limits allow (the fewest steps a time law within
  them fits, none before the last camera move), then the dwell;
- `ocp-robot-pace`: the `Planner`'s first plan to the confidence (the shortest horizon whose plan
  reaches it, not below the problem's, `methods/confidence.py`), run open loop, then the dwell;
- `ocp-mpc`: that plan re-planned at every frame by every rollout from its own belief within the
  limits (`closed_loop.ClosedLoop`), then the dwell.

Per method and rollout mode: the measured success, the mean predicted success at the grasp (the
calibration), the time to grasp (median, 90th percentile), the share capped and the tracker's
consistency (NEES of the final error against its covariance, dimension 6). Rollouts of scenario k in
mode m use `default_rng([seed, k, m])` for every method.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import replace

import numpy as np

from ..model.grasp import nees, within
from ..problem.setup import build_setup
from ..methods.confidence import at_horizon, last_move
from ..methods.registry import run_method
from ..methods.planner import Planner
from .closed_loop import ClosedLoop, robot_pace
from .grasp_rule import GraspRule
from .rollout import MODES, Detection, rollout

METHODS = ("baseline", "ocp-robot-pace", "ocp-mpc")


def scenario_setups(problem, confidence: float):
    """(setup asking `confidence` at the robot's pace, the same without it); the planner knows the
    detector (the problem's `detection:`, else the evaluation's default one)."""
    fast = robot_pace(problem)
    asked = build_setup(fast.with_sections(goal={**fast.source["goal"], "confidence": confidence},
                                           detection=fast.source.get("detection", {})))
    plain = asked.with_ocp(grasp=type(asked.ocp.grasp)(asked.ocp.grasp.position,
                                                       asked.ocp.grasp.angle))
    return asked, plain


def fastest_baseline(plain):
    """The straight line in the fewest steps its time law within the limits needs (the baseline
    lengthens a too short horizon to that), from the last camera move's step on."""
    return run_method(at_horizon(plain, max(1, last_move(plain))), "baseline")


def cell(ro, rule: GraspRule, dt: float) -> dict:
    """One method's rollouts in one mode: success, prediction, times, caps, NEES."""
    hit = within(ro.pos_err, ro.ori_err, rule.position, rule.angle)
    t = ro.grasp_step * dt
    v = nees(ro.final_error, ro.sigma_final)
    return {"success": float(hit.mean()), "predicted": float(np.mean(ro.predicted)),
            "time_median_s": float(np.median(t)), "time_p90_s": float(np.percentile(t, 90)),
            "capped": float(np.mean(ro.capped)), "nees_median": float(np.median(v)),
            "nees_mean": float(np.mean(v)), "times_s": t.tolist(), "hit": hit.tolist()}


def scenario_rows(problem, k: int, rollouts: int, seed: int, confidence: float = 0.95,
                  detection: Detection | None = Detection(), tracker_noise: str = "auto",
                  methods=METHODS) -> dict:
    """Every method's cells (per mode) for one scenario (module docstring); `ocp-mpc` also has its
    re-plans' summary per mode (failures by cause) and its executed samples beyond a limit."""
    asked, plain = scenario_setups(problem, confidence)
    rule = GraspRule.of(asked)
    dt = float(asked.ocp.timing.step_s)
    changes = asked.camera_changes()
    loop = ClosedLoop(asked)  # its Planner's plan to the confidence, within the limits' reserve
    rec = loop.planner.grasp
    out = {"plan": {"steps": loop.planner.horizon, "shortest": round(rec["duration_s"] / dt),
                    "predicted": rec["predicted"], "reached": rec["reached"]},
           "cap_steps": rule.max_steps}
    if not rec["reached"]:  # the time it would need: the search with a cap twice as long
        longer = Planner(asked.with_ocp(timing=replace(
            asked.ocp.timing, max_duration=2 * rule.max_steps * dt)), prebuild=False).grasp
        out["plan"]["needed_steps"] = (round(longer["duration_s"] / dt) if longer["reached"]
                                       else None)
        out["plan"]["needed_predicted"] = longer["predicted"]
    for name in methods:
        policy = None
        if name == "baseline":
            sol = fastest_baseline(plain)
            poses = np.asarray(sol.poses, float)
            out["baseline_steps"] = sol.horizon
        else:  # the first plan, each waypoint in its step's camera frame
            poses = loop.setup.in_step_frames(np.asarray(loop.first_plan.poses, float))
        if name == "ocp-mpc":
            policy = loop
            poses = poses[[0, -1]]
        row = {"replans": {}, "violations": 0}
        for mi, mode in enumerate(MODES):
            if policy is not None:
                policy.reset()
            t0 = time.perf_counter()
            ro = rollout(asked.eval_model, poses, poses[-1] if policy is None
                         else policy.start_and_goal()[1], rollouts,
                         np.random.default_rng([seed, k, mi]), mode, detection=detection,
                         changes=changes, policy=policy, grasp=rule, tracker_noise=tracker_noise)
            row[mode] = cell(ro, rule, dt)
            if policy is not None:
                s = policy.summary()
                missed = [i for i, ok in enumerate(row[mode]["hit"]) if not ok]
                # the misses of rollouts that kept a plan or a registration (counted, said)
                row[mode]["missed_after_failure"] = len(set(missed) & set(s["rollouts_failed"]))
                row[mode]["missed_after_hold"] = len(set(missed) & set(s["rollouts_held"]))
                s["wall_s"] = time.perf_counter() - t0
                s["causes"] = dict(Counter(why.split(":")[0][:60] for _, _, why in
                                           policy.failures))
                row["replans"][mode] = s
                row["violations"] += s["violations"]
        out[name] = row
    return out
