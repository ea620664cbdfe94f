"""What a run leaves: its end (`InteriorRun`) and a record per iteration (`IterationRecord`, what
the `verbose` option prints)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..newton import NewtonRun
from .options import FEASIBLE
from ...status import Status


@dataclass(frozen=True)
class IterationRecord:
    """One iteration's state where it begins (before its convergence test): the barrier parameter
    it starts with and the last step's lengths and corrections."""

    iteration: int
    objective: float
    mu: float
    dual_error: float
    gap: float  # the average complementarity
    relaxed: float  # the largest relaxation (0: no row relaxed)
    step: float  # the last step's length, relative to its direction
    dual_step: float  # the last step's length for the multipliers
    corrections: int  # the last step's second-order corrections

    def line(self) -> str:
        """The line `verbose` prints."""
        return (f"interior {self.iteration:4d}  f {self.objective:.10e}  mu {self.mu:.1e}  "
                f"dual {self.dual_error:.2e}  gap {self.gap:.2e}  relaxed {self.relaxed:.1e}  "
                f"step {self.step:.2e}  dual step {self.dual_step:.2e}  "
                f"corrections {self.corrections}")


@dataclass
class InteriorRun(NewtonRun):
    """Where an interior-point run ended, with its constraint multipliers (a warm start for the next
    run)."""

    multipliers: np.ndarray | None = None
    relaxed_iterations: int = 0  # iterations with relaxed rows (a start outside them, `relax`)
    history: list[IterationRecord] = field(default_factory=list, repr=False)  # per iteration

    @property
    def success(self) -> bool:
        return self.status in (Status.SOLVE_SUCCEEDED, Status.SOLVED_TO_ACCEPTABLE_LEVEL, FEASIBLE)

    def log(self) -> str:
        """The iterations' records as `verbose` printed them."""
        return "\n".join(r.line() for r in self.history)
