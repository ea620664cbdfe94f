"""IPOPT's derivatives of the condensed transcription, built stage-wise (`hessian: surrogate` or
`gauss-newton`): the objective's gradient, the constraint Jacobian and a structured Hessian of the
Lagrangian (`staged_derivatives`).

The objective is S(c(mu)): S, the trace after the scalar Kalman recursions, as a function of the
noise coefficients c (each the squared norm of a residual e(mu)). S is concave and nondecreasing
in c. `surrogate`: drop S's own curvature, keep the coefficients' exact one,
`sum_k (dS/dc_k) Hess c_k`: the Hessian of the majorize-minimise surrogate
`sum_k (dS/dc_k) c_k(mu)` (S lies below its tangent). `gauss-newton`: drop the residuals'
curvature too, `sum_k (dS/dc_k) 2 J_k^T J_k`, positive semidefinite. Both are block tridiagonal in
the means (each c_k depends on two consecutive ones). The gradient is exact:
`sum_k (dS/dc_k) grad c_k`.

Each derivative is one small SX Function per interval (the means at both ends) or per node (the
kinematic constraint `mu_t - pose(q_t)`), mapped over the horizon and scattered into the global
sparsity by a constant sparse matrix (`stages.py`); only the recursion's weights dS/dc see the
whole horizon. The expression graphs, and the C code of `solver.codegen`, hold each stage once
whatever the horizon. The limit rows' stages: `transcription_limits.py`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.belief import NM, NV, vech
from ..model.joint_noise import joint_noise_expr, joint_noise_factor, weight_matrix
from ..model.robot import CAMERA_PARAMETERS
from .stages import assemble, entries, smoothness_matrix
from .surrogate import interval_terms, recursion_weights
from .transcription_limits import limit_stages


def staged_derivatives(tr, pose: ca.Function, sigma0, trace_ref, smoothness) -> dict:
    """IPOPT's `grad_f`, `jac_g` and `hess_lag` of the transcription `tr` (module docstring), its
    pose Function, Sigma_0's and the trace reference's symbols and the smoothness weight."""
    stages = _Stages(tr, pose, sigma0, trace_ref, smoothness)
    grad_f = stages.gradient()
    jac_g = stages.jacobian()
    hess_lag = stages.hessian()
    return {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}


def _interval_stages(m, hessian: str) -> tuple:
    """The interval's stage Functions of the means at both ends `(a, b)`: the noise coefficients,
    the gradient and the curvature (`hessian`: surrogate or Gauss-Newton) of the weighted
    coefficients; and the joint-space term's weights `wj` and symbol (None without it)."""
    a, b = ca.SX.sym("a", NM), ca.SX.sym("b", NM)
    # the joint-space term: its own (q_t, q_t+1) stage
    jv = ca.SX.sym("w_q", NV) if m.joint_noise else None
    (res_m, res_o), coefficients, (wm, wo, wj), weighted = interval_terms(m, a, b, jv)
    coef = ca.Function("coef", [a, b], list(coefficients[:2]))
    ab = ca.vertcat(a, b)
    if hessian == "surrogate":  # exact curvature of the weighted coefficients
        block = ca.hessian(weighted, ab)[0]
    else:  # Gauss-Newton: the residuals' curvature dropped too
        block = sum(2 * wm[k] * ca.mtimes(ca.jacobian(e, ab).T, ca.jacobian(e, ab))
                    for k, e in enumerate(res_m))
        block += sum(2 * wo[k] * ca.mtimes(ca.jacobian(e, ab).T, ca.jacobian(e, ab))
                     for k, e in enumerate(res_o))
    if jv is not None:  # the means' terms do not depend on it
        weighted, block = (ca.substitute(weighted, jv, ca.DM.zeros(NV)),
                           ca.substitute(block, jv, ca.DM.zeros(NV)))
    interval_grad = ca.Function("interval_grad", [a, b, wm, wo],
                                [ca.densify(ca.gradient(weighted, ab))])
    interval_hess = ca.Function("interval_hess", [a, b, wm, wo], [ca.densify(block)])
    return coef, interval_grad, interval_hess, wj, jv


