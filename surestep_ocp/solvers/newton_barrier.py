"""Newton on IPOPT's barrier problem (`NewtonSolver.run_barrier`): the minimum-depth bound kept,
which projected Newton's own formulation does not carry.

The objective minus mu times the logs of the free joints' distances to their bounds and of the
interior means' depths above the bound, mu updated by IPOPT's monotone strategy, steps with the
surrogate's banded Hessian plus the barrier's, an Armijo search with IPOPT's fraction to the
boundary. `solve_ocp_warm` runs it where projected Newton ends below the depth bound.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..model.robot import CAMERA_PARAMETERS
from ..problem.setup import Setup
from .newton_run import NewtonRun, _backtrack, _scale
from ..status import Status

# `run_barrier`: IPOPT's defaults for its barrier problem and the monotone update (mu_init,
# barrier_tol_factor, mu_linear_decrease_factor, mu_superlinear_decrease_power, tau_min, bound_push
# = bound_frac)
MU_INIT, KAPPA_EPS, KAPPA_MU, THETA_MU, TAU_MIN, BOUND_PUSH = 0.1, 10.0, 0.2, 1.5, 0.99, 1e-2


@dataclass
class _BarrierFunction:
    """The barrier function of one run: its objective's Functions (`fz`) and parameters `P`, the
    free variables `idx` with their bounds `xl`, `xh`, and the depth bound."""

    fz: object
    P: np.ndarray
    T: int
    idx: np.ndarray
    xl: np.ndarray
    xh: np.ndarray
    min_depth: float

    def value(self, f_y: float, z_y: np.ndarray, y: np.ndarray,
              m: float) -> tuple[float, np.ndarray]:
        """The barrier function at y from its objective and node depths (inf where a depth is at
        or below the bound), and the interior slacks."""
        s_y = z_y[1:self.T] - self.min_depth
        if np.any(s_y <= 0):
            return np.inf, s_y
        idx = self.idx
        return f_y - m * (np.sum(np.log(s_y)) + np.sum(np.log(y[idx] - self.xl))
                          + np.sum(np.log(self.xh - y[idx]))), s_y

    def merit(self, y: np.ndarray, m: float) -> tuple[float, np.ndarray]:
        """The barrier function at y, its objective and depths evaluated (`fz`)."""
        f_y, z_y, _ = self.fz(y, self.P)
        return self.value(float(f_y[0]), z_y, y, m)


class BarrierRun:
    """`run_barrier` (a base of `NewtonSolver`, whose compiled functions, start, steps and end it
    uses)."""

    def run_barrier(self, setup: Setup, init, tol: float = 1e-6, max_iter: int = 300,
                    verbose: bool = False) -> NewtonRun:
        """Newton on IPOPT's barrier problem, which keeps the minimum-depth bound: the objective
        minus mu times the logs of the free joints' distances to their bounds and of the interior
        means' depths above the bound, mu updated as IPOPT's monotone strategy does (from MU_INIT;
        once the barrier gradient's inf-norm is below KAPPA_EPS mu, to max(tol / 10, min(KAPPA_MU
        mu, mu^THETA_MU))), the start pushed inside the bounds as IPOPT does. The barrier problem's
        minimisers do not depend on the method, so this follows the central path of IPOPT's monotone
        fallback (`solve_ocp_warm`) with Newton's cheaper steps in joint space. Steps: the
        surrogate's banded Hessian plus the barrier's, an Armijo search on the barrier function with
        IPOPT's fraction to the boundary. Converged when the barrier gradient is at most `tol` at
        mu = tol / 10."""
        t0 = time.perf_counter()
        P, x, lo, hi, free, start_ok = self._start(setup, init)
        idx, min_depth = np.flatnonzero(free), setup.ocp.min_depth
        P[CAMERA_PARAMETERS] = trace_ref = _scale(float(self.fz(x, P)[2][0]))  # as `run`
        x = _pushed_inside(x, lo, hi, free)
        xl, xh = lo[idx], hi[idx]
        bar = _BarrierFunction(self.fz, P, self.T, idx, xl, xh, min_depth)
        m, it, shift = MU_INIT, 0, 0.0
        mu_min = tol / 10
        start_ok = start_ok and np.isfinite(bar.merit(x, m)[0])
        status = Status.MAXIMUM_ITERATIONS_EXCEEDED if start_ok else Status.INFEASIBLE_START
        while start_ok and it <= max_iter:
            _, f_val, G, HB, _ = self.step(x, P)
            z, g, gb, band = self._barrier_derivatives(x, P, G, bar)
            err = np.max(np.abs(g[idx] + m * gb[idx]))
            # the barrier problem solved well enough: a smaller mu
            while err <= KAPPA_EPS * m and m > mu_min:
                m = max(mu_min, min(KAPPA_MU * m, m ** THETA_MU))
                err = np.max(np.abs(g[idx] + m * gb[idx]))
            if m <= mu_min and err <= tol:
                status = Status.SOLVE_SUCCEEDED
                break
            if it == max_iter:
                break
            gm = g + m * gb
            step = self._surrogate_step(HB, gm, idx, shift, band_extra=m * band)
            if step is None:
                status = Status.SINGULAR_HESSIAN
                break
            d, shift, _ = step
            tau = max(TAU_MIN, 1.0 - m)
            alpha = _fraction_to_boundary(x, d, idx, xl, xh, tau)
            # this iterate's objective and depths, evaluated above
            value, s = bar.value(float(f_val[0]), z, x, m)
            if verbose:
                print(f"newton barrier {it:4d}  f {float(f_val[0]):.10e}  mu {m:.1e}  |g_mu| "
                      f"{err:.2e}  depth margin {s.min(initial=np.inf):.3e}", flush=True)
            # Armijo, boundary
            def barrier_step(alpha, x=x, d=d, s=s, m=m, tau=tau, value=value, slope=float(gm @ d)):
                trial = x + alpha * d
                v_trial, s_trial = bar.merit(trial, m)
                return (trial if np.all(s_trial >= (1 - tau) * s)
                        and v_trial <= value + 1e-4 * alpha * slope else None)

            trial = _backtrack(alpha, barrier_step)
            if trial is None:
                status = Status.LINE_SEARCH_FAILED
                break
            x, it = trial, it + 1
        return self._end(setup, x, P, trace_ref, status, it, 0, t0)

    def _barrier_derivatives(self, x: np.ndarray, P: np.ndarray, G: np.ndarray,
                             bar: _BarrierFunction) -> tuple:
        """(node depths, the objective's gradient, the barrier's gradient and curvature per unit
        mu, the curvature in the Hessian's band storage) at x; G: the objective's interval
        gradients there."""
        T, nq, n = self.T, self.robot.nq, self.n
        idx, xl, xh = bar.idx, bar.xl, bar.xh
        a, b = self.node_pairs
        z, dz, d2z = self.depth(x, P)
        inv_s = np.zeros(T + 1)
        inv_s[1:T] = 1.0 / (z[1:T] - bar.min_depth)
        dz, d2z = dz.reshape(T + 1, nq), d2z.reshape(T + 1, nq, nq)
        g = np.bincount(self.g_index, weights=G, minlength=n)
        gb = -(inv_s[:, None] * dz).ravel()  # the barrier's gradient and curvature, per unit mu
        gb[idx] += 1.0 / (xh - x[idx]) - 1.0 / (x[idx] - xl)
        blocks = (inv_s[:, None, None] ** 2 * dz[:, :, None] * dz[:, None, :]
                  - inv_s[:, None, None] * d2z)
        band = np.bincount(self.node_band, weights=blocks[:, a, b].ravel(),
                           minlength=self.band * n)
        band = band.reshape(self.band, n)
        band[0, idx] += 1.0 / (x[idx] - xl) ** 2 + 1.0 / (xh - x[idx]) ** 2
        return z, g, gb, band


def _pushed_inside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The start with its free variables pushed inside their bounds as IPOPT does (bound_push,
    bound_frac)."""
    push_lo = BOUND_PUSH * np.minimum(np.maximum(1.0, np.abs(lo)), hi - lo)
    push_hi = BOUND_PUSH * np.minimum(np.maximum(1.0, np.abs(hi)), hi - lo)
    return np.where(free, np.clip(x, lo + push_lo, hi - push_hi), x)


def _fraction_to_boundary(x: np.ndarray, d: np.ndarray, idx: np.ndarray, xl: np.ndarray,
                          xh: np.ndarray, tau: float) -> float:
    """The first step length along d: at most 1, and a fraction `tau` of the way to the free
    variables' bounds (IPOPT's fraction to the boundary)."""
    di = d[idx]
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.concatenate([np.where(di < 0, (x[idx] - xl) / -di, np.inf),
                               np.where(di > 0, (xh - x[idx]) / di, np.inf)])
    # IPOPT's fraction to the boundary
    return min(1.0, tau * float(np.min(room, initial=np.inf)))
