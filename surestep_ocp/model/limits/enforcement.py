"""`enforce`: with `limits.enforce: true`, the plan's limit report (`report`), and the Solution
with it (`motion_limits`): a failure (status `Motion_Limits_Violated`) when a successful plan
breaks a motion limit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .report import UNREACHABLE, LimitsReport, SkippedReport, plan_report
from .values import VIOLATED, MotionLimits, problem_limits


def report(setup, q, limits: MotionLimits | None = None) -> LimitsReport | SkippedReport:
    """The enforced limits' report on the joint path `q` (rows of None: waypoints with no IK
    solution, skipped)."""
    if any(qi is None for qi in q):
        return SkippedReport(UNREACHABLE, ok=False, enforced=True)
    return replace(plan_report(setup.robot, np.array(q, float), setup.ocp.timing.step_s,
                               limits or problem_limits(setup), tool_frame=setup.robot.frame),
                   enforced=True)


def enforce(setup, sol, limits: MotionLimits | None = None):
    """With `limits.enforce: true`: `sol` (a Solution) with its plan's report as `motion_limits`,
    a successful one that breaks a limit as a failure with status `Motion_Limits_Violated` (the
    solver's own status kept as `run.solver_status`; a failed solution keeps its status); `sol`
    itself when the limits are not enforced. `sol` is not changed."""
    if not setup.ocp.limits.enforce:
        return sol
    rep = report(setup, sol.q, limits)
    # a failure keeps its own status (the report says what it breaks)
    if not rep.ok and sol.success:
        return sol.replaced(motion_limits=rep, success=False, status=VIOLATED,
                            run=replace(sol.run, solver_status=sol.status))
    return sol.replaced(motion_limits=rep)

