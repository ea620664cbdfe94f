"""The primal-dual Newton system reduced to the joints at one iterate: the derivatives it needs,
its assembly in band storage and factorisation, and the directions it gives."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .jacobian import _csr_dot, _RowJacobian


@dataclass
class Derivatives:
    """The objective and the rows' derivatives at one iterate, its dual error and average
    complementarity."""

    f_val: float
    g: np.ndarray  # grad f
    HB: np.ndarray  # the surrogate's interval blocks
    DZ: np.ndarray  # the depths' gradients per node, (T + 1, nq)
    D2Z: np.ndarray  # and Hessians, (T + 1, nq, nq)
    A: np.ndarray  # the tool velocities' Jacobians per point
    gy: np.ndarray  # the tool rows' scaled gradients per point
    wk: np.ndarray  # the tool rows' scaled multipliers, (k, points)
    hy: np.ndarray | None  # the end-game's curvature beyond Gauss-Newton's per point
    jac: _RowJacobian
    err_d: float
    gap: float


def derivatives(ip, rows, x, w, s, nc, end_game, secant, previous) -> Derivatives:
    """The derivatives at x with multipliers w (the tool rows' exact curvature with `end_game`),
    the secant pair of the last step given to `secant` (the end-game's)."""
    nw, T, nq, n = ip.newton, ip.T, ip.nq, ip.n
    P, offsets, tool_scale, idx, nb, nd_ = (rows.P, rows.offsets, rows.tool_scale, rows.idx,
                                            rows.nb, rows.nd)
    hy = None
    _, f_val, G, HB, _ = nw.step(x, P)
    f_val = float(f_val[0])
    Z, DZ, D2Z = nw.depth(x, P)
    DZ, D2Z = DZ.reshape(T + 1, nq), D2Z.reshape(T + 1, nq, nq)
    wt = w[nd_ + T - 1:]
    wk = wt.reshape(ip.n_pts, ip.tool_k).T * tool_scale[:, None]  # (k, points)
    if end_game:  # the exact curvature beyond Gauss-Newton's: Hess of w . g - GN's
        A, GT, hy = ip.tool_res(x, offsets, wk)
        hy = hy.reshape(2 * nq, 2 * nq, ip.n_pts, order="F").transpose(2, 0, 1)
    else:
        A, GT = ip.tool_jacs(x, offsets)
    A, gy = ip._tool_gradients(A, GT, tool_scale)
    # (points, k, W nq): the rows' gradients in the window
    tj = ip._to_window(gy)
    g = np.bincount(nw.g_index, weights=G, minlength=n)  # grad f
    if secant is not None:
        # the last step's secant pair, against the surrogate at this point
        step_x = x - previous[0]
        secant.update(step_x, g - previous[1]
                      - np.bincount(nw.h_rows, weights=HB * step_x[nw.h_cols], minlength=n))
    jac = _RowJacobian(ip, idx, DZ, tj)
    err_d = float(np.max(np.abs((g - jac.T(w))[idx]))) if nb else 0.0
    gap = float(w @ s) / nc  # the average complementarity
    return Derivatives(f_val, g, HB, DZ, D2Z, A, gy, wk, hy, jac, err_d, gap)


def reduced_factor(ip, rows, d: Derivatives, w, s, end_game, shift):
    """(w / s, the factor `_factor` gives or None) of the reduced matrix at the derivatives d
    (the tool rows' exact curvature with `end_game` where the matrix with it is positive
    definite), from the last iteration's `shift`."""
    T, n = ip.T, ip.n
    idx, nb, nl, nd_ = rows.idx, rows.nb, rows.nl, rows.nd
    DZ, D2Z, A, gy, wk, hy, HB = d.DZ, d.D2Z, d.A, d.gy, d.wk, d.hy, d.HB
    # the reduced matrix in band storage: the surrogate, then sum (w / c) grad c grad c^T +
    # w Hess(-c)
    sig = w / s
    wl = sig[2 * nb:2 * nb + nl] + sig[2 * nb + nl:nd_]
    wd, zdn = np.zeros(T + 1), np.zeros(T + 1)
    wd[1:T], zdn[1:T] = sig[nd_:nd_ + T - 1], w[nd_:nd_ + T - 1]
    blocks = wd[:, None, None] * DZ[:, :, None] * DZ[:, None, :] - zdn[:, None, None] * D2Z
    # the tool rows per point in (q(s), q'(s)): sum_k (w / c) grad g grad g^T and
    # Gauss-Newton's w Hess g (the end-game adds the rest of it); then per window
    st = sig[nd_ + T - 1:].reshape(ip.n_pts, ip.tool_k)  # (points, k)
    JW = ip._window_terms(ip._tool_blocks(A, gy, wk, st))
    ab = ip._band(HB, wl, blocks.ravel(), JW)
    ab[0, idx] += sig[:nb] + sig[nb:2 * nb]
    factor = None
    if end_game:
        # the tool rows' exact curvature where the matrix with it is positive definite as
        # it is, else Gauss-Newton's: shifted, the exact one gave short, gradient-like steps
        exact = ab + _csr_dot(ip.tool_scatter, ip._window_terms(hy)
                              ).reshape(ip.bw, n)
        factor = ip._factor(exact, idx, 0.0, may_shift=False)
    if factor is None:
        factor = ip._factor(ab, idx, shift)
    return sig, factor


def directions(jac, solve, secant, band_factor, fixed, g, s, w, sig, rho):
    """The Newton direction (dx, dc, dw) as a function of the barrier parameter mu_t: dc the
    rows' linearised change, the relaxation rho gone; with the end-game's secant correction."""
    relaxed = bool(rho.any())

    def direction(mu_t):
        # (dx, dc, dw) for the barrier parameter mu_t; dc the rows' linearised change
        if relaxed:
            dx = solve(jac.T(mu_t / s + sig * rho) - g)
        else:  # (the affine probe's: -g alone)
            dx = solve(jac.T(mu_t / s) - g if np.any(mu_t) else -g)
        if secant is not None and secant.w.size:
            # the surrogate's missing curvature, learnt
            corrected = secant.step(band_factor, fixed, dx)
            dx = dx if corrected is None else corrected
        # the slacks' change: the rows' linearised change, the relaxation gone
        dc = jac.dot(dx) - rho
        return dx, dc, mu_t / s - w - sig * dc

    return direction
