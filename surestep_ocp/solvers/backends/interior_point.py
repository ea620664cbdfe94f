"""The interior-point Newton method (`interior.py`) on the OCP within the enforced motion limits: the joint-space
problem of the projected Newton solver plus the limit rows, solved with a banded system per iteration."""

from __future__ import annotations

import numpy as np

from ...model.limits import enforce as enforce_limits
from ..baseline import straight_line
from ..iterate import InitialGuess, Iterate
from ..nlp_cache import interior_solver
from .base import Context, Outcome


def minimum_jerk(T: int) -> np.ndarray:
    """(T+1,) fractions of the way at the waypoints of a rest-to-rest minimum-jerk time law, 10 s^3 - 15 s^4 + 6 s^5:
    zero velocity and acceleration at both ends, so the straight line keeps within the acceleration limits where a
    constant pace breaks them in its first and last step."""
    s = np.linspace(0.0, 1.0, T + 1)
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def trapezoid(T: int, ramp: float) -> np.ndarray:
    """(T+1,) fractions of the way at the waypoints of a rest-to-rest trapezoidal speed profile that accelerates and
    decelerates over `ramp` of the time each: a peak speed 1 / (1 - ramp) of the mean, where the minimum-jerk law's
    is 1.875 of it (for moves near the tool's speed limits)."""
    s = np.linspace(0.0, 1.0, T + 1)
    v = 1.0 / (1.0 - ramp)  # the cruise speed (the fraction of the way per unit time)
    a = v / ramp
    return np.where(s < ramp, 0.5 * a * s**2,
                    np.where(s > 1 - ramp, 1 - 0.5 * a * (1 - s) ** 2, 0.5 * a * ramp**2 + v * (s - ramp)))


TIME_LAWS = (("minimum-jerk", minimum_jerk), *((f"trapezoidal ({r:g} ramps)", lambda T, r=r: trapezoid(T, r))
                                                for r in (0.3, 0.2, 0.12)))


def timed_line(setup, law=minimum_jerk, name: str = "minimum-jerk") -> InitialGuess:
    """The straight line from start to goal (the baseline's) at the pace of a time law, by IK from the joint line."""
    T = setup.ocp.horizon
    poses = straight_line(setup.x_start, setup.x_goal, T, law(T))
    q = setup.joints_along(poses, setup.q_start, guesses=setup.joint_line(T))[0]
    q[0], q[-1] = setup.q_start, setup.q_goal
    return InitialGuess(q, f"straight line at a {name} pace")


def feasible_line(setup, solver) -> InitialGuess:
    """The straight line at the first of TIME_LAWS whose curve keeps within every row (the interior-point method
    then keeps them); else at the one closest to them (the rows outside get slacks)."""
    best, margin = None, -np.inf
    for name, law in TIME_LAWS:
        guess = timed_line(setup, law, name)
        m = solver.start_margin(setup, guess)
        if m > 0:
            return guess
        if m > margin:
            best, margin = guess, m
    return best


class InteriorPointBackend:
    """The OCP with enforced limits where projected Newton's reformulation is exact (`newton_fits`); a start within
    every row (the caller's, else the straight line at a minimum-jerk pace)."""

    name = "interior"

    def applies(self, ctx: Context) -> str | None:
        if not ctx.setup.ocp.limits.enforce:
            return "the interior-point method is for problems with enforced motion limits (limits.enforce: true)"
        if not ctx.resolved.newton_fits:
            return ("it needs the condensed scalar recursion with the mean observation noise and six joints moving "
                    "the tracked frame")
        return None

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        setup, spec = ctx.setup, ctx.setup.ocp.solver
        solver = interior_solver(setup)
        kw = dict(tol=spec.tol, max_iter=min(spec.surrogate_max_iter, spec.max_iter), verbose=spec.print_level > 0)
        multipliers = warm.multipliers if warm is not None else None
        run = solver.run(setup, start, warm=multipliers, **kw)
        if run.status == "Infeasible_Start" and warm is None:  # a start at a constant pace: the same line, timed
            start = feasible_line(setup, solver)  # (the rows no time law keeps are relaxed at the start)
            run = solver.run(setup, start, relax=True, **kw)
        sol = solver.newton.solution(setup, ctx.method, start, run)
        sol.extras["solver"] = "interior"
        enforce_limits(setup, sol)  # the played curve checked densely, as every plan within the limits
        return Outcome(sol, Iterate(sol.joints, multipliers=run.multipliers) if sol.success else None)
