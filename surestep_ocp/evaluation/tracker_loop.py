"""A re-planning loop against a simulated 20 Hz tracker (`surestep replan` on a problem whose camera
does not move): one `Planner`, a re-plan at every waypoint from the tracker's estimate.

Within enforced limits each re-plan starts from the robot's moving state (docs/realtime.md); the
executed motion is each plan's curve from its start until the next plan's start.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..output.solution import write_json_atomic, write_text_atomic
from ..problem.setup import Setup
from ..methods.planner import Planner
from .tracker import SimulatedTracker


def tracker_loop(setup: Setup, seed: int = 0, progress=None, rti: bool = True) -> dict:
    """One episode: the planner's first plan, then a re-plan per tracker frame until the goal
    (`rti`: real-time iterations, each prepared between frames; else full re-plans).

    Returns the planner, the re-plans (Solutions), the executed pieces (start step, joints, start
    state or None) and a summary (times without builds, failures, steps the goal moved later)."""
    planner = Planner(setup, rti=rti)
    tracker = SimulatedTracker(setup.eval_model, planner.plan.poses[0], rng=seed)
    pieces = [(0, np.array(planner.plan.q, float), None)]
    plans, k = [], 0
    while k + 1 < planner.horizon:
        k += 1
        mean, cov = tracker.move_to(planner.plan.poses[k - planner.step])
        plan = planner.replan(mean, cov, step=k)
        plans.append(plan)
        if progress:
            progress(k, plan)
        if k + 1 < planner.horizon:
            planner.prepare(k + 1)  # between frames: the next re-plan's real-time iteration
        if plan.success:
            start = plan.run.start_state
            pieces.append((k, np.array(plan.q, float), None if start is None else
                           (np.array(start.velocity), np.array(start.acceleration))))
    tracker.move_to(planner.plan.poses[-1])
    ms = np.array([p.replan.time_s * 1e3 for p in plans])
    summary = {
        "seed": seed, "replans": len(plans), "failed": int(sum(not p.success for p in plans)),
        # the tracker's estimate put the goal out of reach: the registration before it held
        "registration_held": int(sum(bool(p.replan.registration_held) for p in plans)),
        # ... and the nearest estimate its belief allows that reaches the goal was registered
        "registration_constrained": int(sum(p.replan.registration_constrained is not None
                                            for p in plans)),
        "replan_median_ms": float(np.median(ms)) if len(ms) else None,
        "replan_worst_ms": float(ms.max()) if len(ms) else None,
        "steps_later": planner.horizon - setup.ocp.horizon,
        "build_time_s": planner.build_time_s,
        "final_error_mm": float(np.linalg.norm(tracker.true_pose[:3] - planner.plan.positions[-1])
                                * 1e3),
    }
    return {"planner": planner, "plans": plans, "pieces": pieces, "summary": summary}


def write_tracker_loop(result: dict, out_dir: Path) -> str:
    """loop.md (a table per re-plan) and loop.json (the same, and the summary), each written whole;
    returns the table."""
    rows = [(p.replan.step, p.horizon, p.status, p.iterations, round(p.replan.time_s * 1e3, 2),
             "yes" if p.replan.kept_previous else "no",
             "yes" if p.replan.registration_held else "no") for p in result["plans"]]
    head = ("| step | steps left | status | iterations | ms | previous plan kept "
            "| registration held |")
    table = "\n".join([head, "|---|---|---|---|---|---|---|"]
                      + [f"| {' | '.join(str(v) for v in r)} |" for r in rows])
    s = result["summary"]
    text = (f"# Re-planning against a simulated 20 Hz tracker (seed {s['seed']})\n\n{table}\n\n"
            f"{s['replans']} re-plans, {s['failed']} failed (the previous plan kept), "
            f"{s['registration_constrained']} with the nearest estimate reaching the goal "
            f"registered and {s['registration_held']} with the registration before held (the "
            f"tracker's estimate put the goal out of reach); median "
            f"{s['replan_median_ms']:.1f} ms, worst {s['replan_worst_ms']:.1f} ms (builds apart: "
            f"{s['build_time_s']:.2f} s); the goal reached {s['steps_later']} steps later than "
            f"planned; final position error {s['final_error_mm']:.2f} mm.\n")
    out_dir.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out_dir / "loop.md", text)
    write_json_atomic(out_dir / "loop.json", {
        "summary": s, "replans": [dict(zip(["step", "steps_left", "status", "iterations", "ms",
                                            "kept_previous", "registration_held"], r))
                                   for r in rows]})
    return text