def joint_stages(tr, wj, Tcb) -> dict:
    """The joint-space motion noise's stage Functions of `(q_t, q_t+1)`: its vech (the
    recursion's coefficients `cj`), and the gradient and Hessian of the surrogate's term
    `wj . vech(W_q)` with the weights frozen (the Hessian: exact, or Gauss-Newton's
    `2 sum_k du_k^T G du_k` with `W_q = sum_k u_k u_k^T`, G = dS/dW)."""
    nq = tr.robot.nq
    qab = ca.SX.sym("qab", 2 * nq)
    w = vech(joint_noise_expr(tr.robot, tr.model.noise.joint_sigma, qab[:nq], qab[nq:],
                              Tcb))
    term = ca.dot(wj, w)
    if tr.hessian == "surrogate":
        hess = ca.hessian(term, qab)[0]
    else:
        G = weight_matrix(wj)
        U = joint_noise_factor(tr.robot, tr.model.noise.joint_sigma, qab[:nq], qab[nq:],
                               Tcb)
        hess = 0
        for k in range(nq):
            dU = ca.jacobian(U[:, k], qab)
            hess += 2 * dU.T @ G @ dU
    return {"coef": ca.Function("joint_coef", [qab, Tcb], [w]),
            "grad": ca.Function("joint_grad", [qab, wj, Tcb],
                                [ca.densify(ca.gradient(term, qab))]),
            "hess": ca.Function("joint_hess", [qab, wj, Tcb], [ca.densify(hess)])}


