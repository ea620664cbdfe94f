"""Where a solve starts and where it ends: the typed points handed between solves.

`InitialGuess` is a joint trajectory to start from. `Iterate` is where a solve ended, to warm-start
the next solve of the same structure: the joints, and for IPOPT its primal-dual point (`PrimalDual`,
in the scaled NLP's variables). A projected Newton run ends with joints only: its bound multipliers
are implicit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class InitialGuess:
    """A joint trajectory to start from, and where it came from."""

    q: np.ndarray  # (T+1, nq) [rad, m]
    source: str


@dataclass(frozen=True)
class PrimalDual:
    """IPOPT's primal and dual values at the end of a solve, with the scaling they are expressed in
    (covariance scales, objective reference): a warm solve of the same NLP reuses the scaling with
    them."""

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    scale: np.ndarray
    trace_ref: float


@dataclass(frozen=True)
class Iterate:
    """The end of a converged solve: its joints, and IPOPT's primal-dual point when IPOPT made it,
    or the interior point method's row multipliers when it did."""

    q: np.ndarray  # (T+1, nq)
    dual: PrimalDual | None = None
    multipliers: np.ndarray | None = None  # `interior.InteriorNewton`'s, in the order of its rows

    @property
    def has_duals(self) -> bool:
        """Whether IPOPT can warm-start from it (a Newton iterate starts Newton again, or IPOPT
        cold)."""
        return self.dual is not None
