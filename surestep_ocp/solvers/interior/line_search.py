"""The line search: the fraction to the boundary, then trial points along the direction with
second-order corrections for the curved rows, accepted by Armijo's test on the barrier function."""

from __future__ import annotations

import numpy as np

from ..newton import TAU_MIN, _backtrack


def _to_boundary(v: np.ndarray, dv: np.ndarray, tau: float) -> float:
    """The largest step a <= 1 with v + a dv >= (1 - tau) v for positive v: tau over the largest
    relative decrease."""
    fall = float(np.min(dv / v))
    return 1.0 if fall >= 0.0 else min(1.0, -tau / fall)




def line_search(ip, rows, x, c, s, w, rho, f_val, g, direction, m, jac, solve, sig, options):
    """Along `direction` (dx, dc, dw) at barrier parameter m: (found, az, corrections) with found
    (point, rows, step) or None (a failed line search), az the multipliers' step to the boundary
    fraction, corrections this iteration's second-order corrections."""
    dx, dc, dw = direction
    P, lin_c, offsets, min_depth, keep, nd_ = (rows.P, rows.lin_c, rows.offsets, rows.min_depth,
                                               rows.keep, rows.nd)
    max_soc, kappa_soc = options.max_soc, options.kappa_soc
    tau = max(TAU_MIN, 1.0 - m)
    a_max, az = _to_boundary(s, dc, tau), _to_boundary(w, dw, tau)
    value = f_val - m * float(np.sum(np.log(s)))
    g_dx = float(g @ dx)

    def accept(a):
        """(point, rows, step) at step a if within the boundary fraction and Armijo's
        decrease (while rows are relaxed: the boundary fraction alone, the relaxation
        shrinking with a), else None."""
        d = a * dx
        # the step, then its second-order corrections (at any length: a row with a tiny
        # slack breaks under the linearisation's error at any length; MAX_SOC in all, each
        # while it brings the rows nearer the boundary fraction by KAPPA_SOC)
        short = np.inf
        while True:
            f_t, c_t = ip.constraints(x + d, P, lin_c, offsets, min_depth, keep)
            s_t = c_t + (1.0 - a) * rho
            below = (1 - tau) - float(np.min(s_t / s))  # <= 0: within the fraction
            if below <= 0.0:
                if rho.any():
                    return x + d, c_t, a
                # Armijo against the decrease the model predicts: the objective linear,
                # the barrier exact on the linearised slacks (its slope alone, for a row
                # leaving a tiny slack, asks a decrease the log never gives: steps of 1e-4)
                v_t = f_t - m * float(np.sum(np.log(s_t)))
                pred = a * g_dx - m * float(np.sum(np.log1p(a * dc / s)))
                return (x + d, c_t, a) if pred <= 0 and v_t <= value + 1e-4 * pred else None
            if (socs[0] == max_soc or below > kappa_soc * short
                    or not np.all(s_t[:nd_] > 0)):
                return None
            short = below
            socs[0] += 1
            # what the linearisation of the curved rows missed
            e = c_t[nd_:] - (c[nd_:] + jac.curved_dot(d))
            d = d + solve(-jac.curved_T(sig[nd_:] * e))

    socs = [0]  # this iteration's second-order corrections
    return _backtrack(a_max, accept), az, socs[0]
