"""Stage-wise sparse derivatives: small dense per-stage blocks scattered into one global sparsity.

A derivative of the OCP (gradient, constraint Jacobian, Hessian of the Lagrangian) is a sum of
blocks, one per interval or node, each a dense output of a small Function mapped over the
horizon. `entries` lists where a stage's dense block goes; `assemble` builds the global
sparsity and one constant sparse matrix per kind of block that scatters the mapped blocks'
entries into the global nonzeros. The expression graphs (and the generated C code) then hold
each stage once, whatever the horizon.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def entries(pairs) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of each entry of each stage's dense (rows x cols) block, column-major within a
    block.

    `pairs`: a list of (row indices, column indices), one per stage."""
    r = np.concatenate([np.tile(ri, len(ci)) for ri, ci in pairs])
    c = np.concatenate([np.repeat(ci, len(ri)) for ri, ci in pairs])
    return r, c


def assemble(shape, parts, constant=None) -> tuple[ca.Sparsity, list[ca.DM], ca.DM]:
    """Sparsity of the sum of scattered stage parts [(rows, cols)] (upper triangle only when square:
    a Hessian), one scatter matrix per part (global nonzeros x part entries) and the nonzeros of
    `constant` (a dense matrix added to the sum, or None)."""
    keep = [np.ones(len(r), bool) if shape[0] != shape[1] else r <= c for r, c in parts]
    rows = [r[k] for (r, _), k in zip(parts, keep)]
    cols = [c[k] for (_, c), k in zip(parts, keep)]
    if constant is not None:
        cr, cc = np.nonzero(constant)
        rows.append(cr)
        cols.append(cc)
    pairs = sorted(set(zip(np.concatenate(rows).tolist(), np.concatenate(cols).tolist())),
                   key=lambda rc: (rc[1], rc[0]))
    sp = ca.Sparsity.triplet(*shape, [r for r, _ in pairs], [c for _, c in pairs])
    nz = {(int(r), int(c)): k for k, (r, c) in enumerate(zip(sp.row(), sp.get_col()))}
    scatters = []
    for (r, c), k in zip(parts, keep):
        src = np.flatnonzero(k)
        dst = [nz[(int(r[i]), int(c[i]))] for i in src]
        scatters.append(ca.DM(ca.Sparsity.triplet(sp.nnz(), len(r), dst, src.tolist()), 1.0))
    const = np.zeros(sp.nnz())
    if constant is not None:
        for r, c in zip(cr, cc):
            const[nz[(int(r), int(c))]] = constant[r, c]
    return sp, scatters, ca.DM(const)


def smoothness_matrix(n: int, q_idx: list[np.ndarray], smoothness: float) -> np.ndarray:
    """D with `smoothness * sum_t |q_t+1 - q_t|^2 = x^T D x / 2` (constant curvature), n x n."""
    D = np.zeros((n, n))
    for t in range(len(q_idx) - 1) if smoothness > 0 else ():
        nq = len(q_idx[t])
        for i, j, sign in ((q_idx[t], q_idx[t], 1), (q_idx[t + 1], q_idx[t + 1], 1),
                           (q_idx[t], q_idx[t + 1], -1), (q_idx[t + 1], q_idx[t], -1)):
            D[np.ix_(i, j)] += 2 * smoothness * sign * np.eye(nq)
    return D
