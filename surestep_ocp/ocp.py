"""The belief-space OCP: direct multiple shooting over joints and belief mean, solved by IPOPT.

Per node t = 0..T: joints `q_t` and mean `mu_t` (camera-frame pose). Constraints:

    mu_t = pose_in_camera(FK(q_t))                      every node
    Sigma_t+1 = belief step (mu_t, mu_t+1, Sigma_t)      every interval
    q_lo <= q_t <= q_hi,  mu_t,z >= min_depth
    q_0 = q_start, mu_0 = x_start, Sigma_0 given, mu_T = x_goal  (hard terminal equality)

Objective: `Tr(Sigma_T)` (divided by the initial guess's value) plus an optional
joint-step smoothness term.

The covariance has four forms (`solver.covariance` in the problem file):

* `full`: `vech(Sigma_t)` (21 numbers, scaled by the initial guess's magnitude) per
  node and a free gain `K_t` per interval, the step in Joseph form
  `(I - K H) P (I - K H)^T + K R V R^T K^T`. That is positive semidefinite for any K
  and smallest, in the matrix (Loewner) order, at the Kalman gain; every later step
  is monotone in that order, so minimising `Tr(Sigma_T)` over gains and path gives
  exactly the Kalman gains at the optimum, with no symbolic inverse. Works for any
  F, Q, H, R and base covariances.
* `condensed`: the covariance is not a variable; the EKF recursion is written out in
  the objective. With identity maps and diagonal base covariances every covariance
  along any path is diagonal, exactly, and the recursion is six scalar Kalman updates
  `sigma+ = p v / (p + v)`; with the paper's constants (multiples of I) the same holds
  from any Sigma_0 on its eigenvalues (`BeliefModel.isotropic`, e.g. after a camera move).
* `diagonal`: six scalar covariances per node with free scalar gains (multiple shooting).
* `auto` (default): `condensed` when the scalar structure is exact, else `full`.

Measured on problems/*.yaml (T = 20, this 2-core machine, exact Hessian; see the issue notes): `full`
converges (the first formulation tried, `(I - K H) P` with the gain equality
`K S = P H^T`, ended in restoration failures) but needs 300-1800 IPOPT iterations
(3-45 s) and sometimes fails; `diagonal` fails more often (T = 3, started from the
condensed optimum moved by 1e-9 rad in random directions: 4 of 8 starts failed, the
first step already 1e10 long: the KKT matrix is near singular where the covariance
collapses); `condensed` with the scalar
recursion solved every problem in 130-460 iterations (1.5-3.5 s). The slow
convergence of the lifted forms comes from the paper's noise model: it vanishes at
the ideal pose, so the covariance collapses there and everything before that node
stops mattering (near-singular reduced Hessian).

The Hessian (`solver.hessian`): with the condensed form of a scalar model and the
paper's observation noise, the objective is S(c(mu)), S the trace after the scalar
Kalman recursions as a function of the noise coefficients c (each the squared norm of a
residual of the means: the step, the rotation between steps, the depth, image and
orientation errors). S is concave and nondecreasing in c (the Riccati map is), so its
own curvature is what makes the exact Hessian indefinite: IPOPT then adds a large
multiple of the identity and crawls (the exact Hessian needed 130-900 iterations, with
the regularisation at 10^1 to 10^2). Since S lies below its tangent, the objective is
majorised by the surrogate `sum_k dS/dc_k c_k(mu)` (weights frozen at the current
point); `surrogate` (the default through `auto`) uses that surrogate's exact Hessian,
`sum_k dS/dc_k Hess c_k`: the exact Hessian without S's curvature, block tridiagonal in
the means, cost linear in T. `gauss-newton` drops the residuals' curvature too
(`sum_k dS/dc_k 2 J_k^T J_k`, positive semidefinite); measured at T = 20 on 20
evaluation instances it needed about twice the iterations (median 46 against 24) and
zig-zags near some optima. `auto` runs IPOPT with the surrogate Hessian for at most
`solver.surrogate_max_iter` iterations and, when that has not converged, polishes with
the exact Hessian warm-started from its primal-dual point; see `solve_ocp_warm`.

With the surrogate or Gauss-Newton Hessian, IPOPT also gets the objective gradient and
the constraint Jacobian from us (`Transcription._staged_derivatives`): small per-interval
and per-node Functions mapped over the horizon, so that `solver.codegen` (default auto:
when a C compiler is found) compiles each stage once, in about 2 s whatever T
(measured at T = 20: function time per solve 22 ms interpreted, 3 ms compiled).

The NLP is parametric in the camera pose (the robot base in the camera frame), the
scales and Sigma_0, so one built solver serves every start, goal and camera pose of
a given structure and horizon (a cache keeps it), which re-planning needs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .belief import DIAG, NV, NX, BeliefModel, unvech, vech
from .codegen import available as compiler_available
from .codegen import compiled_or_interpreted
from .lifted import LiftedTranscription
from .errors import SurestepError
from .newton import NewtonSolver
from .robot import Robot
from .setup import Setup
from .solution import Solution, evaluate
from .stages import assemble, entries, smoothness_matrix
from .surrogate import interval_terms, pose_function, recursion_weights, scalar_trace

FORMS = ("auto", "full", "diagonal", "condensed")
HESSIANS = ("exact", "surrogate", "gauss-newton")  # what a Transcription is built with (`auto` resolves to one)


@dataclass
class InitialGuess:
    """A joint trajectory to start from, and where it came from."""

    q: np.ndarray  # (T+1, nq)
    source: str


@dataclass
class WarmStart:
    """Primal and dual values of a previous solve of the same transcription, and its scaling.

    The scaling (covariance scales, objective reference) is reused by the warm solve: the
    values and multipliers are those of the scaled NLP.
    """

    x: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    scale: np.ndarray
    trace_ref: float


@dataclass
class NewtonWarm:
    """A previous Newton solution's joint trajectory, to start the next Newton solve from (primal only:
    the bound multipliers are implicit in a projected method)."""

    q: np.ndarray


class _Layout:
    """Named blocks of the decision vector (no slicing by stride)."""

    def __init__(self):
        self.blocks: list[tuple[str, int, ca.SX]] = []

    def add(self, name: str, size: int) -> ca.SX:
        sym = ca.SX.sym(name, size)
        self.blocks.append((name, size, sym))
        return sym

    def vector(self) -> ca.SX:
        return ca.vertcat(*[b[2] for b in self.blocks])

    def split(self, values: np.ndarray) -> dict[str, np.ndarray]:
        out, i = {}, 0
        for name, size, _ in self.blocks:
            out[name] = np.asarray(values[i : i + size]).ravel()
            i += size
        return out

    def join(self, values: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([np.asarray(values[name], float).ravel() for name, _, _ in self.blocks])


def resolve_form(model: BeliefModel, form: str) -> str:
    if form not in FORMS:
        raise SurestepError(f"unknown covariance form '{form}'; allowed: {', '.join(FORMS)}")
    if form == "auto":
        return "condensed" if model.scalar or model.structured else "full"
    if form == "diagonal" and not model.diagonal:
        raise SurestepError("solver.covariance: the diagonal form is exact only with identity motion/observation "
                            "maps and diagonal base covariances; use full, condensed or auto")
    return form


class Transcription:
    """The multiple-shooting NLP of one structure (robot, belief model, horizon, form), built once."""

    def __init__(self, robot: Robot, model: BeliefModel, horizon: int, form: str, smoothness: float,
                 options: dict, hessian: str = "exact", codegen: bool = False, codegen_required: bool = False):
        self.robot, self.model, self.T, self.form = robot, model, horizon, form
        self.scalar = form == "condensed" and model.scalar
        T, nq = horizon, robot.nq
        ns = NX if form == "diagonal" else NV
        self.ns = ns
        L = self.layout = _Layout()
        qs, mus, ss, Ks = [], [], [], []
        for t in range(T + 1):
            qs.append(L.add(f"q{t}", nq))
            mus.append(L.add(f"mu{t}", NX))
            if form == "condensed":
                continue
            ss.append(L.add(f"s{t}", ns))
            if t < T:
                Ks.append(L.add(f"K{t}", NX * NX if form == "full" else NX))
        # Parameters: robot base in the camera frame (3x4), covariance scales, trace reference.
        Tcb = ca.SX.sym("T_cam_base", 3, 4)
        scale = ca.SX.sym("scale", T + 1)
        trace_ref = ca.SX.sym("trace_ref")
        sigma0 = ca.SX.sym("sigma0", NV)
        self.p = ca.vertcat(ca.vec(Tcb), scale, trace_ref, sigma0)

        pose = pose_function(robot)

        g = [mus[t] - pose(qs[t], Tcb) for t in range(T + 1)]
        predicted = model.noise.objective == "predicted"
        if predicted and form != "condensed":
            raise SurestepError("objective.covariance: predicted needs solver.covariance: condensed (or auto)")
        if form == "condensed":  # the covariance is shot through the EKF steps inside the objective
            if self.scalar:  # exact: six scalar Kalman recursions (in Sigma_0's eigenbasis when isotropic)
                trace_T = scalar_trace(
                    sigma0, [ca.diag(model.motion_noise(mus[t], mus[t + 1])) for t in range(T)],
                    [lambda p, t=t: ca.diag(model.planning_noise(mus[t + 1], vech(ca.diag(p)))) for t in range(T)],
                    predicted)
            else:
                s_t = sigma0
                for t in range(T - 1):
                    s_t = model.step_expr(mus[t], mus[t + 1], s_t)
                last = model.predict_expr if predicted else model.step_expr
                s_t = last(mus[T - 1], mus[T], s_t)
                trace_T = sum(s_t[i] for i in DIAG)
        else:
            for t in range(T):
                g.append(self._step(mus[t], mus[t + 1], scale[t] * ss[t], Ks[t]) / scale[t + 1]
                         - ss[t + 1])
            trace_T = scale[T] * (ca.sum1(ss[T]) if form == "diagonal" else sum(ss[T][i] for i in DIAG))
        self.poses = pose.map(T + 1)  # (q columns, T_cam_base) -> mean columns, for initial points
        self.trace = ca.Function("trace", [L.vector(), self.p], [trace_T])  # Tr(Sigma_T) the planner minimises
        f = trace_T / trace_ref
        if smoothness > 0:
            f += smoothness * sum(ca.sumsqr(qs[t + 1] - qs[t]) for t in range(T))
        self.ng = ca.vertcat(*g).shape[0]
        self.hessian, self.hess_lag = hessian, None
        if hessian not in HESSIANS:
            raise SurestepError(f"unknown Hessian '{hessian}'; allowed: {', '.join(HESSIANS)}")
        if hessian != "exact":
            if form != "condensed" or not model.structured:
                raise SurestepError(f"the {hessian} Hessian needs the condensed form of a model with constant "
                                    "motion/observation maps and the mean observation noise")
        elif codegen:
            raise SurestepError(CODEGEN_EXACT)
        self.codegen, self.codegen_note = codegen, None
        t0 = time.perf_counter()
        if hessian != "exact":
            staged = self._staged_derivatives(pose, sigma0, trace_ref, smoothness)
            if codegen:  # measured at T = 20: function time 22 -> 3.5 ms per solve (24 iterations)
                staged, self.codegen_note = compiled_or_interpreted(staged, codegen_required)
                self.codegen = self.codegen_note is None
            self.hess_lag = staged["hess_lag"]
            options = {**options, **staged}
        self.solver = ca.nlpsol("surestep_ocp", "ipopt", {"x": L.vector(), "f": f, "g": ca.vertcat(*g),
                                                           "p": self.p}, options)
        self.build_time_s = time.perf_counter() - t0

    def _staged_derivatives(self, pose: ca.Function, sigma0, trace_ref, smoothness) -> dict:
        """Objective gradient, constraint Jacobian and a structured Hessian of the Lagrangian, built stage-wise.

        The objective is S(c(mu)): S, the trace after the scalar Kalman recursions, as a function
        of the noise coefficients c (each the squared norm of a residual e(mu)). S is concave and
        nondecreasing in c. `surrogate`: drop S's own curvature, keep the coefficients' exact
        one, `sum_k (dS/dc_k) Hess c_k`: the Hessian of the majorize-minimise surrogate
        `sum_k (dS/dc_k) c_k(mu)` (S lies below its tangent). `gauss-newton`: drop the
        residuals' curvature too, `sum_k (dS/dc_k) 2 J_k^T J_k`, positive semidefinite. Both are
        block tridiagonal in the means (each c_k depends on two consecutive ones). The gradient
        is exact: `sum_k (dS/dc_k) grad c_k`.

        Each derivative is one small SX Function per interval (the means at both ends) or per
        node (the kinematic constraint `mu_t - pose(q_t)`), mapped over the horizon and scattered
        into the global sparsity by a constant sparse matrix; only the recursion's weights dS/dc
        see the whole horizon. The expression graphs, and the C code of `solver.codegen`, hold
        each stage once whatever the horizon. Returns IPOPT's `grad_f`, `jac_g` and `hess_lag`.
        """
        m, T, nq = self.model, self.T, self.robot.nq
        n = self.layout.vector().shape[0]
        weights = recursion_weights(m, T, sigma0, trace_ref)
        a, b = ca.SX.sym("a", NX), ca.SX.sym("b", NX)
        (res_m, res_o), coefficients, (wm, wo), weighted = interval_terms(m, a, b)
        coef = ca.Function("coef", [a, b], list(coefficients))
        ab = ca.vertcat(a, b)
        if self.hessian == "surrogate":  # exact curvature of the weighted coefficients
            block = ca.hessian(weighted, ab)[0]
        else:  # Gauss-Newton: the residuals' curvature dropped too
            block = sum(2 * wm[k] * ca.mtimes(ca.jacobian(e, ab).T, ca.jacobian(e, ab)) for k, e in enumerate(res_m))
            block += sum(2 * wo[k] * ca.mtimes(ca.jacobian(e, ab).T, ca.jacobian(e, ab)) for k, e in enumerate(res_o))
        interval_grad = ca.Function("interval_grad", [a, b, wm, wo], [ca.densify(ca.gradient(weighted, ab))])
        interval_hess = ca.Function("interval_hess", [a, b, wm, wo], [ca.densify(block)])
        q, lam, Tcb = ca.SX.sym("q", nq), ca.SX.sym("lam", NX), ca.SX.sym("T_cam_base", 3, 4)
        # g_t = mu_t - pose(q_t): Jacobian -d pose/dq (and I in the mean); curvature -Hess(lam . pose)
        node_jac = ca.Function("node_jac", [q, Tcb], [ca.densify(-ca.jacobian(pose(q, Tcb), q))])
        node_hess = ca.Function("node_hess", [q, lam, Tcb], [ca.densify(ca.hessian(-ca.dot(lam, pose(q, Tcb)), q)[0])])

        # Where each stage output's entries go (column-major within each stage block).
        offsets = dict(zip((name for name, _, _ in self.layout.blocks),
                           np.cumsum([0] + [size for _, size, _ in self.layout.blocks])))
        mu_idx = [np.arange(offsets[f"mu{t}"], offsets[f"mu{t}"] + NX) for t in range(T + 1)]
        q_idx = [np.arange(offsets[f"q{t}"], offsets[f"q{t}"] + nq) for t in range(T + 1)]
        ab_idx = [np.concatenate([mu_idx[t], mu_idx[t + 1]]) for t in range(T)]
        g_idx = [np.arange(NX * t, NX * (t + 1)) for t in range(T + 1)]

        D = smoothness_matrix(n, q_idx, smoothness)

        X, P = ca.MX.sym("x", n), ca.MX.sym("p", self.p.shape[0])
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.ng)
        Tcb_x, sigma0_x, ref_x = ca.Function("params", [self.p], [self.p[:12].reshape((3, 4)), sigma0, trace_ref])(P)
        mus = ca.horzcat(*[X[i[0]:i[0] + NX] for i in mu_idx])
        qs = ca.horzcat(*[X[i[0]:i[0] + nq] for i in q_idx])
        S_x, w_m, w_o = weights(*coef.map(T)(mus[:, :T], mus[:, 1:]), sigma0_x, ref_x)
        G = interval_grad.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        B = interval_hess.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        Jq = node_jac.map(T + 1)(qs, Tcb_x)
        K = node_hess.map(T + 1)(qs, ca.reshape(lam_g[:NX * (T + 1)], NX, T + 1), Tcb_x)
        smooth_f = 0.5 * ca.bilin(ca.DM(D), X, X) if smoothness > 0 else 0

        grad_sp, (sc_g,), _ = assemble((n, 1), [entries([(i, [0]) for i in ab_idx])])
        grad = ca.MX(grad_sp, ca.mtimes(sc_g, ca.vec(G)))
        if smoothness > 0:
            grad = ca.densify(grad) + ca.mtimes(ca.DM(D), X)
        grad_f = ca.Function("nlp_grad_f", [X, P], [S_x + smooth_f, ca.densify(grad)], ["x", "p"], ["f", "grad"])

        jac_sp, (sc_q, sc_mu), _ = assemble((self.ng, n), [entries(list(zip(g_idx, q_idx))),
                                                          entries(list(zip(g_idx, mu_idx)))])
        J_nz = ca.mtimes(sc_q, ca.vec(Jq)) + ca.mtimes(sc_mu, ca.DM(np.tile(np.eye(NX).ravel(order="F"), T + 1)))
        g_x = ca.vec(mus - ca.Function("poses", [q, Tcb], [pose(q, Tcb)]).map(T + 1)(qs, Tcb_x))
        jac_g = ca.Function("nlp_jac_g", [X, P], [g_x, ca.MX(jac_sp, J_nz)], ["x", "p"], ["g", "jac"])

        hess_sp, (sc_b, sc_k), const = assemble((n, n), [entries([(i, i) for i in ab_idx]),
                                                         entries([(i, i) for i in q_idx])], np.triu(D))
        H_nz = lam_f * (ca.mtimes(sc_b, ca.vec(B)) + const) + ca.mtimes(sc_k, ca.vec(K))
        hess_lag = ca.Function("nlp_hess_l", [X, P, lam_f, lam_g], [ca.MX(hess_sp, H_nz)],
                               ["x", "p", "lam_f", "lam_g"], ["hess"])
        return {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}

    def _step(self, x0, x1, s, K):
        m = self.model
        if self.form == "diagonal":
            p = s + ca.diag(m.motion_noise(x0, x1))
            v = ca.diag(m.planning_noise(x1, vech(ca.diag(p))))
            return (1 - K) ** 2 * p + K**2 * v  # scalar Joseph form, gains free (as in `full`)
        p = m.predict_expr(x0, x1, s)
        S, H = m.innovation_expr(x0, x1, p)
        P = unvech(p)
        K = ca.reshape(K, NX, NX)
        IKH = ca.DM.eye(NX) - K @ H
        post = IKH @ P @ IKH.T + K @ (S - H @ P @ H.T) @ K.T  # Joseph form; S - H P H^T = R V R^T
        return vech(0.5 * (post + post.T))

    # ------------------------------------------------------------------ one solve
    def guess(self, setup: Setup, q: np.ndarray) -> tuple[dict, np.ndarray]:
        """Consistent primal point (mean, covariance, gains) from a joint trajectory; and the scales."""
        model, T = setup.model, self.T  # this setup's Sigma_0 (the cached model may hold another)
        mu = np.array([setup.pose_of(qi) for qi in q])
        sig, pred = model.propagate(mu)
        out = {}
        for t in range(T + 1):
            out[f"q{t}"], out[f"mu{t}"] = q[t], mu[t]
            out[f"s{t}"] = np.diag(sig[t]) if self.form == "diagonal" else vech(sig[t])
            if t < T and self.form == "diagonal":
                v = np.diag(np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))))
                out[f"K{t}"] = np.diag(pred[t]) / (np.diag(pred[t]) + v)
            elif t < T:
                _, _, H, Rm = (np.asarray(M) for M in model.jacobians(mu[t], mu[t + 1]))
                S = H @ pred[t] @ H.T + Rm @ np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))) @ Rm.T
                out[f"K{t}"] = np.linalg.solve(S, H @ pred[t]).T.ravel(order="F")
        scale = np.array([max(np.trace(s) / NX, 1e-14) for s in sig])
        return out, scale

    def bounds(self, setup: Setup, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prob, T, nq = setup.problem, self.T, self.robot.nq
        movable = set(self.robot.supporting_joints())
        s0 = np.asarray(prob.noise.Sigma0, float)
        lo, hi = {}, {}
        for t in range(T + 1):
            ql, qh = self.robot.lower.copy(), self.robot.upper.copy()
            for j in range(nq):
                if t == 0 or j not in movable:
                    ql[j] = qh[j] = setup.q_start[j]
            lo[f"q{t}"], hi[f"q{t}"] = ql, qh
            ml, mh = np.full(NX, -np.inf), np.full(NX, np.inf)
            ml[2] = prob.min_depth
            if t == 0:
                ml = mh = setup.x_start
            if t == T:
                ml = mh = setup.x_goal
            lo[f"mu{t}"], hi[f"mu{t}"] = ml, mh
            if t == 0:
                lo["s0"] = hi["s0"] = (np.diag(s0) if self.form == "diagonal" else vech(s0)) / scale[0]
            else:
                lo[f"s{t}"], hi[f"s{t}"] = np.full(self.ns, -np.inf), np.full(self.ns, np.inf)
                lo[f"s{t}"][slice(None) if self.form == "diagonal" else DIAG] = 0.0
            if t < T:
                nk = NX * NX if self.form == "full" else NX
                lo[f"K{t}"], hi[f"K{t}"] = np.full(nk, -np.inf), np.full(nk, np.inf)
        return self.layout.join(lo), self.layout.join(hi)

    def _parameters(self, setup: Setup, scale: np.ndarray, trace_ref: float) -> np.ndarray:
        sigma0 = np.asarray(setup.problem.noise.Sigma0, float)
        # the scalar recursions start from their channel variances (the trace is the same)
        s0 = setup.model.recursion_sigma0(sigma0) if self.form == "condensed" else vech(sigma0)
        return np.concatenate([setup.T_cam_base[:3, :].ravel(order="F"), scale, [trace_ref], s0])

    def _condensed_start(self, setup: Setup, init: InitialGuess) -> tuple[np.ndarray, np.ndarray, float]:
        """Initial point of the condensed form (joints, and their means by FK), scales, and its trace."""
        T, q = self.T, np.asarray(init.q, float)
        mu = np.asarray(self.poses(q.T, setup.T_cam_base[:3, :])).T
        x0 = self.layout.join({**{f"q{t}": q[t] for t in range(T + 1)}, **{f"mu{t}": mu[t] for t in range(T + 1)}})
        scale = np.ones(T + 1)  # unused by this form
        return x0, scale, float(self.trace(x0, self._parameters(setup, scale, 1.0)))

    def start_solution(self, setup: Setup, init: InitialGuess, method: str = "ocp") -> Solution | None:
        """The initial guess itself as a plan, if it is feasible (every bound to 1e-9; the kinematic
        constraints hold by construction in the condensed form); None otherwise."""
        if self.form != "condensed":
            return None
        x0, scale, trace_ref = self._condensed_start(setup, init)
        lbx, ubx = self.bounds(setup, scale)
        violation = float(np.max(np.maximum(lbx - x0, 0) + np.maximum(x0 - ubx, 0)))
        if violation > 1e-9:
            return None
        q = np.asarray(init.q, float)
        return evaluate(setup, method, np.array([setup.pose_of(qi) for qi in q]), list(q), success=True,
                        status="Initial_Guess_Kept", solve_time_s=0.0, iterations=0, objective=trace_ref,
                        extras={"init": init.source, "solver": "ipopt", "covariance_form": self.form,
                                "build_time_s": self.build_time_s, "compiled": self.codegen,
                                "ocp_trace_final": trace_ref, "initial_trace": trace_ref,
                                "constraint_violation": violation})

    def solve(self, setup: Setup, init: InitialGuess, method: str = "ocp",
              warm: WarmStart | None = None) -> tuple[Solution, WarmStart]:
        T = self.T
        t0 = time.perf_counter()  # the solve time counts the set-up of the call (initial point, scales, bounds)
        if warm is None and self.form == "condensed":  # no covariance variables: means and the trace only
            x0, scale, trace_ref = self._condensed_start(setup, init)
        elif warm is None:
            x0, scale = self.guess(setup, np.asarray(init.q, float))
            trace_ref = float(np.sum(np.asarray(x0[f"s{T}"])[slice(None) if self.form == "diagonal" else DIAG]))
            for t in range(T + 1):
                x0[f"s{t}"] = x0[f"s{t}"] / scale[t]
            x0 = self.layout.join(x0)
        else:
            x0, scale, trace_ref = warm.x, warm.scale, warm.trace_ref
        lbx, ubx = self.bounds(setup, scale)
        p = self._parameters(setup, scale, trace_ref)
        args = dict(x0=x0, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0, p=p)
        if warm is not None:
            args.update(lam_x0=warm.lam_x, lam_g0=warm.lam_g)
        res = self.solver(**args)
        solve_s = time.perf_counter() - t0
        stats = self.solver.stats()
        vals = self.layout.split(np.asarray(res["x"]).ravel())
        q = np.array([vals[f"q{t}"] for t in range(T + 1)])
        poses = np.array([setup.pose_of(qi) for qi in q])  # Pinocchio FK of the solution's joints
        if self.form == "condensed":
            ocp_trace = float(res["f"]) * trace_ref
        else:
            sT = vals[f"s{T}"] * scale[T]
            ocp_trace = float(np.sum(sT) if self.form == "diagonal" else np.trace(unvech(sT)))
        sol = evaluate(
            setup, method, poses, list(q),
            success=bool(stats["success"]), status=str(stats["return_status"]), solve_time_s=solve_s,
            iterations=int(stats["iter_count"]), objective=float(res["f"]) * trace_ref,
            extras={
                "init": init.source if warm is None else f"warm start ({init.source})",
                "solver": "ipopt",
                "covariance_form": self.form,
                "build_time_s": self.build_time_s,
                "compiled": self.codegen,  # derivatives compiled to C (solver.codegen)
                **({"codegen_note": self.codegen_note} if self.codegen_note else {}),
                "ocp_trace_final": ocp_trace,
                "initial_trace": trace_ref,  # the planner's objective at the (cold) initial guess
                "constraint_violation": float(np.max(np.abs(np.asarray(res["g"])))),
            },
        )
        return sol, WarmStart(np.asarray(res["x"]).ravel(), np.asarray(res["lam_x"]).ravel(),
                              np.asarray(res["lam_g"]).ravel(), scale, trace_ref)


_CACHE: dict[tuple, Transcription] = {}

# IPOPT options for re-solves started from a previous primal-dual solution.
WARM_OPTIONS = {
    "ipopt.warm_start_init_point": "yes",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
    "ipopt.mu_init": 1e-6,
}


# IPOPT options for the lifted NLP started at the condensed solution (a KKT point up to tol, with its
# multipliers): a small monotone barrier. Measured on the default problem at T = 20: 15 and 1 iterations (paper
# constants, correlated V_d0) against 65-73 with the adaptive update, which raised mu to 1e-3 and walked away.
LIFTED_FROM_CONDENSED = {
    "ipopt.mu_init": 1e-9,
    "ipopt.mu_strategy": "monotone",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
}


def solver_options(setup: Setup, extra: dict | None = None) -> dict:
    prob = setup.problem
    opts = {
        "ipopt.print_level": prob.solver.print_level,
        "print_time": False,
        "ipopt.sb": "yes",
        "ipopt.tol": prob.solver.tol,
        "ipopt.max_iter": prob.solver.max_iter,
        # Measured (full form): the adaptive barrier update needed 2.6-3.3x fewer
        # iterations than the monotone default and avoided its restoration failures.
        "ipopt.mu_strategy": "adaptive",
        # The terminal equality is hard: IPOPT's defaults accept a violation of 1e-4, and 1e-2 at its
        # "acceptable" level, whatever `tol` is.
        "ipopt.constr_viol_tol": min(prob.solver.tol, 1e-8),
        "ipopt.acceptable_constr_viol_tol": 1e-6,
    }
    opts.update({f"ipopt.{k}": v for k, v in prob.solver.options.items()})
    opts.update(extra or {})
    return opts


def transcription(setup: Setup, form: str | None = None, extra_options: dict | None = None,
                  horizon: int | None = None, hessian: str = "exact") -> Transcription:
    """The (cached) transcription for this setup's structure (form: default from the problem file)."""
    model = setup.model
    form = resolve_form(model, form or setup.problem.solver.covariance)
    T = setup.problem.horizon if horizon is None else horizon
    opts = solver_options(setup, extra_options)
    codegen = resolve_codegen(setup, hessian)
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(), model.key(), model.scalar, T, form,
           setup.problem.objective.smoothness, tuple(sorted((k, repr(v)) for k, v in opts.items())), hessian, codegen,
           setup.problem.solver.codegen is True)
    if key not in _CACHE and form == "full" and hessian == "surrogate":  # the lifted form's structured Hessian
        _CACHE[key] = LiftedTranscription(setup.robot, model, T, setup.problem.objective.smoothness, opts, codegen,
                                          codegen_required=setup.problem.solver.codegen is True)
    elif key not in _CACHE:
        _CACHE[key] = Transcription(setup.robot, model, T, form, setup.problem.objective.smoothness, opts, hessian,
                                    codegen, codegen_required=setup.problem.solver.codegen is True)
    return _CACHE[key]


