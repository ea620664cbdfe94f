"""One configuration of `surestep evaluate` (the worker side, in this process, a pool's worker or a
Dask worker): every method plans once, every plan is rolled out per rollout mode, and the outcome
is one JSON-able record (a line of `progress.jsonl`; `evaluation.py` runs the configurations).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..method_grammar import is_closed_loop
from ..methods.registry import method_setup, run_method
from ..model.grasp import within
from ..model.limits.values import problem_limits
from .closed_loop import ClosedLoop
from .configs import ConfigurationSampler, load_evaluation
from .pacing import paced
from .rollout import MODES, plan_metrics
from ..status import Status

_SAMPLERS: dict = {}


def _sampler(eval_path: str):
    key = str(Path(eval_path).resolve())
    if key not in _SAMPLERS:
        _SAMPLERS[key] = ConfigurationSampler(load_evaluation(eval_path))
    return _SAMPLERS[key]


def executed_poses(setup, poses, pace: str) -> np.ndarray:
    """The waypoints the rollouts follow: the plan's (`planned`) or the plan's run at the tool's
    limits (`limits`: the problem's `limits:` tool speeds, one rollout step of `timing.step_s` each;
    pacing.py)."""
    poses = np.asarray(poses, float)
    if pace == "planned":
        return poses
    lim = problem_limits(setup)
    return paced(poses, setup.ocp.timing.step_s, lim.tool_speed, lim.tool_rotation)


def evaluate_configuration(eval_path: str, seed: int, index: int, methods: tuple[str, ...],
                           rollouts: int, modes: tuple[str, ...]) -> dict:
    """Plan with every method on configuration `index` and roll each plan out; a JSON-able record.

    Picklable arguments only (each process builds its own set-up and solvers). A method
    that raises is recorded with its error (no plan, no metrics); a plan whose solver
    reports failure is still rolled out, and flagged.
    """
    smp = _sampler(eval_path)
    cfg = smp.sample(seed, index)
    setup = smp.setup_of(cfg)
    spec = smp.spec
    rec = {"config": index, "seed": seed, "rollouts": rollouts, **cfg.to_dict(), "solves": {},
           "metrics": {m: {} for m in modes},
           "pos_errors": {m: {} for m in modes}, "ori_errors": {m: {} for m in modes},
           "success": {m: {} for m in modes}, "detected": {m: {} for m in modes}}
    per_rollout = ("pos_errors", "ori_errors", "success", "detected")
    cache = {}
    for name in methods:
        t0 = time.perf_counter()
        policy = None
        try:
            if is_closed_loop(name):  # re-plans in every rollout, from this first plan
                policy = ClosedLoop(method_setup(setup, name))
                sol = policy.first_plan.replaced(method=name)
            else:
                sol = run_method(setup, name, cache)
        except Exception as exc:  # noqa: BLE001 - recorded in solves.csv and counted in the table
            rec["solves"][name] = {"success": False,
                                   "status": f"error: {type(exc).__name__}: {exc}",
                                   "solve_time_s": time.perf_counter() - t0, "iterations": 0,
                                   "evaluated": False}
            continue
        cache[name] = sol
        solve = {"success": sol.success, "status": sol.status, "solve_time_s": sol.solve_time_s,
                 "iterations": sol.iterations, "evaluated": True}
        if sol.status == Status.INITIAL_GUESS_KEPT:  # why: what every solver attempt ended with
            solve["kept_start"] = ("; ".join(f"{a.label}: {a.status}" for a in sol.attempts)
                                   or sol.run.solver or "")
        try:
            # a closed loop runs within the limits: at the robot's pace already
            poses = (np.asarray(sol.poses, float) if policy is not None
                     else executed_poses(setup, sol.poses, spec.pace))
            solve["rollout_steps"] = len(poses) - 1
            for mode in modes:
                rng = np.random.default_rng([seed, index, MODES.index(mode)])
                if policy is not None:
                    policy.reset()
                met, ro = plan_metrics(setup.eval_model, poses, setup.x_goal, rollouts, rng, mode,
                                       sol.sigma_final, detection=spec.detection, policy=policy)
                if policy is not None:
                    summary = policy.summary()
                    solve.setdefault("replans", {})[mode] = {
                        k: summary[k] for k in ("replans", "failed", "late_replans", "median_ms",
                                                "worst_ms", "late_worst", "violations")}
                rec["metrics"][mode][name] = met
                rec["pos_errors"][mode][name] = ro.pos_err.tolist()
                rec["ori_errors"][mode][name] = ro.ori_err.tolist()
                ok = within(ro.pos_err, ro.ori_err, spec.grasp_position, spec.grasp_angle)
                rec["success"][mode][name] = float(np.mean(ok))
                rec["detected"][mode][name] = (float(np.mean(ro.detected))
                                               if ro.detected is not None else 1.0)
        except (ValueError, np.linalg.LinAlgError) as exc:  # e.g. NaN waypoints of a failed solve
            solve.update(evaluated=False, status=f"{sol.status}; rollout error: {exc}")
            for mode in modes:
                rec["metrics"][mode].pop(name, None)
                for key in per_rollout:
                    rec[key][mode].pop(name, None)
        rec["solves"][name] = solve
    return rec
