"""The barrier parameter (Mehrotra's probe, re-centred after a short step, floored by the dual
error), the multipliers' safeguard and the convergence test."""

from __future__ import annotations

import numpy as np

from .line_search import _to_boundary
from .options import FEASIBLE
from ...status import Status


def safeguard(w: np.ndarray, m: float, s: np.ndarray) -> np.ndarray:
    """IPOPT's safeguard: the multipliers w with w s within a band around m."""
    r = m / s
    return np.minimum(np.maximum(w, r * 1e-10), r * 1e10)


def stalled(f_hist: list, f_val: float, options) -> bool:
    """Whether the objective changed by at most `acceptable_change` (relative) over the last
    `acceptable_iter` iterations."""
    return (len(f_hist) > options.acceptable_iter
            and abs(f_hist[-1 - options.acceptable_iter] - f_val)
            <= options.acceptable_change * max(abs(f_val), 1e-12))


def end_status(status, gap, err_d, is_stalled, rho, c, it, relaxed_its, options) -> str | None:
    """The status the run ends with at this iteration (before its step), or None to go on:
    converged (to the tolerance, or acceptably once the objective stalls) with the average
    complementarity at `mu_final` and no row relaxed; else at `max_iter` (with `feasible_ok`, the
    steps that shrank a relaxation not counted, up to `relaxed_max`)."""
    o = options
    if gap <= o.mu_final and (err_d <= o.tol or is_stalled) and not rho.any():
        return Status.SOLVE_SUCCEEDED if err_d <= o.tol else Status.SOLVED_TO_ACCEPTABLE_LEVEL
    if (it - (relaxed_its if o.feasible_ok else 0) == o.max_iter
            or (o.feasible_ok and relaxed_its >= o.relaxed_max)):
        if o.feasible_ok and not rho.any() and np.all(c > 0):
            return FEASIBLE
        return status
    return None


def probe(direction, s: np.ndarray, w: np.ndarray, nc: int):
    """Mehrotra's probe: the affine step (mu = 0) says how far the complementarity can fall:
    (its rows' change, its multipliers' change, the complementarity after it)."""
    _, dca, dwa = direction(0.0)
    ap, ad = _to_boundary(s, dca, 1.0), _to_boundary(w, dwa, 1.0)
    gap_aff = float((s + ap * dca) @ (w + ad * dwa)) / nc
    return dca, dwa, gap_aff


def barrier_update(m, m_last, gap, gap_aff, err_d, is_stalled, rho, last_step, options) -> float:
    """The next barrier parameter: Mehrotra's from the probe, re-centred at the gap after a step
    cut short; while the dual error is above the tolerance, no lower than `mu_per_dual(_relaxed)`
    times it, nor than its last value (with `feasible_ok` only while rows are relaxed)."""
    o = options
    if last_step >= o.short_step:
        # sigma = (gap_aff / gap)^3; the barrier parameter is never raised here
        m = max(o.mu_final / 10, min(m, gap * min(1.0, (gap_aff / max(gap, 1e-300)) ** 3)))
    else:
        # the last step was cut short (the iterate off the central path): re-centre at the
        # current gap
        m = max(o.mu_final / 10, gap)
    if err_d > o.tol and not is_stalled and (not o.feasible_ok or rho.any()):
        m = max(m, min(m_last, (o.mu_per_dual_relaxed if rho.any() else o.mu_per_dual)
                        * err_d))
    return m