CODEGEN_EXACT = ("solver.codegen: true compiles the stage-wise derivatives of the surrogate and Gauss-Newton "
                 "Hessians only (the exact condensed Hessian did not compile within 10 minutes); use "
                 "solver.hessian: auto, surrogate or gauss-newton, or codegen: auto or false")


def resolve_codegen(setup: Setup, hessian: str) -> bool:
    """Whether the transcription with this Hessian is compiled: `solver.codegen` true, or auto with a C compiler."""
    choice = setup.problem.solver.codegen
    if hessian == "exact":
        return False
    return compiler_available() if choice == "auto" else bool(choice)


def resolve_hessian(setup: Setup, form: str) -> str:
    """`solver.hessian` of the problem resolved for this model and covariance form.

    The surrogate and Gauss-Newton matrices exist for the condensed form of a scalar model
    with the paper's (mean) observation noise; `auto` uses the surrogate there (then polishes
    with the exact Hessian if needed) and the exact Hessian elsewhere.
    """
    choice, model = setup.problem.solver.hessian, setup.model
    possible = form == "condensed" and model.structured
    if form == "full" and model.structured and model.noise.objective == "posterior" and choice in ("auto", "surrogate"):
        return "surrogate"  # the lifted form's structured Hessian (lifted.py)
    if choice in ("surrogate", "gauss-newton") and not possible:
        raise SurestepError(f"solver.hessian: {choice} needs a model with constant motion/observation maps and "
                            "noise.observation_noise: mean (gauss-newton: the condensed form); use exact or auto")
    if choice == "auto":
        return "surrogate" if possible else "exact"
    return choice


