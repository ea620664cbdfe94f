"""`enforce`: with `limits.enforce: true`, a successful Solution whose plan breaks a motion limit
becomes a failure (status `Motion_Limits_Violated`), its limit report recorded as its
`motion_limits`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .report import UNREACHABLE, LimitsReport, SkippedReport, plan_report
from .values import VIOLATED, MotionLimits, problem_limits


def enforce(setup, sol, limits: MotionLimits | None = None) -> LimitsReport | SkippedReport | None:
    """With `limits.enforce: true`: check the plan of `sol` (a Solution), record the report as
    `sol.motion_limits`, and turn a successful solution that breaks a limit into a failure with
    status `Motion_Limits_Violated` (the solver's own status kept as `sol.run.solver_status`; a
    failed solution keeps its status). Returns the report (None when the limits are not
    enforced)."""
    if not setup.ocp.limits.enforce:
        return None
    if any(q is None for q in sol.q):
        rep = SkippedReport(UNREACHABLE, ok=False, enforced=True)
    else:
        rep = replace(plan_report(setup.robot, np.array(sol.q, float), setup.ocp.timing.step_s,
                                  limits or problem_limits(setup), tool_frame=setup.robot.frame),
                      enforced=True)
    sol.motion_limits = rep
    # a failure keeps its own status (the report says what it breaks)
    if not rep.ok and sol.success:
        sol.run = replace(sol.run, solver_status=sol.status)
        sol.success, sol.status = False, VIOLATED
    return rep

