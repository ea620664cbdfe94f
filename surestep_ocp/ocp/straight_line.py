"""The straight line from start to goal and the time laws it is played at.

The baseline's path (`methods/baseline.py`), and the interior-point method's first start within the
limits (`solvers/backends/interior_point.py`: the line at the first of TIME_LAWS that keeps every
row): position linear, orientation by slerp.
"""

from __future__ import annotations

import numpy as np

from ..model.lie import continued_along, slerp_many
from .iterate import InitialGuess


def straight_line(x_start: np.ndarray, x_goal: np.ndarray, horizon: int,
                  fractions: np.ndarray | None = None) -> np.ndarray:
    """(T+1, 6) waypoints from start to goal, evenly spaced in position and in angle (the shortest
    rotation), the rotation vector continued along them from the start's (it may end on the goal's
    other side); `fractions` (T+1 from 0 to 1): the waypoints at these fractions of the way instead
    (a time law)."""
    s = np.linspace(0.0, 1.0, horizon + 1) if fractions is None else np.asarray(fractions, float)
    p = (1 - s)[:, None] * x_start[:3] + s[:, None] * x_goal[:3]
    r = slerp_many(x_start[3:], x_goal[3:], s)
    r[0], r[-1] = x_start[3:], x_goal[3:]
    return np.hstack([p, continued_along(r)])


def minimum_jerk(T: int) -> np.ndarray:
    """(T+1,) fractions of the way at the waypoints of a rest-to-rest minimum-jerk time law,
    10 s^3 - 15 s^4 + 6 s^5:
    zero velocity and acceleration at both ends, so the straight line keeps within the acceleration
    limits where a constant pace breaks them in its first and last step."""
    s = np.linspace(0.0, 1.0, T + 1)
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def trapezoid(T: int, ramp: float) -> np.ndarray:
    """(T+1,) fractions of the way at the waypoints of a rest-to-rest trapezoidal speed profile that
    accelerates and decelerates over `ramp` of the time each: a peak speed 1 / (1 - ramp) of the
    mean, where the minimum-jerk law's is 1.875 of it (for moves near the tool's speed limits)."""
    s = np.linspace(0.0, 1.0, T + 1)
    v = 1.0 / (1.0 - ramp)  # the cruise speed (the fraction of the way per unit time)
    a = v / ramp
    return np.where(s < ramp, 0.5 * a * s**2,
                    np.where(s > 1 - ramp, 1 - 0.5 * a * (1 - s) ** 2,
                             0.5 * a * ramp**2 + v * (s - ramp)))


# the time laws the interior-point method's start tries in turn (backends/interior_point.py,
# feasible_line)
TIME_LAWS = (("minimum-jerk", minimum_jerk),
             *((f"trapezoidal ({r:g} ramps)", lambda T, r=r: trapezoid(T, r))
                for r in (0.3, 0.2, 0.12)))


def timed_line(setup, law=minimum_jerk, name: str = "minimum-jerk",
               guesses: np.ndarray | None = None) -> InitialGuess:
    """The straight line from start to goal (the baseline's) at the pace of a time law, by IK from
    `guesses` (T + 1 joint vectors; default the joint line)."""
    T = setup.ocp.horizon
    poses = straight_line(setup.x_start, setup.x_goal, T, law(T))
    q = setup.joints_along(poses, setup.q_start,
                           guesses=setup.joint_line(T) if guesses is None else guesses)[0]
    q[0], q[-1] = setup.q_start, setup.q_goal
    return InitialGuess(q, f"straight line at a {name} pace")
