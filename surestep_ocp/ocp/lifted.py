"""The lifted multiple-shooting OCP: vech(Sigma_t) as node variables, the Kalman step as the
shooting constraint.

Per node t: joints `q_t`, mean `mu_t` (position and unit quaternion, `Robot.camera_pose`) and
`s_t = vech(Sigma_t) / scale_t` (21 numbers, scaled by the initial guess's covariance size).
Constraints:

    mu_t - pose(q_t) = 0                                   every node (kinematics)
    Phi(scale_t s_t, c(mu_t, mu_t+1)) / scale_t+1 - s_t+1 = 0   every interval (the EKF step)
    bounds: joints, minimum depth, q_0, mu_0, s_0 = Sigma_0, mu_T = x^G (hard)

with `Phi(Sigma, c) = P - P H^T (H P H^T + R V R^T)^-1 H P`, `P = F Sigma F^T + Q W Q^T`,
`W = sum_k c_k W_k`, `V = V_min + sum_k c_k V_k` and `c` the scalar noise coefficients (squared
residuals of the means). Objective: `scale_T Tr(s_T) / Tr_ref` (linear) plus the joint smoothness.

The Hessian: `Tr(Sigma_T)` along the shooting constraints is `S(c)`, concave and nondecreasing in
the coefficients (`BeliefModel.structured`); its curvature in c makes the exact Hessian of the
Lagrangian indefinite. The structured Hessian is the condensed surrogate's,
`sum_k w_tk Hess c_k(mu_t, mu_t+1)` with the weights `w = dS/dc` of the recursion along the current
means (`surrogate.recursion_weights`), plus the kinematic curvature; zero in the covariance block
(the shooting constraints, Jacobian -I in s_t+1, determine it). At a KKT point these weights equal
`(dPhi_t/dc)^T lam_t`, so it is the Lagrangian's Hessian without the concave part of `lam . Phi`; a
converged point is a KKT point of the lifted NLP. Every derivative is one small Function per
interval or node, mapped and scattered (`stages.py`), compiled with `solver.codegen`.

Where it converges: near a solution (the strategy in `ocp.py` starts it at the condensed solution,
with the adjoint recursion's multipliers). From the straight line IPOPT's filter accepts first steps
whose covariances are far from the recursion; the trace variable goes negative and it does not
recover (docs/general_models.md).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import scipy.sparse.linalg

from ..model.belief import DIAG, NM, NV, NX, BeliefModel, unvech, vech
from ..model.robot import CAMERA_PARAMETERS, Robot
from ..output.solution import Solution
from ..problem.setup import Setup
from ..buffered import thread_buffered
from .codegen import compiled_or_interpreted
from .stages import assemble, entries, smoothness_matrix
from .surrogate import (
    interval_terms,
    kalman_stage,
    kalman_stage_jacobian,
    pose_function,
    recursion_weights,
)
from .transcription import ipopt_solution


def _stage_functions(model: BeliefModel, stage: ca.Function, pose: ca.Function, nq: int) -> dict:
    """The lifted NLP's stage Functions: per interval (`a`, `b` the means at both ends, `s` the
    scaled covariance, `sc0`, `sc1` the scales) the shooting constraint `g`, its Jacobian `jac`
    and the surrogate's curvature `hess`; per node the kinematic constraint's `node_jac` and
    `node_hess`; the noise coefficients `coef` (the motion ones first, `nm` of them)."""
    # ---- interval functions: (a, b) the means at both ends, s the scaled covariance, sc0/sc1
    # the scales
    a, b, s = ca.SX.sym("a", NM), ca.SX.sym("b", NM), ca.SX.sym("s", NV)
    sc0, sc1 = ca.SX.sym("sc0"), ca.SX.sym("sc1")
    (_, _), coefficients, (wm, wo, _), weighted = interval_terms(model, a, b)
    c = ca.vertcat(*coefficients)
    g_int = stage(sc0 * s, c)[0] / sc1
    coef = ca.Function("lifted_coef", [a, b], [c])
    interval_g = ca.Function("lifted_g", [a, b, s, sc0, sc1], [g_int])
    Jsc = kalman_stage_jacobian(model)(sc0 * s, c) / sc1  # d g / d(Sigma, c)
    Jab = ca.mtimes(Jsc[:, NV:], ca.jacobian(c, ca.vertcat(a, b)))
    interval_jac = ca.Function("lifted_jac", [a, b, s, sc0, sc1],
                               [ca.densify(ca.horzcat(Jab, sc0 * Jsc[:, :NV]))])
    interval_hess = ca.Function("lifted_hess", [a, b, wm, wo],
                                [ca.densify(ca.hessian(weighted, ca.vertcat(a, b))[0])])
    q, lk, Tcb = ca.SX.sym("q", nq), ca.SX.sym("lk", NM), ca.SX.sym("camera", CAMERA_PARAMETERS)
    node_jac = ca.Function("lifted_node_jac", [q, Tcb],
                           [ca.densify(-ca.jacobian(pose(q, Tcb), q))])
    node_hess = ca.Function("lifted_node_hess", [q, lk, Tcb],
                            [ca.densify(ca.hessian(-ca.dot(lk, pose(q, Tcb)), q)[0])])
    return {"coef": coef, "nm": wm.shape[0], "g": interval_g, "jac": interval_jac,
            "hess": interval_hess, "node_jac": node_jac, "node_hess": node_hess}


class LiftedTranscription:
    """The lifted NLP of one structure (robot, structured belief model, horizon, smoothness), built
    once."""

    form = "full"
    hessian = "surrogate"

    def __init__(self, robot: Robot, model: BeliefModel, horizon: int, smoothness: float,
                 options: dict, codegen: bool = False, codegen_required: bool = False):
        if not model.structured or model.noise.objective != "posterior" or model.joint_noise:
            raise ValueError("the lifted form's structured Hessian needs a structured model "
                             "without joint-space noise minimising Tr(Sigma_T|T) "
                             "(solver_config.resolve rejects the others for users)")
        t0 = time.perf_counter()
        self.robot, self.model, self.T = robot, model, horizon
        T, nq = horizon, robot.nq
        self.nz = nz = nq + NM + NV  # per node: q, mu, s
        self.n = n = nz * (T + 1)
        self.ng = NM * (T + 1) + NV * T
        self.n_p = CAMERA_PARAMETERS + (T + 1) + 1 + NV
        pose = pose_function(robot)
        stage = kalman_stage(model)
        fn = _stage_functions(model, stage, pose, nq)
        self.coef = fn["coef"]

        # ---- indices (node-major decision vector: q_t, mu_t, s_t)
        base = [nz * t for t in range(T + 1)]
        self.q_idx = q_idx = [np.arange(o, o + nq) for o in base]
        self.mu_idx = [np.arange(o + nq, o + nq + NM) for o in base]
        self.s_idx = [np.arange(o + nq + NM, o + nz) for o in base]
        D = smoothness_matrix(n, q_idx, smoothness)

        # ---- symbolic NLP over the mapped stages
        X, P = ca.MX.sym("x", n), ca.MX.sym("p", self.n_p)
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.ng)
        Z = ca.reshape(X, nz, T + 1)
        qs, mus, ss = Z[:nq, :], Z[nq:nq + NM, :], Z[nq + NM:, :]
        c0 = CAMERA_PARAMETERS
        Tc, scale, ref = P[:c0], P[c0:c0 + T + 1], P[c0 + T + 1]
        sc_a, sc_b = ca.reshape(scale[:T], 1, T), ca.reshape(scale[1:], 1, T)
        args = (mus[:, :T], mus[:, 1:], ss[:, :T], sc_a, sc_b)
        g_kin = ca.vec(mus - pose.map(T + 1)(qs, Tc))
        g_step = ca.vec(fn["g"].map(T)(*args) - ss[:, 1:])
        g = ca.vertcat(g_kin, g_step)
        trace_T = scale[T] * sum(ss[k, T] for k in DIAG)
        f = trace_T / ref + (0.5 * ca.bilin(ca.DM(D), X, X) if smoothness > 0 else 0)
        grad_f = ca.Function("lifted_grad_f", [X, P], [f, ca.densify(ca.gradient(f, X))],
                             ["x", "p"], ["f", "grad"])
        jac_g = self._jacobian(fn, X, P, g, qs, Tc, args)
        hess_lag = self._hessian(fn, (X, P, lam_f, lam_g), qs, mus, Tc, ref, D)

        staged = {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}
        self.codegen, self.codegen_note = codegen, None
        if codegen:
            staged, self.codegen_note = compiled_or_interpreted(staged, codegen_required)
            self.codegen = self.codegen_note is None
        self.hess_lag, self.jac_g, self.grad_f = (staged["hess_lag"], staged["jac_g"],
                                                  staged["grad_f"])
        self._adjoint = None  # the Jacobian's pattern for `multipliers`, made on first use
        # initial covariances: the Kalman recursion along the initial means (mapaccum of the same
        # stage)
        M, S0 = ca.MX.sym("mus", NM, T + 1), ca.MX.sym("sigma0", NV)
        roll = stage.mapaccum("lifted_roll", T)(S0, self.coef.map(T)(M[:, :T], M[:, 1:]))[0]
        self.roll = ca.Function("lifted_rollout", [M, S0], [roll])
        self.poses = pose.map(T + 1)
        # the initial multipliers are always given (the adjoint recursion, or a warm start's): IPOPT
        # uses them
        self.solver = ca.nlpsol("surestep_lifted", "ipopt", {"x": X, "f": f, "g": g, "p": P},
                                {**options, "ipopt.warm_start_init_point": "yes", **staged,
                                 # a trial point whose covariance is not PD has no Cholesky factor
                                 # (NaN): IPOPT shortens the step, which is its answer; no warning
                                 # per evaluation
                                 "show_eval_warnings": False})
        self.build_time_s = time.perf_counter() - t0

    def _jacobian(self, fn: dict, X, P, g, qs, Tc, args: tuple) -> ca.Function:
        """`lifted_jac_g`: the constraints (the kinematic rows, then the shooting rows) and their
        Jacobian, scattered from the mapped stages."""
        T, n = self.T, self.n
        q_idx, mu_idx, s_idx = self.q_idx, self.mu_idx, self.s_idx
        kin_rows = [np.arange(NM * t, NM * (t + 1)) for t in range(T + 1)]
        step_rows = [NM * (T + 1) + np.arange(NV * t, NV * (t + 1)) for t in range(T)]
        eye_nv = -np.eye(NV).ravel(order="F")
        jac_sp, (j_q, j_mu, j_int, j_next), _ = assemble((self.ng, n), [
            entries(list(zip(kin_rows, q_idx))), entries(list(zip(kin_rows, mu_idx))),
            entries([(step_rows[t], np.concatenate([mu_idx[t], mu_idx[t + 1], s_idx[t]]))
                     for t in range(T)]),
            entries([(step_rows[t], s_idx[t + 1]) for t in range(T)])])
        J_nz = (ca.mtimes(j_q, ca.vec(fn["node_jac"].map(T + 1)(qs, Tc)))
                + ca.mtimes(j_mu, ca.DM(np.tile(np.eye(NM).ravel(order="F"), T + 1)))
                + ca.mtimes(j_int, ca.vec(fn["jac"].map(T)(*args)))
                + ca.mtimes(j_next, ca.DM(np.tile(eye_nv, T))))
        return ca.Function("lifted_jac_g", [X, P], [g, ca.MX(jac_sp, J_nz)], ["x", "p"],
                           ["g", "jac"])

    def _hessian(self, fn: dict, symbols: tuple, qs, mus, Tc, ref, D: np.ndarray) -> ca.Function:
        """`lifted_hess_l`: the structured Hessian of the Lagrangian (module docstring): the
        surrogate's curvature in the means with the recursion's weights along them, plus the
        kinematic curvature and the smoothness."""
        T, n, mu_idx = self.T, self.n, self.mu_idx
        c0 = CAMERA_PARAMETERS
        X, P, lam_f, lam_g = symbols
        hess_sp, (h_int, h_q), const = assemble((n, n), [
            entries([(np.concatenate([mu_idx[t], mu_idx[t + 1]]),) * 2 for t in range(T)]),
            entries([(i, i) for i in self.q_idx])], np.triu(D))
        lam_kin = ca.reshape(lam_g[:NM * (T + 1)], NM, T + 1)
        # motion coefficients, then observation
        C, nm = self.coef.map(T)(mus[:, :T], mus[:, 1:]), fn["nm"]
        _, w_m, w_o, _ = recursion_weights(self.model, T, ca.SX.sym("sigma0", NV),
                                           ca.SX.sym("trace_ref"))(
            C[:nm, :], C[nm:, :], ca.MX(0, T), P[c0 + T + 2:], ref)
        H_nz = (lam_f * (const + ca.mtimes(
                    h_int, ca.vec(fn["hess"].map(T)(mus[:, :T], mus[:, 1:], w_m, w_o))))
                + ca.mtimes(h_q, ca.vec(fn["node_hess"].map(T + 1)(qs, lam_kin, Tc))))
        return ca.Function("lifted_hess_l", [X, P, lam_f, lam_g], [ca.MX(hess_sp, H_nz)],
                           ["x", "p", "lam_f", "lam_g"], ["hess"])

    # ------------------------------------------------------------------ one solve
    def _start(self, setup: Setup, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Consistent initial point (joints, means by FK, covariances by the recursion), scales,
        initial trace."""
        T = self.T
        mu = np.asarray(self.poses(q.T, setup.camera_parameter()))  # 7 x T+1
        s0 = vech(np.asarray(setup.ocp.sigma0, float))
        S = np.hstack([s0[:, None], np.asarray(self.roll(mu, s0))])  # 21 x T+1
        tr = S[DIAG, :].sum(axis=0)
        scale = np.maximum(tr / NX, 1e-14)
        Z = np.vstack([q.T, mu, S / scale])
        return Z.ravel(order="F"), scale, float(tr[T])

    def multipliers(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Multipliers at `x`: `lam_g` with the Lagrangian stationary in the means and covariances
        (the adjoint recursion, solved backwards as one sparse triangular system), and
        `lam_x = -(grad f + J^T lam_g)`, the bound multipliers that make it stationary in every
        variable (exact at a KKT point of the condensed form, whose joints are the same)."""
        # the Jacobian's nonzeros through CasADi's buffer interface: a DM's conversion to scipy
        # cost about half of this function (docs/general_models.md, "The secant end-game")
        # (per thread: the NLP is shared by the threads of a process)
        if self._adjoint is None:
            self._adjoint = self._adjoint_pattern()
        nz = thread_buffered(("jac_g", self.jac_g), lambda: self.jac_g)(x, p)[1]
        sel, indices, indptr, rows, col_of, cols = self._adjoint
        # J[:, cols]^T
        A = scipy.sparse.csr_matrix((nz[sel], indices, indptr), shape=(len(cols), self.ng))
        grad = np.asarray(self.grad_f(x, p)[1]).ravel()
        lam_g = scipy.sparse.linalg.spsolve(A, -grad[cols])
        return lam_g, -(grad + np.bincount(col_of, weights=nz * lam_g[rows], minlength=self.n))

    def _adjoint_pattern(self) -> tuple:
        """The constraint Jacobian's fixed pattern, for `multipliers`: the nonzeros (`sel`, in
        order) and the CSR indices of `J[:, cols]^T` (cols: the means and the covariances after the
        first), and each nonzero's row and column (for `J^T lam` by one bincount); built once
        instead of scipy's slicing per call."""
        sp = self.jac_g.sparsity_out(1)
        rows, colind = np.asarray(sp.row()), np.asarray(sp.colind())
        col_of = np.repeat(np.arange(self.n), np.diff(colind))
        cols = np.concatenate(self.mu_idx + self.s_idx[1:])
        position = np.full(self.n, -1)
        position[cols] = np.arange(len(cols))
        keep = np.flatnonzero(position[col_of] >= 0)
        sel = keep[np.argsort(position[col_of[keep]], kind="stable")]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(position[col_of[sel]],
                                                            minlength=len(cols)))])
        return sel, rows[sel], indptr, rows, col_of, cols

    def bounds(self, setup: Setup, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prob, T, nq = setup.ocp, self.T, self.robot.nq
        movable = self.robot.supporting_joints()
        lo, hi = np.full((self.nz, T + 1), -np.inf), np.full((self.nz, T + 1), np.inf)
        lo[:nq, :], hi[:nq, :] = self.robot.lower[:, None], self.robot.upper[:, None]
        held = np.setdiff1d(np.arange(nq), movable)
        lo[held, :] = hi[held, :] = np.asarray(setup.q_start)[held, None]
        lo[:nq, 0] = hi[:nq, 0] = setup.q_start
        lo[nq + 2, :] = prob.min_depth
        lo[nq:nq + NM, 0] = hi[nq:nq + NM, 0] = setup.m_start
        lo[nq:nq + NM, T] = hi[nq:nq + NM, T] = setup.m_goal
        lo[nq + NM:, 0] = hi[nq + NM:, 0] = vech(np.asarray(prob.noise.Sigma0, float)) / scale[0]
        return lo.ravel(order="F"), hi.ravel(order="F")

    def solve(self, setup: Setup, init, method: str = "ocp", warm=None):
        T, nq = self.T, self.robot.nq
        t0 = time.perf_counter()
        if warm is None:
            x0, scale, trace_ref = self._start(setup, np.asarray(init.q, float))
        else:
            x0, scale, trace_ref = warm.x, warm.scale, warm.trace_ref
        lbx, ubx = self.bounds(setup, scale)
        p = np.concatenate([setup.camera_parameter(), scale, [trace_ref],
                            # for the Hessian's weights
                            setup.model.recursion_sigma0(setup.ocp.sigma0)])
        args = dict(x0=x0, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0, p=p)
        if warm is not None:
            args.update(lam_x0=warm.lam_x, lam_g0=warm.lam_g)
        else:
            # the multipliers of the initial point: adjoint recursion, bound multipliers from the
            # residual
            args.update(zip(("lam_g0", "lam_x0"), self.multipliers(x0, p)))
        res = self.solver(**args)
        solve_s = time.perf_counter() - t0
        Z = np.asarray(res["x"]).reshape(self.nz, T + 1, order="F")
        return ipopt_solution(self, setup, method, init, warm, Z[:nq, :].T.copy(), res, solve_s,
                              scale, trace_ref, float(scale[T] * np.trace(unvech(Z[nq + NM:, T]))),
                              float(np.max(np.abs(np.asarray(res["g"])))),
                              "full (lifted, structured Hessian)")

    def start_solution(self, setup: Setup, init, method: str = "ocp") -> Solution | None:
        """Not offered by the lifted form (the condensed form keeps a feasible start)."""
        return None
