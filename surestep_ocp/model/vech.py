"""A symmetric 6x6 matrix as its `vech`: the lower triangle column by column (NV = 21 numbers),
the form the belief model carries its covariances in; `vech`, `unvech` and `trace_vech` on CasADi
or NumPy values, `unvech_many` on many NumPy rows at once.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

NX = 6  # the tangent (and pose) size: position, rotation
NV = NX * (NX + 1) // 2  # 21
_TRIL = [(i, j) for j in range(NX) for i in range(j, NX)]  # vech order: column-major lower triangle
DIAG = [k for k, (i, j) in enumerate(_TRIL) if i == j]  # positions of the diagonal in vech
_UNVECH_INDEX = np.zeros((NX, NX), int)  # (6, 6) position in vech of each entry
for _k, (_i, _j) in enumerate(_TRIL):
    _UNVECH_INDEX[_i, _j] = _UNVECH_INDEX[_j, _i] = _k


def vech(M):
    """Lower triangle of a symmetric 6x6 matrix, column by column (CasADi or NumPy)."""
    if isinstance(M, np.ndarray):
        return np.array([M[i, j] for i, j in _TRIL])
    return ca.vertcat(*[M[i, j] for i, j in _TRIL])


def unvech(v):
    """Symmetric 6x6 matrix of its `vech` (CasADi or NumPy)."""
    if isinstance(v, np.ndarray):
        M = np.zeros((NX, NX))
        for k, (i, j) in enumerate(_TRIL):
            M[i, j] = M[j, i] = v[k]
        return M
    M = ca.SX.zeros(NX, NX) if isinstance(v, ca.SX) else ca.MX.zeros(NX, NX)
    for k, (i, j) in enumerate(_TRIL):
        M[i, j] = v[k]
        if i != j:
            M[j, i] = v[k]
    return M


def unvech_many(V: np.ndarray) -> np.ndarray:
    """(N, 6, 6) symmetric matrices of the rows of V (N, 21), NumPy."""
    V = np.asarray(V, float)
    return V[:, _UNVECH_INDEX]


def trace_vech(v):
    """Trace of the matrix whose vech is `v`."""
    return sum(v[k] for k in DIAG)
