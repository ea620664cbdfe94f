"""The real-time iteration's two phases (acados' RTI): what the preparation leaves for the next
re-plan, and the feedback that turns it into a plan when the tracker's estimate arrives.

The preparation (`Planner.prepare`, before the estimate) runs one interior-point iteration from the
current plan shifted to the executed curve's state; the feedback (`RealTimeIteration._feedback`)
moves that iterate's goal to where the registered camera sees it and checks every row, which is
all that stands between the measurement and the plan (docs/realtime.md). Where a row breaks the
Planner re-plans in full (planner.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..model.robot import CAMERA_PARAMETERS
from ..ocp.iterate import InitialGuess
from ..output.solution import Solution
from ..output.solution_records import ReplanAttempt
from ..problem.setup import Setup
from ..solvers.backends import ReplanSolver
from ..status import Status
from .replan_solvers import ReplanSolvers, replan_solution


@dataclass
class Prepared:
    """A real-time iteration's preparation (`Planner.prepare`): valid for the re-plan of `plan`
    at waypoint `step` seen from the camera `camera` (its pose's bytes)."""

    plan: Solution
    step: int
    camera: bytes
    q0: np.ndarray  # the executed curve's state at `step`: joints, velocities, accelerations
    v0: np.ndarray
    a0: np.ndarray
    warm: InitialGuess  # the shifted plan it iterated from
    run: object  # its iteration (the solver's run record)
    solver: ReplanSolver  # the re-planning solver of its structure
    parameters: np.ndarray  # its compiled functions' parameters (its objective's scale set)
    time_s: float  # its time without builds
    reserve: float  # the fraction of the limits its iteration kept for corrections


class RealTimeIteration(ReplanSolvers):
    """The feedback phase of a Planner's real-time iterations (a base of `Planner`, which prepares
    them)."""

    def _feedback(self, prep: Prepared, registered: Setup, q_goal: np.ndarray, cov,
                  t0: float) -> tuple[Solution | None, np.ndarray]:
        """The real-time iteration's feedback: the prepared iterate with its goal moved to
        `q_goal` (the shift eased in, no velocity or acceleration added at either end), if that
        keeps every row (the limits themselves: the reserve is room for such corrections): (its
        Solution, with `extras["feedback_s"]` from `t0` until its joints were known, or None;
        the moved iterate)."""
        x = np.array(prep.run.q, float)
        s = np.linspace(0.0, 1.0, len(x))
        x += (10 * s**3 - 15 * s**4 + 6 * s**5)[:, None] * (q_goal - x[-1])[None]
        # every row at the moved iterate, seen from the registered camera (the rows do not
        # depend on the covariance)
        P = prep.parameters.copy()
        P[:CAMERA_PARAMETERS] = replace(registered, q_start=prep.q0).camera_parameter()
        if not np.all(prep.solver.rows(x.ravel(), P, prep.v0, prep.a0, self.setup.ocp.min_depth)
                      > 0.0):
            return None, x
        feedback_s = time.perf_counter() - t0
        # the plan's Solution: no longer in the measurement's path
        sub = replace(registered.with_ocp(horizon=len(x) - 1, sigma0=cov), q_start=prep.q0,
                      q_goal=q_goal)
        sub.x_start, sub.x_goal = sub.poses_of(np.vstack([prep.q0, q_goal]))
        solver, propagation = self._interior(sub)
        run = prep.run
        P = solver.parameters(sub)
        P[CAMERA_PARAMETERS] = run.initial_trace  # the objective's scale: the preparation's
        run = solver.plan_at(sub, x.ravel(), P, run.initial_trace, Status.FEASIBLE_POINT_FOUND,
                             run.iterations, run.relaxed_iterations, t0)
        sol = replan_solution(sub, propagation, solver, prep.warm, run, cov, prep.v0, prep.a0)
        tried = [ReplanAttempt(reserve=prep.reserve, steps_added=0, status=prep.run.status,
                               iterations=prep.run.iterations,
                               relaxed_iterations=prep.run.relaxed_iterations)]
        return sol.replaced(extras={**sol.extras, "reserve": prep.reserve, "extended_steps": 0,
                                    "feedback_s": feedback_s, "attempts_tried": tried}), x
