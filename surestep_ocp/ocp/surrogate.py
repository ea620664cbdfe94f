"""Pieces shared by the two OCP solvers (IPOPT's structured Hessian in `ocp.py`, the projected
Newton solver in `newton.py`): the kinematic pose map, the scalar Kalman recursion, its weights, and
the per-interval noise coefficients whose weighted sum is the majorize-minimise surrogate.

With the paper's constants the EKF is six scalar recursions, and `Tr(Sigma_T) = S(c)` with `c` the
noise coefficients (squared norms of residuals of the means, per interval); `S` is concave and
nondecreasing in `c`, so `sum_k dS/dc_k c_k(mu)` with the weights frozen majorises it
(docs/hessian_and_newton.md, "The Hessian").
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.belief import DIAG, NV, NX, BeliefModel, posterior, trace_vech, unvech, vech
from ..model.robot import Robot
from .codegen import SX_OPTIONS


def pose_function(robot: Robot) -> ca.Function:
    """`pose(q, camera) -> mean` of the tracked frame in the camera frame (`Robot.camera_pose`)."""
    return robot.camera_pose


def scalar_trace(sigma0, motion: list, observation: list, predicted: bool):
    """Trace after the six scalar Kalman recursions `s+ = p v / (p + v)`, `p = s + w_t`,
    `v = v_t(p)`.

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
    """`S^-1 B` for a symmetric positive definite SX matrix S, by a Cholesky factorisation written
    out in elementary operations (fewer instructions than `casadi.solve`'s symbolic QR:
    docs/general_models.md)."""
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
    """Symbols `sigma` (vech), `c` (motion coefficients, observation ones, then the vech of the
    joint-space motion noise if the model has it), the prediction `P = F Sigma F^T + Q W Q^T`, the
    observation noise `M = R V R^T`, the gain `K = P H^T (H P H^T + M)^-1` with
    `W = sum_k c_k W_k (+ W_q)`, `V = V_min + sum_k c_k V_k`, and the constant maps."""
    F, Q, H, R = (ca.DM(M) for M in model.constant_maps)
    Wm, Vm = model.motion_matrices(), model.observation_matrices()
    s, c = ca.SX.sym("sigma", NV), ca.SX.sym("c", len(Wm) + len(Vm) + joint_size(model))
    W = sum(c[k] * ca.DM(M) for k, M in enumerate(Wm))
    if model.joint_noise:
        W = W + unvech(c[len(Wm) + len(Vm):])
    V = ca.DM(model.noise.V_min) + sum(c[len(Wm) + k] * ca.DM(M) for k, M in enumerate(Vm))
    P = F @ unvech(s) @ F.T + Q @ W @ Q.T
    M = R @ V @ R.T
    K = spd_solve(H @ P @ H.T + M, H @ P).T
    return s, c, P, M, K, (F, Q, H, R), (Wm, Vm)


def joint_size(model: BeliefModel) -> int:
    """Entries of the joint-space motion noise among a step's coefficients: its vech (21), or
    none."""
    return NV if model.joint_noise else 0


def _unit_vech(v: int) -> np.ndarray:
    """The symmetric matrix whose vech is the v-th unit vector (d unvech(c) / d c_v)."""
    e = np.zeros(NV)
    e[v] = 1.0
    return unvech(e)


def kalman_stage(model: BeliefModel) -> ca.Function:
    """One step of the matrix Kalman recursion with the model's constant maps (F, Q, H, R), as a
    function of the noise coefficients: `(sigma, c) -> (sigma+, sigma_pred)` (vech), `Sigma+` the
    model's own update without cancellation (`belief.posterior`: `P - K H P` lost definiteness at
    extreme noise scales)."""
    s, c, P, M, _, (_, _, H, _), _ = _stage_symbols(model)
    post = posterior(P, H, M, model.observation_inverse, solve=spd_solve)
    return ca.Function("kalman_stage", [s, c], [vech(post), vech(P)],
                       ["sigma", "c"], ["sigma_next", "sigma_pred"])


def kalman_stage_jacobian(model: BeliefModel) -> ca.Function:
    """`(sigma, c) -> d sigma+ / d(sigma, c)` (21 x (21 + nc)) of `kalman_stage`, by the first-order
    perturbation of the Riccati update at the Kalman gain, `d Sigma+ = A dP A^T + K R dV R^T K^T`
    with `A = I - K H` (the gain's own variation drops out, it is optimal): each column a congruence
    of one base matrix, in far fewer instructions than AD through the symbolic 6x6 solve
    (docs/general_models.md)."""
    s, c, _, _, K, (F, Q, H, R), (Wm, Vm) = _stage_symbols(model)
    A = ca.DM.eye(NX) - K @ H
    B, AQ, KR = A @ F, A @ Q, K @ R
    cols = []
    for j in range(NX):  # vech order: column-major lower triangle
        for i in range(j, NX):
            E = B[:, i] @ B[:, j].T
            cols.append(vech(E + E.T) if i != j else vech(E))
    cols += [vech(AQ @ ca.DM(M) @ AQ.T) for M in Wm] + [vech(KR @ ca.DM(M) @ KR.T) for M in Vm]
    cols += [vech(AQ @ ca.DM(_unit_vech(v)) @ AQ.T) for v in range(joint_size(model))]
    return ca.Function("kalman_stage_jac", [s, c], [ca.horzcat(*cols)], ["sigma", "c"], ["jac"])


