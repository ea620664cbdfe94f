"""What a finished `surestep serve` run reports (loop.ServoLoop's state at its end): the one line
`serve: ...` on stdout, the last estimate's error from the goal in it, and the run's log (--log).
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
from scipy.spatial.transform import Rotation

from ..model.grasp import grasp_probability
from ..output.solution import write_json_atomic


def summary_line(loop) -> str:
    """The one line `serve: ...` of a finished run."""
    logs = [g for g in loop.shared.logs]
    kept = [g for g in logs if g.ok]
    ready = np.array([(g.ready - g.arrival) * 1e3 for g in kept])
    first = np.array([(g.first_command - g.arrival) * 1e3 for g in kept
                      if g.first_command is not None])
    gaps = np.diff(np.array(loop.sent_at)) * 1e3 if len(loop.sent_at) > 1 else np.zeros(1)
    # the fault holds' own gaps are not the stream's
    held = [h["sent_before"] - 1 for h in loop.holds if 0 < h["sent_before"] < len(loop.sent_at)]
    held = np.array(held, int)
    gaps = np.delete(gaps, held) if len(gaps) > len(held) else np.zeros(1)
    span = loop.sent_at[-1] - loop.sent_at[0] if len(loop.sent_at) > 1 else math.nan
    span -= (np.sum(np.diff(loop.sent_at)[held]) if len(held) else 0.0)  # the holds' time
    rate = (len(loop.sent_at) - 1 - len(held)) / span if span > 0 else math.nan

    def stat(a):
        return f"{np.median(a):.1f}/{a.max():.1f}" if len(a) else "-"

    err = goal_error(loop)
    budget = "-" if loop.budget is None else f"{loop.budget * 1e3:.1f}"
    return (f"serve: {loop.outcome}; {len(logs)} re-plans ({len(logs) - len(kept)} not played), "
            f"ready median/worst {stat(ready)} ms, first new set-point {stat(first)} ms after "
            f"the estimate (budget {budget} ms); servo {rate:.1f} Hz, {len(loop.sent_at)} "
            "set-points, longest gap "
            f"{gaps.max():.1f} ms" + (" outside holds" if loop.holds else "")
            + (f"; {len(loop.holds)} fault hold(s), "
               f"{sum(h['resumed'] is not None for h in loop.holds)} resumed" if loop.holds else "")
            + f"; {loop.shared.estimates} estimates"
            + (f"; last estimate {err[0] * 1e3:.2f} mm, {err[1]:.3f} rad from the goal, "
               f"P(grasp) {err[2]:.3f}" if err else ""))


def goal_error(loop):
    """(position [m], angle [rad], P(grasp)) of the last estimate from the goal, or None."""
    if loop.shared.estimate is None:
        return None
    mean, cov = loop.shared.estimate
    goal = np.asarray(loop.setup.x_goal, float)
    dp = float(np.linalg.norm(mean[:3] - goal[:3]))
    dr = float((Rotation.from_rotvec(goal[3:]).inv() * Rotation.from_rotvec(mean[3:]))
               .magnitude())
    g = loop.serve.problem.grasp
    try:
        p = float(grasp_probability(cov, g.position, g.angle))
    except ImportError:
        p = float("nan")
    return dp, dr, p


def write_log(loop) -> None:
    """The run's log (--log, JSON): every re-plan, the set-points' times, the holds, the budget."""
    first = loop.holds[0] if loop.holds else {}
    data = {"replans": [asdict(g) for g in loop.shared.logs],
            "sent_at": [t - loop.origin for t in loop.sent_at],
            "outcome": loop.outcome, "hold": first.get("reason"),
            "hold_at": first.get("at"), "holds": loop.holds,
            "estimates": loop.shared.estimates, "period": loop.period, "dt": loop.dt,
            "last_estimate": first.get("last_estimate",
                                       loop.shared.last_estimate - loop.origin),
            "fault_seen": first.get("fault_seen"),
            "t0_wall": loop.origin_wall_ns * 1e-9, "budget": loop.budget,
            "probes": loop.probes,
            "servo": {"pid": loop.servo.proc.pid, "exit": loop.serve.servo_code,
                      "reports_dropped": loop.dropped}}
    write_json_atomic(loop.opts.log, data)
