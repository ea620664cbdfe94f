"""The secant end-game of projected Newton: a limited-memory symmetric rank-one correction of the
surrogate Hessian learnt from the steps taken, for the curvature the surrogate lacks where the
exact Hessian is too costly (the 6x6 recursion, long horizons; docs/hessian_and_newton.md).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dpbtrs

# rank-one terms the secant end-game keeps (its tail is a few iterations: rarely reached)
SECANT_MEMORY = 20


class _SecantCorrection:
    """A limited-memory SR1 correction `A = U diag(w) U^T` of the surrogate Hessian (structured
    quasi-Newton).

    The surrogate misses S's own curvature in the coefficients (concave: negative semidefinite),
    which has no cheap exact form for the 6x6 recursion (nc Hessian-vector products) or at long
    horizons. Each step s with gradient change y gives the secant residual `r = y - H s - A s` of
    the current surrogate H; SR1 adds `r r^T / (r . s)` (indefinite updates allowed, as the missing
    part is). The step solves `(H + A) d = -g` by Woodbury on H's banded factor, and is used only
    where `H + A` is positive definite on the free variables (Haynsworth: the capacitance matrix
    `W^-1 + U^T H^-1 U` then has the inertia of `W^-1`)."""

    def __init__(self, n: int):
        self.U, self.w = np.zeros((n, 0)), np.zeros(0)
        # (factor, U H^-1 terms) of the last `step`: the interior point solves twice per factor
        self._last = None

    def update(self, s: np.ndarray, r_surrogate: np.ndarray) -> None:
        """Add the SR1 term for step s, given `y - H s` (H: the surrogate at the new point); skipped
        when r . s is tiny against |r| |s| (SR1's safeguard)."""
        r = r_surrogate - self.U @ (self.w * (self.U.T @ s))
        den = float(r @ s)
        if abs(den) <= 1e-8 * np.linalg.norm(r) * np.linalg.norm(s):
            return
        self.U = np.column_stack([self.U, r])[:, -SECANT_MEMORY:]
        self.w = np.append(self.w, 1.0 / den)[-SECANT_MEMORY:]
        self._last = None

    def step(self, factor: np.ndarray, fixed: np.ndarray, z0: np.ndarray) -> np.ndarray | None:
        """`(H + A)^-1 (-g)` from `z0 = H^-1 (-g)` and H's banded Cholesky factor (held variables:
        identity rows, no correction), or None where `H + A` is not positive definite there."""
        if not self.w.size:
            return None
        if self._last is None or self._last[0] is not factor or self._last[1] is not fixed:
            U = np.where(fixed[:, None], 0.0, self.U)
            Z = dpbtrs(factor, U, lower=1)[0]
            cap = np.diag(1.0 / self.w) + U.T @ Z
            cap = 0.5 * (cap + cap.T)
            ev = np.linalg.eigvalsh(cap)
            ok = not (np.min(np.abs(ev)) <= 1e-12 * np.max(np.abs(ev))
                      or np.sum(ev < 0) != np.sum(self.w < 0))
            self._last = (factor, fixed, U, Z, cap, ok)
        _, _, U, Z, cap, ok = self._last
        if not ok:
            return None
        d = z0 - Z @ np.linalg.solve(cap, U.T @ z0)
        return d if np.all(np.isfinite(d)) else None
