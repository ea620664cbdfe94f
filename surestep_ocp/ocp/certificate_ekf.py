"""The certificate's independent NumPy EKF: the trace recomputed without CasADi's recursion.

`numpy_trace` runs the planning model's EKF in Joseph form in plain NumPy (six scalar filters
where every covariance stays diagonal) along a plan's means, with the model's noise maps as the
certificate's Function gives them or as `_noises` evaluates them one by one; `_fd_gradient` is the
objective's gradient by central differences of it (the certificate's `fd_step` check).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.belief import NX, unvech_many, vech
from ..problem.setup import Setup

_OFF_DIAGONAL = ~np.eye(NX, dtype=bool)


def numpy_trace(setup: Setup, means: np.ndarray, q: np.ndarray, noises=None) -> float:
    """Tr(Sigma_T) of the planning model by a plain NumPy EKF (Joseph form) along the means, with
    the model's noise maps evaluated at the waypoints (all at once where they do not depend on
    the prediction). `noises`: those maps' values, `(W, V, maps)` as `_noises` gives them."""
    model = setup.model
    T = len(means) - 1
    W, V, maps = _noises(setup, means, q) if noises is None else noises
    predicted = model.noise.objective == "predicted"
    S = np.asarray(setup.ocp.sigma0, float)
    if (V is not None and maps is None and not S[_OFF_DIAGONAL].any()
            and not W[:, _OFF_DIAGONAL].any() and not V[:, _OFF_DIAGONAL].any()):
        # every covariance stays diagonal: six scalar Kalman filters, in plain floats
        s = np.diag(S).tolist()
        w = np.diagonal(W, axis1=1, axis2=2).tolist()
        v = np.diagonal(V, axis1=1, axis2=2).tolist()
        total = 0.0
        for i in range(NX):
            si = s[i]
            for t in range(T):
                p = si + w[t][i]
                vt = v[t][i]
                k = p / (p + vt)
                si = (1 - k) * (1 - k) * p + k * k * vt  # Joseph form
            total += p if predicted else si
        return float(total)
    eye = np.eye(NX)
    P = S
    for t in range(T):
        if maps is None:
            P = S + W[t]
        else:
            F, Qm = maps[0][t], maps[1][t]
            P = F @ S @ F.T + Qm @ W[t] @ Qm.T
        P = 0.5 * (P + P.T)
        Vt = V[t] if V is not None else np.asarray(model.planning_noise(means[t + 1], vech(P)))
        if maps is None:
            Mo = Vt
            K = np.linalg.solve(P + Mo, P).T
            IKH = eye - K
        else:
            H, R = maps[2][t], maps[3][t]
            Mo = R @ Vt @ R.T
            K = np.linalg.solve(H @ P @ H.T + Mo, H @ P).T
            IKH = eye - K @ H
        S = IKH @ P @ IKH.T + K @ Mo @ K.T
        S = 0.5 * (S + S.T)
    return float(np.trace(P if predicted else S))


def _noises(setup: Setup, means: np.ndarray, q: np.ndarray):
    """(W (T, 6, 6) with the joint-space term, V (T, 6, 6) or None where it depends on the
    prediction, (F, Q, H, R) each (T, 6, 6) or None for identity maps) at the means, each map
    evaluated on its own (the finite-difference check's path; `certify` takes them from its
    Function)."""
    model = setup.model
    T = len(means) - 1
    a, b = means[:-1].T, means[1:].T
    W = _blocks(_mapped(model, "motion_noise", T)(a, b), T)
    joint = setup.joint_noises(q)
    if joint is not None:
        W = W + unvech_many(joint)
    maps = (None if model.identity_maps
            else tuple(_blocks(m, T) for m in _mapped(model, "jacobians", T)(a, b)))
    V = (_blocks(_mapped(model, "observation_noise", T)(b), T)
         if model.noise.observation_noise == "mean" else None)
    return W, V, maps


_MAPS: dict[tuple, ca.Function] = {}


def _mapped(model, name: str, T: int) -> ca.Function:
    """The model's Function `name` mapped over T waypoints (cached per model and T)."""
    key = (model.key(), model.identity_maps, name, T)
    if key not in _MAPS:
        _MAPS[key] = getattr(model, name).map(T)
    return _MAPS[key]


def _blocks(M, T: int) -> np.ndarray:
    """(T, 6, 6) from a mapped Function's 6 x 6T output."""
    return np.asarray(M, float).reshape(NX, T, NX).transpose(1, 0, 2)


def _out_blocks(v: np.ndarray, T: int) -> np.ndarray:
    """(T, 6, 6) from the flat (column-major) values of a 6 x 6T output."""
    return v.reshape(T, NX, NX).transpose(0, 2, 1)


def _fd_gradient(setup: Setup, q: np.ndarray, ref: float, step: float) -> np.ndarray:
    """The gradient of f by central differences, f by the NumPy EKF along the means of q (the
    moving joints of q_1..q_T; zeros elsewhere)."""
    def f(x: np.ndarray) -> float:
        qx = x.reshape(q.shape)
        dq = np.diff(qx, axis=0)
        return (numpy_trace(setup, setup.means_of(qx), qx) / ref
                + setup.ocp.smoothness * float(np.sum(dq * dq)))

    x, g = q.ravel().copy(), np.zeros(q.size)
    nq = q.shape[1]
    for t in range(1, len(q)):
        for j in setup.robot.supporting_joints():
            i = t * nq + j
            e = np.zeros_like(x)
            e[i] = step
            g[i] = (f(x + e) - f(x - e)) / (2 * step)
    return g