def newton_applies(setup: Setup, form: str, hessian: str, forced: bool) -> bool:
    """Whether the projected Newton solver's reformulation is exact here: the surrogate model (the condensed
    scalar recursion with the mean noise, Hessian not forced) and exactly six joints moving the tracked frame,
    so that the terminal pose fixes the last node's joints (locally); a redundant arm keeps IPOPT."""
    return form == "condensed" and hessian != "exact" and not forced and len(setup.robot.supporting_joints()) == NX


def solve_ocp(setup: Setup, init: InitialGuess, solver_options: dict | None = None,
              method: str = "ocp", form: str | None = None) -> Solution:
    """Solve the belief-space OCP from the initial joint trajectory `init` (see `solve_ocp_warm`)."""
    return solve_ocp_warm(setup, init, solver_options, method, form)[0]


def solve_ocp_warm(setup: Setup, init: InitialGuess, solver_options: dict | None = None, method: str = "ocp",
                   form: str | None = None, warm: WarmStart | NewtonWarm | None = None
                   ) -> tuple[Solution, WarmStart | NewtonWarm | None]:
    """Solve the belief-space OCP; also return the primal-dual point for a later warm start.

    Strategy (after the Newton solver where it applies, each attempt is IPOPT on the same
    NLP; they differ in the Hessian, the starting point and the barrier update):

    With `solver.name: newton`, or `auto` (the default) where it applies (`newton_applies`):
    first the projected Newton method of `newton.py` (no IPOPT); if it converges, that is
    the solution. If not (a violated depth bound, which only IPOPT has, or no convergence
    in `surrogate_max_iter` iterations), IPOPT follows as below from `init`. (Starting
    IPOPT from Newton's last iterate instead was measured worse: on evaluation
    configuration 0 at T = 20 it failed after 6530 iterations, 26 s.)

    A Newton solution returns its joints (`NewtonWarm`) as the warm start: the next Newton
    solve starts there (the re-solve after a 3 mm / 2 degree camera move at T = 20: 4.5 ms
    median, `benchmarks/solve_speed.py`).

    0. With `warm` (a previous IPOPT solve's primal-dual point, e.g. before the camera moved):
       the exact Hessian from there (near an optimum Newton converges fast; measured at
       T = 20: 13.7 ms median, against 39.5 ms with Gauss-Newton), or the forced Hessian
       with `solver.hessian: surrogate | gauss-newton`.
    1. With the surrogate Hessian (`solver.hessian: auto` or `surrogate`) or Gauss-Newton:
       at most `solver.surrogate_max_iter` iterations (auto) or `solver.max_iter` (forced)
       from `init`. A converged run is a KKT point of the true problem (the Hessian only
       shapes the steps), so it is returned as it is.
    2. (auto) If it stopped short, the exact Hessian, warm-started from where it stopped.
    3. If nothing converged, or with `solver.hessian: exact`: the exact Hessian from
       `init` with the adaptive barrier update, then with the monotone one (measured:
       each fails on some problems where the other succeeds; the barrier strategy is left
       alone when the caller or the problem file sets it).
    4. If every converged point is worse than the cold start and the start is feasible (every
       bound met; the straight line's IK normally is), the start itself is returned, status
       `Initial_Guess_Kept` (success: a valid plan, never worse than where we began), with
       no warm-start point (None). This happens when the steps cross the axis-angle cut at
       rotations of pi (evaluation configurations 0, 36, 45, 91 of 100). A retry with the
       exact Hessian from `init` used to run first: it never ended below the start there
       (16 of 16 solves of the OCP variants) and cost 1-7 s, so it was dropped.

    Every attempt is reported in `extras["attempts"]` (with `kept`); time and iterations
    are their sums; `extras["worse_than_initial_guess"]` flags a kept point above the start
    (an infeasible start that could not be kept).
    Returns a Solution whatever IPOPT's status; check `success` (the CLI turns a failure
    into an error carrying the status).
    """
    form = resolve_form(setup.model, form or setup.problem.solver.covariance)
    hessian = resolve_hessian(setup, form)
    spec, opts = setup.problem.solver, dict(solver_options or {})
    if spec.codegen is True and hessian == "exact":
        raise SurestepError(CODEGEN_EXACT)
    pinned = "ipopt.mu_strategy" in opts or "mu_strategy" in spec.options
    tried: list[tuple[str, Solution, WarmStart | NewtonWarm | None]] = []
    used: list[Transcription] = []

    def attempt(name: str, hess: str, extra: dict, start: WarmStart | None) -> bool:
        extra = {**extra, **WARM_OPTIONS} if start is not None else extra
        used.append(transcription(setup, form, {**opts, **extra}, hessian=hess))
        sol, reached = used[-1].solve(setup, init, method, warm=start)
        tried.append((name + (", warm start" if start is not None else ""), sol, reached))
        return sol.success

    pre, cold = None, init
    if form == "full" and hessian == "surrogate" and warm is None:
        # The lifted NLP starts at the condensed solution (joints; means, covariances and multipliers follow):
        # from the straight line IPOPT's filter accepted first steps whose covariances left the recursion and the
        # PSD cone (lifted.py), although the step in the joints equals the condensed one.
        pre = solve_ocp_warm(setup, init, solver_options, method, "condensed")[0]
        if pre.success:
            init = InitialGuess(np.array(pre.q), f"condensed solution ({init.source})")
    done = False
    forced = spec.hessian in ("surrogate", "gauss-newton")  # no exact-Hessian attempts
    newton_fits = newton_applies(setup, form, hessian, forced)
    if spec.name == "newton" and not newton_fits:
        raise SurestepError("solver.name: newton needs the condensed form of a model with constant motion and "
                            "observation maps, noise.observation_noise: mean, solver.hessian: auto and exactly six joints moving the "
                            "tracked frame (the goal pose then fixes the last joints); use solver.name: auto or ipopt")
    warm_given = warm is not None
    if spec.name in ("newton", "auto") and newton_fits and (warm is None or isinstance(warm, NewtonWarm)):
        start = init if warm is None else InitialGuess(np.asarray(warm.q), f"warm start ({init.source})")
        first = newton_solver(setup).solve(setup, start, method, tol=spec.tol,
                                           max_iter=min(spec.surrogate_max_iter, spec.max_iter),
                                           verbose=spec.print_level > 0)
        tried.append(("newton" + (", warm start" if warm is not None else ""), first,
                      NewtonWarm(np.array(first.q)) if first.success else None))
        done = first.success
    if isinstance(warm, NewtonWarm):  # IPOPT has no multipliers from Newton: it starts cold from init
        warm = None
    if warm is not None:  # near the optimum already: Newton's local convergence (the lifted form: its own Hessian)
        hess = hessian if forced or form == "full" else "exact"
        done = attempt(hess, hess, {}, warm)
    if not done and hessian != "exact":
        cap = spec.max_iter if forced else min(spec.surrogate_max_iter, spec.max_iter)
        near = LIFTED_FROM_CONDENSED if pre is not None and pre.success and not pinned else {}
        done = attempt("lifted" if form == "full" else hessian, hessian, {"ipopt.max_iter": cap, **near}, None)
        if not done and not forced and form == "condensed":  # polish from the point reached (same variables)
            done = attempt("exact", "exact", {}, tried[-1][2])
    if not done and not forced:
        done = attempt("exact", "exact", {}, None)
        if not done and not pinned:
            attempt("exact, monotone barrier", "exact", {"ipopt.mu_strategy": "monotone"}, None)
    finished = [k for k, (_, s_k, _) in enumerate(tried) if s_k.success]
    pick = min(finished, key=lambda k: tried[k][1].objective) if finished else len(tried) - 1
    smooth0 = setup.problem.objective.smoothness * float(np.sum(np.diff(np.asarray(cold.q, float), axis=0) ** 2))

    def start_objective(s_k: Solution) -> float:  # the planner's objective at the cold start (trace + smoothness)
        return s_k.extras["initial_trace"] * (1 + smooth0)

    if finished and warm is None and tried[pick][1].objective > start_objective(tried[pick][1]):
        # Every converged point is above the (cold) start: keep the start if it is a feasible plan, rather than
        # return a plan worse than the one we began from (step 4). Reported as its own attempt.
        start = used[-1].start_solution(setup, init, method) if used else None  # same start point and bounds
        if start is not None:
            ran = sorted({s_k.extras["solver"] for _, s_k, _ in tried})
            start.extras["solver"] = f"none (the initial guess; {', '.join(ran)} converged above it)"
            tried.append(("none: the feasible initial guess, below every converged point", start, None))
            pick = len(tried) - 1
    sol, last = tried[pick][1], tried[pick][2]
    sol.extras["attempts"] = [{"hessian": name, "status": s_k.status, "iterations": s_k.iterations,
                               "solve_time_s": s_k.solve_time_s, "objective": s_k.objective, "kept": k == pick,
                               "compiled": s_k.extras["compiled"]}
                              for k, (name, s_k, _) in enumerate(tried)]
    sol.extras["hessian"] = " + ".join(name for name, _, _ in tried)
    sol.extras["initial_objective"] = start_objective(sol)
    sol.extras["worse_than_initial_guess"] = bool(sol.objective > sol.extras["initial_objective"])
    sol.extras["init"] = init.source if not warm_given else f"warm start ({init.source})"
    sol.solve_time_s = sum(s_k.solve_time_s for _, s_k, _ in tried)
    sol.iterations = sum(s_k.iterations for _, s_k, _ in tried)
    if pre is not None:  # the condensed solve that started the lifted one: reported, and counted in time
        sol.extras["condensed_start"] = {"status": pre.status, "iterations": pre.iterations, "solver":
                                         pre.extras.get("solver"), "solve_time_s": pre.solve_time_s,
                                         "objective": pre.objective}
        sol.extras["initial_trace"] = pre.extras["initial_trace"]
        sol.extras["initial_objective"] = pre.extras["initial_objective"]
        sol.extras["worse_than_initial_guess"] = bool(sol.objective > sol.extras["initial_objective"])
        sol.solve_time_s += pre.solve_time_s
        sol.iterations += pre.iterations
    return sol, last


_NEWTON: dict[tuple, NewtonSolver] = {}


def newton_solver(setup: Setup) -> NewtonSolver:
    """The (cached) projected Newton solver of this setup's structure (`solver.name: newton`)."""
    model, prob = setup.model, setup.problem
    codegen = resolve_codegen(setup, "surrogate")
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(), model.key(), model.scalar,
           prob.horizon, prob.objective.smoothness, codegen, prob.solver.codegen is True)
    if key not in _NEWTON:
        _NEWTON[key] = NewtonSolver(setup.robot, model, prob.horizon, prob.objective.smoothness, codegen,
                                    codegen_required=prob.solver.codegen is True)
    return _NEWTON[key]


def cached_transcriptions() -> list[Transcription]:
    """The transcriptions built so far in this process (e.g. to report their build times)."""
    return list(_CACHE.values())
