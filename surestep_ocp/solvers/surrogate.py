"""Pieces shared by the two OCP solvers (IPOPT's structured Hessian in `ocp.py`, the projected Newton
solver in `newton.py`): the kinematic pose map, the scalar Kalman recursion, its weights, and the
per-interval noise coefficients whose weighted sum is the majorize-minimise surrogate.

With the paper's constants the EKF is six scalar recursions, and `Tr(Sigma_T) = S(c)` with `c` the
noise coefficients (squared norms of residuals of the means, per interval); `S` is concave and
nondecreasing in `c`, so `sum_k dS/dc_k c_k(mu)` with the weights frozen majorises it (docs/hessian_and_newton.md,
"The Hessian").
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.belief import DIAG, NV, NX, BeliefModel, trace_vech, unvech, vech
from ..model.robot import Robot


def pose_function(robot: Robot) -> ca.Function:
    """`pose(q, camera) -> mean` of the tracked frame in the camera frame (`Robot.camera_pose`)."""
    return robot.camera_pose


def scalar_trace(sigma0, motion: list, observation: list, predicted: bool):
    """Trace after the six scalar Kalman recursions `s+ = p v / (p + v)`, `p = s + w_t`, `v = v_t(p)`.

    `sigma0`: the vech parameter whose diagonal holds the channel variances; `motion[t]`: the six
    motion noises of step t; `observation[t](p)`: the six observation noises given the prediction.
    With `predicted`, the trace of the last prediction (before the last observation).
    """
    s = ca.vertcat(*[sigma0[i] for i in DIAG])
    for w, v_of in zip(motion, observation):
        p = s + w
        v = v_of(p)
        s = p * v / (p + v)
    return ca.sum1(p if predicted else s)


def spd_solve(S, B):
    """`S^-1 B` for a symmetric positive definite SX matrix S, by a Cholesky factorisation written out in
    elementary operations (870 instructions for 6x6 against 1580 for `casadi.solve`'s symbolic QR)."""
    n = S.shape[0]
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        L[j][j] = ca.sqrt(S[j, j] - sum(L[j][k] ** 2 for k in range(j)))
        for i in range(j + 1, n):
            L[i][j] = (S[i, j] - sum(L[i][k] * L[j][k] for k in range(j))) / L[j][j]
    cols = []
    for c in range(B.shape[1]):
        y = [None] * n
        for i in range(n):
            y[i] = (B[i, c] - sum(L[i][k] * y[k] for k in range(i))) / L[i][i]
        x = [None] * n
        for i in reversed(range(n)):
            x[i] = (y[i] - sum(L[k][i] * x[k] for k in range(i + 1, n))) / L[i][i]
        cols.append(ca.vertcat(*x))
    return ca.horzcat(*cols)


def _stage_symbols(model: BeliefModel):
    """Symbols `sigma` (vech), `c` (motion coefficients, then observation ones), the prediction
    `P = F Sigma F^T + Q W Q^T`, the gain `K = P H^T (H P H^T + R V R^T)^-1` with `W = sum_k c_k W_k`,
    `V = V_min + sum_k c_k V_k`, and the constant maps."""
    F, Q, H, R = (ca.DM(M) for M in model.constant_maps)
    Wm, Vm = model.motion_matrices(), model.observation_matrices()
    s, c = ca.SX.sym("sigma", NV), ca.SX.sym("c", len(Wm) + len(Vm))
    W = sum(c[k] * ca.DM(M) for k, M in enumerate(Wm))
    V = ca.DM(model.noise.V_min) + sum(c[len(Wm) + k] * ca.DM(M) for k, M in enumerate(Vm))
    P = F @ unvech(s) @ F.T + Q @ W @ Q.T
    K = spd_solve(H @ P @ H.T + R @ V @ R.T, H @ P).T
    return s, c, P, K, (F, Q, H, R), (Wm, Vm)


def kalman_stage(model: BeliefModel) -> ca.Function:
    """One step of the matrix Kalman recursion with the model's constant maps (F, Q, H, R), as a function of the
    noise coefficients: `(sigma, c) -> (sigma+, sigma_pred)` (vech), `Sigma+ = P - K H P` (symmetrised)."""
    s, c, P, K, (_, _, H, _), _ = _stage_symbols(model)
    post = P - K @ H @ P
    return ca.Function("kalman_stage", [s, c], [vech(0.5 * (post + post.T)), vech(P)], ["sigma", "c"],
                       ["sigma_next", "sigma_pred"])


def kalman_stage_jacobian(model: BeliefModel) -> ca.Function:
    """`(sigma, c) -> d sigma+ / d(sigma, c)` (21 x (21 + nc)) of `kalman_stage`, by the first-order
    perturbation of the Riccati update at the Kalman gain, `d Sigma+ = A dP A^T + K R dV R^T K^T` with
    `A = I - K H` (the gain's own variation drops out, it is optimal): each column a congruence of one
    base matrix. AD through the symbolic 6x6 solve gave 47k instructions against about 4k here."""
    s, c, _, K, (F, Q, H, R), (Wm, Vm) = _stage_symbols(model)
    A = ca.DM.eye(NX) - K @ H
    B, AQ, KR = A @ F, A @ Q, K @ R
    cols = []
    for j in range(NX):  # vech order: column-major lower triangle
        for i in range(j, NX):
            E = B[:, i] @ B[:, j].T
            cols.append(vech(E + E.T) if i != j else vech(E))
    cols += [vech(AQ @ ca.DM(M) @ AQ.T) for M in Wm] + [vech(KR @ ca.DM(M) @ KR.T) for M in Vm]
    return ca.Function("kalman_stage_jac", [s, c], [ca.horzcat(*cols)], ["sigma", "c"], ["jac"])


def recursion_weights(model: BeliefModel, T: int, sigma0, trace_ref) -> ca.Function:
    """`weights(cm, co, sigma0, trace_ref) -> (S, dS/dcm, dS/dco)`: the scaled trace after the Kalman
    recursions as a function of the (motion, observation) coefficient matrices (one column per interval),
    and its gradient, the surrogate's weights. `sigma0` and `trace_ref` are the caller's SX symbols
    (`BeliefModel.recursion_sigma0` gives sigma0's value).

    A scalar model runs six scalar recursions; any other structured model (`BeliefModel.structured`:
    constant maps, any SPD base matrices) the 6x6 matrix recursion, concave and nondecreasing in c too.
    """
    Wm, Vm = model.motion_matrices(), model.observation_matrices()
    nm, no = len(Wm), len(Vm)
    cm, co = ca.SX.sym("cm", nm, T), ca.SX.sym("co", no, T)
    floor = model.noise.V_min
    predicted = model.noise.objective == "predicted"
    if model.scalar:
        Wd, Vd = [ca.DM(np.diag(M)) for M in Wm], [ca.DM(np.diag(M)) for M in Vm]
        S = scalar_trace(sigma0, [sum(cm[k, t] * Wd[k] for k in range(nm)) for t in range(T)],
                         [lambda p, t=t: ca.DM(np.diag(floor)) + sum(co[k, t] * Vd[k] for k in range(no))
                          for t in range(T)], predicted)
    else:  # stage-wise (mapaccum): the generated code holds one Kalman step whatever T
        cm, co = ca.MX.sym("cm", nm, T), ca.MX.sym("co", no, T)
        sigma0, trace_ref = ca.MX.sym("sigma0", NV), ca.MX.sym("trace_ref")
        post, pred = kalman_stage(model).mapaccum("kalman_roll", T)(sigma0, ca.vertcat(cm, co))
        S = trace_vech((pred if predicted else post)[:, T - 1])
    S = S / trace_ref
    return ca.Function("weights", [cm, co, sigma0, trace_ref],
                       [S, ca.jacobian(S, ca.vec(cm)).reshape((nm, T)), ca.jacobian(S, ca.vec(co)).reshape((no, T))])


def interval_terms(model: BeliefModel, a, b):
    """For the means `a`, `b` at both ends of an interval: the residuals `(motion, observation)` whose
    squared norms are the noise coefficients, the coefficient vectors, and the weight symbols `(wm, wo)`
    with the weighted sum `sum_k wm_k |e_k|^2 + sum_k wo_k |e_k|^2` (the surrogate's interval term)."""
    res_m = model.motion_residuals(a, b)
    res_o = [e for e, _ in model.observation_residuals(b)]
    wm, wo = ca.SX.sym("wm", len(res_m)), ca.SX.sym("wo", len(res_o))
    coefficients = (ca.vertcat(*[ca.sumsqr(e) for e in res_m]), ca.vertcat(*[ca.sumsqr(e) for e in res_o]))
    weighted = (sum(wm[k] * ca.sumsqr(e) for k, e in enumerate(res_m))
                + sum(wo[k] * ca.sumsqr(e) for k, e in enumerate(res_o)))
    return (res_m, res_o), coefficients, (wm, wo), weighted