class _Stages:
    """The symbolic NLP over the mapped stage Functions of one transcription: the decision vector,
    the parameters and the multipliers as MX, the stages' values along them, and where each
    stage's entries go."""

    def __init__(self, tr, pose: ca.Function, sigma0, trace_ref, smoothness):
        m, T, nq = tr.model, tr.T, tr.robot.nq
        self.tr, self.T, self.pose, self.smoothness = tr, T, pose, smoothness
        self.n = n = tr.layout.vector().shape[0]
        weights = recursion_weights(m, T, sigma0, trace_ref)
        coef, interval_grad, interval_hess, wj, jv = _interval_stages(m, tr.hessian)
        q, lam, Tcb = (ca.SX.sym("q", nq), ca.SX.sym("lam", NM),
                       ca.SX.sym("camera", CAMERA_PARAMETERS))
        self.q, self.Tcb = q, Tcb
        # g_t = mu_t - pose(q_t): Jacobian -d pose/dq (and I in the mean); curvature -Hess(lam .
        # pose)
        node_jac = ca.Function("node_jac", [q, Tcb], [ca.densify(-ca.jacobian(pose(q, Tcb), q))])
        node_hess = ca.Function("node_hess", [q, lam, Tcb],
                                [ca.densify(ca.hessian(-ca.dot(lam, pose(q, Tcb)), q)[0])])

        # Where each stage output's entries go (column-major within each stage block).
        offsets = dict(zip((name for name, _, _ in tr.layout.blocks),
                           np.cumsum([0] + [size for _, size, _ in tr.layout.blocks])))
        self.mu_idx = mu_idx = [np.arange(offsets[f"mu{t}"], offsets[f"mu{t}"] + NM)
                                for t in range(T + 1)]
        self.q_idx = q_idx = [np.arange(offsets[f"q{t}"], offsets[f"q{t}"] + nq)
                              for t in range(T + 1)]
        self.ab_idx = [np.concatenate([mu_idx[t], mu_idx[t + 1]]) for t in range(T)]
        self.g_idx = [np.arange(NM * t, NM * (t + 1)) for t in range(T + 1)]

        self.D = D = smoothness_matrix(n, q_idx, smoothness)

        self.X, self.P = X, P = ca.MX.sym("x", n), ca.MX.sym("p", tr.p.shape[0])
        self.lam_f, self.lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", tr.ng)
        lam_g = self.lam_g
        Tcb_x, sigma0_x, ref_x = ca.Function("params", [tr.p],
                                             [tr.p[:CAMERA_PARAMETERS], sigma0, trace_ref])(P)
        self.Tcb_x = Tcb_x
        self.mus = mus = ca.horzcat(*[X[i[0]:i[0] + NM] for i in mu_idx])
        self.qs = qs = ca.horzcat(*[X[i[0]:i[0] + nq] for i in q_idx])
        self.qq_idx = [np.concatenate([q_idx[t], q_idx[t + 1]]) for t in range(T)]
        self.qab_x = qab_x = ca.vertcat(qs[:, :T], qs[:, 1:])
        self.joint = joint = joint_stages(tr, wj, Tcb) if jv is not None else None
        cj = joint["coef"].map(T)(qab_x, Tcb_x) if joint else ca.MX(0, T)
        S_x, w_m, w_o, self.w_j = weights(*coef.map(T)(mus[:, :T], mus[:, 1:]), cj, sigma0_x,
                                          ref_x)
        self.S_x = S_x
        self.G = interval_grad.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        self.B = interval_hess.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        self.Jq = node_jac.map(T + 1)(qs, Tcb_x)
        self.K = node_hess.map(T + 1)(qs, ca.reshape(lam_g[:NM * (T + 1)], NM, T + 1), Tcb_x)
        self.smooth_f = 0.5 * ca.bilin(ca.DM(D), X, X) if smoothness > 0 else 0
        self.limit_hess = None  # the limit rows' Hessian entries and blocks (`jacobian`)

    def gradient(self) -> ca.Function:
        """`nlp_grad_f`: the objective and its gradient (exact)."""
        n, T, joint = self.n, self.T, self.joint
        grad_parts = ([entries([(i, [0]) for i in self.ab_idx])]
                      + ([entries([(i, [0]) for i in self.qq_idx])] if joint else []))
        grad_sp, sc_g, _ = assemble((n, 1), grad_parts)
        grad_nz = ca.mtimes(sc_g[0], ca.vec(self.G))
        if joint:
            grad_nz += ca.mtimes(sc_g[1], ca.vec(joint["grad"].map(T)(self.qab_x, self.w_j,
                                                                        self.Tcb_x)))
        grad = ca.MX(grad_sp, grad_nz)
        if self.smoothness > 0:
            grad = ca.densify(grad) + ca.mtimes(ca.DM(self.D), self.X)
        return ca.Function("nlp_grad_f", [self.X, self.P], [self.S_x + self.smooth_f,
                                                           ca.densify(grad)], ["x", "p"],
                           ["f", "grad"])

    def jacobian(self) -> ca.Function:
        """`nlp_jac_g`: the constraint rows (kinematic, then the limit rows) and their Jacobian."""
        tr, n, T, q, Tcb = self.tr, self.n, self.T, self.q, self.Tcb
        jac_parts = [entries(list(zip(self.g_idx, self.q_idx))),
                     entries(list(zip(self.g_idx, self.mu_idx)))]
        g_x = ca.vec(self.mus - ca.Function("poses", [q, Tcb], [self.pose(q, Tcb)]).map(T + 1)(
            self.qs, self.Tcb_x))
        lin_const, g_lim = None, []
        # the limit rows: A x (constant Jacobian), then the tool rows per point
        if tr.limits is not None:
            jac_part, hess_part, lin_const, Jt, Ht, g_lim = limit_stages(
                tr, self.X, self.lam_g, self.q_idx, n)
            jac_parts.append(jac_part)
            self.limit_hess = hess_part, Ht
        jac_sp, sc_j, jconst = assemble((tr.ng, n), jac_parts, lin_const)
        J_nz = (ca.mtimes(sc_j[0], ca.vec(self.Jq))
                + ca.mtimes(sc_j[1], ca.DM(np.tile(np.eye(NM).ravel(order="F"), T + 1))))
        if tr.limits is not None:
            J_nz += jconst + ca.mtimes(sc_j[2], ca.vec(Jt))
        return ca.Function("nlp_jac_g", [self.X, self.P],
                           [ca.vertcat(g_x, *g_lim), ca.MX(jac_sp, J_nz)], ["x", "p"],
                           ["g", "jac"])

    def hessian(self) -> ca.Function:
        """`nlp_hess_l`: the structured Hessian of the Lagrangian (upper triangle; after
        `jacobian`, which builds the limit rows' blocks)."""
        n, T, joint, lam_f = self.n, self.T, self.joint, self.lam_f
        hess_parts = [entries([(i, i) for i in self.ab_idx]),
                      entries([(i, i) for i in self.q_idx])]
        if self.limit_hess is not None:
            hess_parts.append(self.limit_hess[0])
        if joint:
            hess_parts.append(entries([(i, i) for i in self.qq_idx]))
        hess_sp, sc_h, const = assemble((n, n), hess_parts, np.triu(self.D))
        sc_b, sc_k = sc_h[:2]
        H_nz = (lam_f * (ca.mtimes(sc_b, ca.vec(self.B)) + const)
                + ca.mtimes(sc_k, ca.vec(self.K)))
        if self.limit_hess is not None:
            H_nz += ca.mtimes(sc_h[2], ca.vec(self.limit_hess[1]))
        if joint:
            H_nz += lam_f * ca.mtimes(sc_h[-1], ca.vec(joint["hess"].map(T)(self.qab_x, self.w_j,
                                                                             self.Tcb_x)))
        return ca.Function("nlp_hess_l", [self.X, self.P, lam_f, self.lam_g],
                           [ca.MX(hess_sp, H_nz)], ["x", "p", "lam_f", "lam_g"], ["hess"])
