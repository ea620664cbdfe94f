"""What every projected-Newton-type run shares (`NewtonSolver.run`, its barrier run and the
interior-point method): the compiled functions' parameter vector, the objective's scale, the
backtracking line search, and where a run ended (`NewtonRun`).

Kept apart from the solver (newton.py) so that the runs built on it (newton_barrier.py,
interior/) use them without importing the solver's construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..problem.setup import Setup
from ..status import Status


def parameters(setup: Setup) -> np.ndarray:
    """The compiled functions' parameter vector of `setup`: the camera, the objective's scale (1
    until a run sets its own) and Sigma_0 in the recursion's form."""
    return np.concatenate([setup.camera_parameter(), [1.0],
                           setup.model.recursion_sigma0(setup.ocp.sigma0)])


@dataclass
class NewtonRun:
    """Where a projected Newton run ended, before its plan is evaluated (`NewtonSolver.run`)."""

    q: np.ndarray  # (T+1, nq) joints
    poses: np.ndarray  # (T+1, 6) planned poses [m, rad], camera frame
    status: Status
    iterations: int
    exact_steps: int
    objective: float  # Tr(Sigma_T) of the planning model plus smoothness
    trace: float  # Tr(Sigma_T) of the planning model
    initial_trace: float  # at the initial guess
    violation: float  # terminal pose [m or rad] or depth bound [m]
    solve_time_s: float
    secant_steps: int = 0  # steps with the secant end-game's correction

    @property
    def success(self) -> bool:
        return self.status == Status.SOLVE_SUCCEEDED


def _scale(trace: float) -> float:
    """The objective's scale: the start's trace, or 1 where that is 0 (every observation noise 0:
    the posterior is 0 along any plan, and only the smoothness term is left)."""
    return trace if trace > 0 else 1.0


def _backtrack(alpha: float, trial_at) -> np.ndarray | None:
    """Halve the step length from `alpha` until `trial_at(alpha)` returns an accepted point (each
    caller's Armijo test); None once it is below 1e-12 (a failed line search)."""
    while alpha > 1e-12:
        trial = trial_at(alpha)
        if trial is not None:
            return trial
        alpha /= 2
    return None
