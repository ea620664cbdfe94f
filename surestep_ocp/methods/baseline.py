"""The straight-line baseline: position linear, orientation by slerp, no optimisation.

With `limits.enforce: false` the line runs at a constant pace (from rest: most robots cannot play
its first and last step). With `limits.enforce: true` the same line runs at a time law within the
limits, rest to rest (the constant pace where it is within them): in the problem's duration when a
law fits, else in the fewest whole steps found in which one fits, said in `extras["time_law"]` and
the status `Duration_Lengthened` (docs/motion_limits_and_export.md, "The baseline within the
limits").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..model.limits import VIOLATED, MotionLimits, problem_limits
from ..model.limits.retiming import PchipPath, ToolSpeed, planned_curve, toppra_grid, toppra_run
from ..problem.setup import Setup
from ..output.solution import Solution
from ..ocp.plan_evaluation import evaluate
from ..ocp.straight_line import TIME_LAWS, straight_line
from ..status import Status


def reachability(setup: Setup, poses: np.ndarray) -> tuple[list, dict]:
    """Joint solutions of pose-space waypoints and a summary of which are reachable."""
    # batched Newton from the joint-space line first (as for the OCP's initial guess), then
    # sequential IK
    q_best, ok, res_m, res_r = setup.joints_along(poses, setup.q_start,
                                                  guesses=setup.joint_line(len(poses) - 1))
    qs = [q if k else None for q, k in zip(q_best, ok)]
    info = {
        "reachable": int(ok.sum()),
        "unreachable": int((~ok).sum()),
        "ik_residual_m": res_m.tolist(),
        "ik_residual_rad": res_r.tolist(),
    }
    return qs, info


def solve_baseline(setup: Setup) -> Solution:
    """The straight line: at a constant pace, or (limits enforced) a time law within them."""
    if setup.ocp.limits.enforce:
        return _within_limits(setup)
    t0 = time.perf_counter()
    poses = straight_line(setup.x_start, setup.x_goal, setup.ocp.horizon)
    elapsed = time.perf_counter() - t0
    qs, info = reachability(setup, poses)
    sol = evaluate(setup, "baseline", poses, qs, success=True, status="not optimised",
                   solve_time_s=elapsed, iterations=0, objective=np.nan,
                   extras={"reachability": info})
    return sol.replaced(objective=sol.trace_final)


def constant_pace(T: int) -> np.ndarray:
    """(T+1,) fractions of the way at a constant pace (the baseline without enforced limits)."""
    return np.linspace(0.0, 1.0, T + 1)


# The laws the baseline tries in turn within enforced limits: its own constant pace, then TIME_LAWS.
BASELINE_LAWS = (("constant-pace", constant_pace), *TIME_LAWS)
MAX_STEPS = 4000  # the longest baseline searched within the limits (200 s at 0.05 s per step)
LENGTHENED = Status.DURATION_LENGTHENED  # the status of a baseline in more steps than the horizon
PATH_POINTS = 50  # points of the line (by IK) that toppra's path interpolates
FREE_CLOCK = 1e3  # toppra's bound on the path parameter's own speed and acceleration: never binding


@dataclass
class _Timed:
    """The straight line in `steps` steps at one time law: waypoints, joints, played curve."""

    steps: int
    law: str
    poses: np.ndarray
    qs: list
    reach: dict
    played: dict | None  # retiming.planned_curve's check (None: a waypoint unreachable)

    @property
    def within(self) -> bool:
        return self.played is not None and self.played["within"]

    def stretch(self) -> float:
        """How much longer the same law must take to be within its limits (velocities scale as
        1 / stretch, accelerations as 1 / stretch^2)."""
        peaks = self.played["peak_ratios"]
        return max(peaks["joint_velocity"], math.sqrt(peaks["joint_acceleration"]),
                   peaks["tool_speed"] or 0.0, peaks["tool_rotation"] or 0.0)


def _timed(setup: Setup, limits: MotionLimits, steps: int, name: str, law) -> _Timed:
    poses = straight_line(setup.x_start, setup.x_goal, steps, law(steps))
    qs, reach = reachability(setup, poses)
    played = None
    if not reach["unreachable"]:
        dt = setup.ocp.timing.step_s
        q = np.array(qs, float)
        played = planned_curve(q, dt, limits, 1.0 / dt, setup.robot, setup.robot.frame)[1]
    return _Timed(steps, name, poses, qs, reach, played)


def _first_within(setup: Setup, limits: MotionLimits, steps: int,
                  laws) -> tuple[_Timed | None, list[_Timed]]:
    """The line in `steps` steps at the first of `laws` whose played curve is within the limits
    (None: none is), and every law tried (they stop at an unreachable waypoint)."""
    tried = []
    for name, law in laws:
        tried.append(_timed(setup, limits, steps, name, law))
        if tried[-1].within or tried[-1].played is None:
            break
    return (tried[-1] if tried[-1].within else None), tried


def time_optimal_law(setup: Setup, limits: MotionLimits) -> tuple[float, object] | None:
    """toppra's time-optimal law along the line (rest to rest, within the joint velocity and
    acceleration limits and the tool's speeds): its duration [s] and the law (`steps` -> the
    fractions of the way at `steps + 1` evenly spaced times); None where toppra finds none or a
    point of the line is unreachable. No law is faster along this path."""
    s = np.linspace(0.0, 1.0, PATH_POINTS + 1)
    poses = straight_line(setup.x_start, setup.x_goal, PATH_POINTS, s)
    q, ok = setup.joints_along(poses, setup.q_start, guesses=setup.joint_line(PATH_POINTS))[:2]
    if not ok.all():
        return None
    path = PchipPath(s, q)
    tool = ToolSpeed(setup.robot, setup.robot.frame, limits)
    traj = toppra_run(path, toppra_grid(s)[0], limits, np.ones(3), FREE_CLOCK, FREE_CLOCK, tool)
    if traj is None:
        return None
    duration = float(traj.duration)

    def law(steps: int) -> np.ndarray:
        f = np.clip(traj(np.linspace(0.0, duration, steps + 1))[:, -1], 0.0, 1.0)
        f[0], f[-1] = 0.0, 1.0
        return f

    return duration, law


def _fewest_steps(setup: Setup, limits: MotionLimits, tried: list[_Timed], laws,
                  floor: int = 0) -> _Timed | None:
    """The line in the fewest steps found (more than `tried`'s and than `floor`, a count known too
    short) at which a law is within the limits: grown by the laws' least stretch until one fits (at
    most MAX_STEPS), then bisected (the played curve's peaks are nearly, not exactly, monotone in
    the steps)."""
    lo, best = max(tried[0].steps, floor), None
    while best is None:
        if any(t.played is None for t in tried):
            return None
        steps = max(lo + 1, math.ceil(tried[0].steps * min(t.stretch() for t in tried)))
        if steps > MAX_STEPS:
            return None
        best, tried = _first_within(setup, limits, steps, laws)
        if best is None:
            lo = steps
    hi = best.steps
    while hi - lo > 1:
        mid = (lo + hi) // 2
        found = _first_within(setup, limits, mid, laws)[0]
        lo, hi, best = (mid, hi, best) if found is None else (lo, mid, found)
    return best


def _within_limits(setup: Setup) -> Solution:
    """The straight line at a time law within the enforced limits (module docstring): BASELINE_LAWS
    in the problem's steps, then toppra's time-optimal law too, in as many steps as it takes."""
    t0 = time.perf_counter()
    limits = problem_limits(setup)
    T, dt = setup.ocp.horizon, setup.ocp.timing.step_s
    laws = list(BASELINE_LAWS)
    best, tried = _first_within(setup, limits, T, laws)
    optimal = None
    if best is None and tried[-1].played is not None:
        optimal = time_optimal_law(setup, limits)
        if optimal is not None:
            laws.append(("time-optimal (toppra)", optimal[1]))
            best, tried = _first_within(setup, limits, T, laws)
        if best is None:  # fewer steps than 0.9 of toppra's duration: too short for any law
            floor = 0 if optimal is None else math.floor(0.9 * optimal[0] / dt)
            best = _fewest_steps(setup, limits, tried, laws, floor)
    line = best or tried[0]  # none within: the constant pace in T steps (as unenforced), over them
    record = {"law": line.law, "steps": line.steps, "duration_s": line.steps * dt,
              "problem_steps": T, "problem_duration_s": T * dt,
              "lengthened_by_s": (line.steps - T) * dt, "played_curve": line.played}
    if optimal is not None:
        record["time_optimal_s"] = optimal[0]  # toppra's: a bound no law along the line beats
    success, status = True, "not optimised" if line.steps == T else LENGTHENED
    if best is None and line.played is not None:  # (unreachable: `limits.enforce` reports it)
        success, status = False, VIOLATED
        record["not_within"] = (f"no time law keeps the straight line within the limits in at "
                                f"most {MAX_STEPS} steps ({MAX_STEPS * dt:g} s)")
    elapsed = time.perf_counter() - t0
    sol = evaluate(_with_steps(setup, line.steps), "baseline", line.poses, line.qs,
                   success=success, status=status, solve_time_s=elapsed, iterations=0,
                   objective=np.nan, extras={"reachability": line.reach, "time_law": record})
    return sol.replaced(objective=sol.trace_final)


def _with_steps(setup: Setup, steps: int) -> Setup:
    """The setup of a plan in `steps` steps: a moving camera holds its last pose after T."""
    extra = steps - setup.ocp.horizon
    if extra <= 0 or not setup.camera_schedule:
        return setup
    held = [setup.camera_schedule[-1]] * extra
    return replace(setup, camera_schedule=[*setup.camera_schedule, *held])


def duration_note(sol: Solution) -> str | None:
    """One line on a baseline's duration within enforced limits (None without a time law): kept,
    or lengthened and by how much, or not within them."""
    tl = sol.extras.get("time_law")
    if not tl:
        return None
    steps = f"{tl['duration_s']:.3f} s ({tl['steps']} steps)"
    asked = f"the problem's {tl['problem_duration_s']:.3f} s ({tl['problem_steps']} steps)"
    if tl.get("not_within"):
        return f"{steps}, {tl['law']} time law: {tl['not_within']}"
    if tl["steps"] == tl["problem_steps"]:
        return f"{steps}, the problem's, at a {tl['law']} time law within the motion limits"
    bound = (f"; toppra's time-optimal motion along the line: {tl['time_optimal_s']:.3f} s"
             if "time_optimal_s" in tl else "")
    return (f"{steps}: {asked} lengthened by {tl['lengthened_by_s']:.3f} s, the fewest steps "
            f"found in which a time law ({tl['law']}) keeps the straight line within the motion "
            f"limits{bound}")