def recursion_weights(model: BeliefModel, T: int, sigma0, trace_ref) -> ca.Function:
    """`weights(cm, co, cj, sigma0, trace_ref) -> (S, dS/dcm, dS/dco, dS/dcj)`: the scaled trace
    after the Kalman recursions as a function of the (motion, observation, joint-space) coefficient
    matrices (one column per interval; `cj` the vech of the joint-space motion noise, no rows
    without it), and its gradient, the surrogate's weights. `sigma0` and `trace_ref` are the
    caller's SX symbols (`BeliefModel.recursion_sigma0` gives sigma0's value).

    A scalar model runs six scalar recursions; any other structured model (`BeliefModel.structured`:
    constant maps, any SPD base matrices, the joint-space term) the 6x6 matrix recursion, concave
    and nondecreasing in c too (in the joint-space term's matrix: `dS/dW` is positive semidefinite).
    """
    Wm, Vm = model.motion_matrices(), model.observation_matrices()
    nm, no, nj = len(Wm), len(Vm), joint_size(model)
    cm, co, cj = ca.SX.sym("cm", nm, T), ca.SX.sym("co", no, T), ca.SX.sym("cj", nj, T)
    floor = model.noise.V_min
    predicted = model.noise.objective == "predicted"
    if model.scalar:
        Wd, Vd = [ca.DM(np.diag(M)) for M in Wm], [ca.DM(np.diag(M)) for M in Vm]
        S = scalar_trace(sigma0, [sum(cm[k, t] * Wd[k] for k in range(nm)) for t in range(T)],
                         [lambda p, t=t: ca.DM(np.diag(floor))
                          + sum(co[k, t] * Vd[k] for k in range(no))
                          for t in range(T)], predicted)
    else:  # stage-wise (mapaccum): the generated code holds one Kalman step whatever T
        cm, co, cj = ca.MX.sym("cm", nm, T), ca.MX.sym("co", no, T), ca.MX.sym("cj", nj, T)
        sigma0, trace_ref = ca.MX.sym("sigma0", NV), ca.MX.sym("trace_ref")
        post, pred = kalman_stage(model).mapaccum("kalman_roll", T)(sigma0, ca.vertcat(cm, co, cj))
        S = trace_vech((pred if predicted else post)[:, T - 1])
    S = S / trace_ref
    grads = [ca.jacobian(S, ca.vec(c)).reshape(c.shape) if c.numel() else type(S).zeros(0, T)
             for c in (cm, co, cj)]
    return ca.Function("weights", [cm, co, cj, sigma0, trace_ref], [S, *grads], SX_OPTIONS)


def interval_terms(model: BeliefModel, a, b, joint=None):
    """For the means `a`, `b` at both ends of an interval (and `joint`, the vech of the joint-space
    motion noise of its joints, when the model has it): the residuals `(motion, observation)` whose
    squared norms are the noise coefficients, the coefficient vectors
    `(motion, observation, joint)`, the weight symbols `(wm, wo, wj)` and the weighted sum `sum_k
    wm_k |e_k|^2 + sum_k wo_k |e_k|^2 + wj . joint` (the surrogate's interval term:
    `wj = dS/d vech(W_q)`, so `wj . vech(W_q) = <dS/dW, W_q>`)."""
    if (joint is not None) != model.joint_noise:
        raise ValueError("interval_terms: the joint-space motion noise is given exactly when "
                         "the model has it")
    res_m = model.motion_residuals(a, b)
    res_o = [e for e, _ in model.observation_residuals(b)]
    wm, wo, wj = (ca.SX.sym("wm", len(res_m)), ca.SX.sym("wo", len(res_o)),
                  ca.SX.sym("wj", joint_size(model)))
    cj = joint if joint is not None else ca.SX(0, 1)
    coefficients = (ca.vertcat(*[ca.sumsqr(e) for e in res_m]),
                    ca.vertcat(*[ca.sumsqr(e) for e in res_o]), cj)
    weighted = (sum(wm[k] * ca.sumsqr(e) for k, e in enumerate(res_m))
                + sum(wo[k] * ca.sumsqr(e) for k, e in enumerate(res_o)))
    if joint is not None:
        weighted += ca.dot(wj, joint)
    return (res_m, res_o), coefficients, (wm, wo, wj), weighted
