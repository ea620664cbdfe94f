"""The rows' Jacobian at one iterate (`_RowJacobian`) and the sparse products it and the band's
assembly use."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import _sparsetools


class _RowJacobian:
    """The rows' Jacobian at one iterate, in the order of `InteriorNewton.constraints` (bounds
    +-e_i, linear rows +-a_i, depths grad z, tool rows -grad g): products with it and with its
    transpose, each pair of direct rows by one product. The curved rows' entries are written into
    the solver's CSR matrix in place (valid until the next iterate's)."""

    def __init__(self, ip, idx: np.ndarray, DZ: np.ndarray, tj: np.ndarray):
        if ip.jac_idx is not idx and not np.array_equal(ip.jac_idx, idx):
            ip._jac_pattern(idx)
        self.idx, self.n, self.L, self.C = idx, ip.n, ip.lin_map, ip.jac_curved
        self.nb, self.nl = len(idx), ip.n_lin
        self.C.data[ip.jac_depth] = DZ[1:ip.T].ravel()
        self.C.data[ip.jac_tool] = -tj.ravel()  # (points, k, W nq)

    def T(self, v: np.ndarray) -> np.ndarray:
        """sum_i v_i grad c_i"""
        nb, nl = self.nb, self.nl
        out = _csr_tdot(self.C, v[2 * nb + 2 * nl:], self.n)
        _csr_tdot(self.L, v[2 * nb:2 * nb + nl] - v[2 * nb + nl:2 * nb + 2 * nl], self.n, out)
        out[self.idx] += v[:nb] - v[nb:2 * nb]
        return out

    def dot(self, dx: np.ndarray) -> np.ndarray:
        """grad c_i . dx for every row"""
        nb, nl = self.nb, self.nl
        out = np.zeros(2 * nb + 2 * nl + self.C.shape[0])
        np.take(dx, self.idx, out=out[:nb])
        np.negative(out[:nb], out=out[nb:2 * nb])
        lin = _csr_dot(self.L, dx, out[2 * nb:2 * nb + nl])
        np.negative(lin, out=out[2 * nb + nl:2 * nb + 2 * nl])
        _csr_dot(self.C, dx, out[2 * nb + 2 * nl:])
        return out

    def curved_dot(self, dx: np.ndarray) -> np.ndarray:
        """grad c_i . dx for the curved rows alone (depths, tool rows)"""
        return _csr_dot(self.C, dx)

    def curved_T(self, v: np.ndarray) -> np.ndarray:
        """sum_i v_i grad c_i over the curved rows alone"""
        return _csr_tdot(self.C, v, self.n)


def _csr_dot(A: sp.csr_matrix, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """A @ x (added to `out` if given) by SciPy's kernel without its dispatch, which costs twice
    the product at these sizes (tens of microseconds, several times an iteration)."""
    y = np.zeros(A.shape[0]) if out is None else out
    _sparsetools.csr_matvec(A.shape[0], A.shape[1], A.indptr, A.indices, A.data, x, y)
    return y


def _csr_tdot(A: sp.csr_matrix, v: np.ndarray, n: int, out: np.ndarray | None = None
              ) -> np.ndarray:
    """A^T @ v (added to `out` if given), A's CSR arrays read as its transpose's CSC."""
    y = np.zeros(n) if out is None else out
    _sparsetools.csc_matvec(n, A.shape[0], A.indptr, A.indices, A.data, v, y)
    return y
