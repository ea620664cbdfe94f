"""The condensed, gain-lifted and diagonal transcriptions of the belief-space OCP (IPOPT).

Direct multiple shooting over joints and belief mean. Per node t = 0..T: joints `q_t` and mean
`mu_t` (camera-frame position and unit quaternion, 7 numbers: rotation-valued, no axis-angle chart),
tied by `mu_t = pose_in_camera(FK(q_t))` (`Robot.camera_pose`: the FK quaternion); joint limits, a
minimum depth, `q_0`, `mu_0`, `Sigma_0` fixed and `mu_T = x^G` (hard; the goal's quaternion on the
goal joints' sheet). Objective: `Tr(Sigma_T)` divided by the initial guess's value, plus an optional
joint-step smoothness term. The covariance forms (`solver.covariance`):

* `condensed`: no covariance variables; the EKF recursion is written out in the objective (six
  scalar Kalman updates for a scalar model, the 6x6 recursion otherwise). With the surrogate or
  Gauss-Newton Hessian the derivatives are built stage-wise (`_staged_derivatives`, `stages.py`) and
  compiled.
* `full` with the exact Hessian: `vech(Sigma_t)` per node and a free gain `K_t` per interval, the
  step in Joseph form, which is smallest at the Kalman gain (no symbolic inverse; any F, Q, H, R).
  The lifted form with the structured Hessian is `lifted.py`.
* `diagonal`: six scalar covariances per node with free scalar gains.

The NLP is parametric in the camera pose (the robot base in the camera frame), the scales and
Sigma_0, so one built solver serves every start, goal and camera pose of a given structure and
horizon (`nlp_cache.transcription` caches it). Measurements: docs/method.md and
docs/hessian_and_newton.md.

With `limits` (a problem's `limits.enforce: true`, `limits.py`) the NLP also carries the motion
limits, each row normalised by its limit (so every bound is 1). By default
(`limits.CURVE_ROWS = "curve"`, `_limit_rows`) they bound the curve `surestep export` plays at the
planned times: linear rows on its velocity and acceleration control points, the tool's speeds at
points inside every step. With "steps" (before, kept for measurements): joint velocities
`(q_t+1 - q_t) / (dt v_max)` and accelerations `(q_t+1 - 2 q_t + q_t-1) / (dt^2 a_max)` of the
moving joints, linear, with the plan at rest before q_0 and after q_T (q_-1 = q_0, q_T+1 = q_T: a
plan is a motion from rest to rest, as `limits.py` reports it and `surestep export` runs it); per
interval the tool's squared translation `|p(q_t+1) - p(q_t)|^2 / (v_tool dt)^2` and its rotation
`(3 - tr(R_t^T R_t+1)) / (2 - 2 cos(w_tool dt))` (the angle between the two orientations is at most
`w_tool dt` exactly when this is at most 1), with the frame's FK (no needle offset); and the RCM
distance as a lower bound on the PSM's insertion joint (`limits.rcm_insertion_bound`).
"""

from __future__ import annotations

import time


import casadi as ca
import numpy as np

from ..model.belief import DIAG, NM, NV, NX, BeliefModel, unvech, vech
from .codegen import compiled_or_interpreted
from ..errors import SurestepError
from ..problem.solver_config import HESSIANS
from .iterate import InitialGuess, PrimalDual
from ..model.joint_noise import (joint_noise_expr, joint_noise_factor, joint_noise_function,
                                 weight_matrix)
from ..model import limits as lm
from ..model.limits import MotionLimits
from ..model.robot import CAMERA_PARAMETERS, Robot
from ..problem.setup import Setup
from ..output.solution import Solution, evaluate
from ..output.solution_records import SolveRecord
from .stages import assemble, entries, smoothness_matrix
from .surrogate import interval_terms, pose_function, recursion_weights, scalar_trace

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
        return np.concatenate([np.asarray(values[name], float).ravel()
                               for name, _, _ in self.blocks])


class Transcription:
    """The multiple-shooting NLP of one structure (robot, belief model, horizon, form), built
    once."""

    def __init__(self, robot: Robot, model: BeliefModel, horizon: int, form: str, smoothness: float,
                 options: dict, hessian: str = "exact", codegen: bool = False,
                 codegen_required: bool = False, limits: tuple[float, MotionLimits] | None = None):
        self.robot, self.model, self.T, self.form = robot, model, horizon, form
        self.limits = limits  # (step_s, MotionLimits) enforced as constraints, or None
        self.scalar = form == "condensed" and model.scalar
        T, nq = horizon, robot.nq
        ns = NX if form == "diagonal" else NV
        self.ns = ns
        L = self.layout = _Layout()
        qs, mus, ss, Ks = [], [], [], []
        for t in range(T + 1):
            qs.append(L.add(f"q{t}", nq))
            mus.append(L.add(f"mu{t}", NM))
            if form == "condensed":
                continue
            ss.append(L.add(f"s{t}", ns))
            if t < T:
                Ks.append(L.add(f"K{t}", NX * NX if form == "full" else NX))
        # Parameters: robot base in the camera frame (3x4), covariance scales, trace reference.
        Tcb = ca.SX.sym("camera", CAMERA_PARAMETERS)
        scale = ca.SX.sym("scale", T + 1)
        trace_ref = ca.SX.sym("trace_ref")
        sigma0 = ca.SX.sym("sigma0", NV)
        self.p = ca.vertcat(ca.vec(Tcb), scale, trace_ref, sigma0)

        pose = pose_function(robot)
        self.joint_fn = (joint_noise_function(robot, model.noise.joint_sigma) if model.joint_noise
                         else None)
        # W_q, vech
        wq = [self.joint_fn(qs[t], qs[t + 1], Tcb) if self.joint_fn else None for t in range(T)]

        g = [mus[t] - pose(qs[t], Tcb) for t in range(T + 1)]
        # needs the condensed form (solver_config.resolve)
        predicted = model.noise.objective == "predicted"
        if form == "condensed":  # the covariance is shot through the EKF steps inside the objective
            # exact: six scalar Kalman recursions (in Sigma_0's eigenbasis when isotropic)
            if self.scalar:
                trace_T = scalar_trace(
                    sigma0, [ca.diag(model.motion_noise(mus[t], mus[t + 1])) for t in range(T)],
                    [lambda p, t=t: ca.diag(model.planning_noise(mus[t + 1], vech(ca.diag(p))))
                     for t in range(T)],
                    predicted)
            else:
                s_t = sigma0
                for t in range(T - 1):
                    s_t = model.step_expr(mus[t], mus[t + 1], s_t, wq[t])
                last = model.predict_expr if predicted else model.step_expr
                s_t = last(mus[T - 1], mus[T], s_t, wq[T - 1])
                trace_T = sum(s_t[i] for i in DIAG)
        else:
            for t in range(T):
                g.append(self._step(mus[t], mus[t + 1], scale[t] * ss[t], Ks[t], wq[t])
                         / scale[t + 1]
                         - ss[t + 1])
            trace_T = scale[T] * (ca.sum1(ss[T]) if form == "diagonal"
                                  else sum(ss[T][i] for i in DIAG))
        self.poses = pose.map(T + 1)  # (q columns, T_cam_base) -> mean columns, for initial points
        # Tr(Sigma_T) the planner minimises
        self.trace = ca.Function("trace", [L.vector(), self.p], [trace_T])
        f = trace_T / trace_ref
        if smoothness > 0:
            f += smoothness * sum(ca.sumsqr(qs[t + 1] - qs[t]) for t in range(T))
        self.ng_eq = ca.vertcat(*g).shape[0]  # the equality rows; the limit rows (if any) follow
        self._limit_rows(L.vector(), qs, g)
        self.ng = ca.vertcat(*g).shape[0]
        self.hessian, self.hess_lag = hessian, None
        # solver_config.resolve rejects these for users: a caller's bug
        if hessian not in HESSIANS or (
                hessian != "exact" and (form != "condensed" or not model.structured)) or (
                hessian == "exact" and codegen):
            raise ValueError(f"no {hessian} Hessian (codegen {codegen}) for the {form} form "
                             "of this model")
        self.codegen, self.codegen_note = codegen, None
        t0 = time.perf_counter()
        if hessian != "exact":
            staged = self._staged_derivatives(pose, sigma0, trace_ref, smoothness)
            # compiled: the derivatives' time per solve several times lower (docs/solve_speed.md)
            if codegen:
                staged, self.codegen_note = compiled_or_interpreted(staged, codegen_required)
                self.codegen = self.codegen_note is None
            self.hess_lag = staged["hess_lag"]
            options = {**options, **staged}
        self.solver = ca.nlpsol("surestep_ocp", "ipopt",
                                {"x": L.vector(), "f": f, "g": ca.vertcat(*g), "p": self.p},
                                options)
        self.build_time_s = time.perf_counter() - t0

    def _limit_rows(self, x: ca.SX, qs: list, g: list) -> None:
        """Append the motion-limit rows (module docstring) to `g`: the linear ones `A x`
        (A constant), then the tool's normalised translation and rotation (`self.tool_point`, of a
        window of waypoints per point).

        `limits.CURVE_ROWS` "curve" (the default): the rows bound the curve `surestep export` plays
        at the planned times (`limits.py`, "the played curve"): joint acceleration by the Bernstein
        control points of each step's cubic (linear, sufficient everywhere), joint velocity at the
        knots within `v_max - a_max dt / 2` (sufficient given the acceleration rows; the quartic's
        control points where that is not positive), the tool's squared speed `|J_v(q(s)) q'(s)|^2`
        and rotation `|J_w q'|^2` at `limits.TOOL_POINTS` of each step, each point a function of the
        four waypoints the piece depends on. "steps": the finite differences of the waypoints
        (velocity per step, acceleration per waypoint, the tool's chord per step), as before; kept
        for measurements."""
        self.n_lin = self.n_tool = 0
        self.A, self.tool_point, self.rcm_bound, self.limit_g = None, None, None, None
        # the curve's tool rows as a function of (q(s), q'(s)) (`_tool_stages`)
        self.tool_rate = None
        if self.limits is None:
            return
        dt, lim = self.limits
        T, nq, n = self.T, self.robot.nq, x.shape[0]
        idx = self._q_index()
        mov = self.robot.supporting_joints()
        self.curve = lm.CURVE_ROWS
        if self.curve not in ("curve", "steps"):
            raise SurestepError(f"limits.CURVE_ROWS must be 'curve' or 'steps', got {self.curve!r}")
        if self.curve == "curve":
            rows, joints = lm.curve_limit_rows(T, dt, lim, mov)  # the interior point's too
        else:
            # (q_t+1 - q_t) / dt per step; acceleration at waypoint t, at rest before q_0 and after
            # q_T
            Rv = (np.eye(T + 1, k=1) - np.eye(T + 1))[:T] / dt
            Ra = lm.knot_derivatives(T, dt)[1]
            rows = [row / scale[j] for R, scale in ((Rv, lim.velocity), (Ra, lim.acceleration))
                    for row in R for j in mov]
            joints = [j for R in (Rv, Ra) for _ in R for j in mov]
        # the joint bounds on the curve between the waypoints (the insertion's lower one from the
        # RCM distance): |row . x + offset| <= 1 (the interior point's rows too)
        Rp, jp, off = lm.curve_position_rows(T, dt, *lm.joint_bounds(self.robot,
                                                                      lim.rcm_min_distance), mov)
        offsets = np.concatenate([np.zeros(len(rows)), off])
        blocks = []
        for row, j in zip([*rows, *Rp], [*joints, *jp]):
            B = np.zeros(n)
            B[[idx[m][j] for m in range(T + 1)]] = row
            blocks.append(B)
        self.A = np.array(blocks)
        # exact zeros, rounded
        self.A[np.abs(self.A) < 1e-12 * np.abs(self.A).max(axis=1, keepdims=True)] = 0.0
        # rows that are 0 by construction (the velocities at rest)
        nonzero = np.any(self.A != 0, axis=1)
        self.A, self.A_offset = self.A[nonzero], offsets[nonzero]
        self.n_lin = len(self.A)
        qa, qd = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
        Ta = self.robot.fk_expr(qa, self.robot.frame)
        if self.curve == "curve":
            win = 4
            pv = ca.jtimes(Ta[:3, 3], qa, qd)  # the tool's velocity [m/s] (world frame), and dR/dt
            Rd = ca.jtimes(ca.vec(Ta[:3, :3]), qa, qd)
            # the speed between the points may exceed theirs a little (the export checks)
            k = 1 - lm.TOOL_MARGIN
            rate = ca.Function("tool_rate", [qa, qd],
                               [ca.vertcat(ca.sumsqr(pv) / (k * lim.tool_speed) ** 2,
                                           0.5 * ca.sumsqr(Rd) / (k * lim.tool_rotation) ** 2)])
            w, c = ca.SX.sym("w", win * nq), ca.SX.sym("c", 2 * win)
            ws = ca.reshape(w, nq, win)
            out = rate(ws @ c[:win], ws @ c[win:])
            self.tool_rate = rate
            windows, weights, _ = lm.tool_point_windows(T, dt)
        else:
            win = 2
            # c unused: the chord of (q_t, q_t+1)
            w, c = ca.SX.sym("w", win * nq), ca.SX.sym("c", 2 * win)
            Tb = self.robot.fk_expr(w[nq:], self.robot.frame)
            Tw = self.robot.fk_expr(w[:nq], self.robot.frame)
            rows = [ca.sumsqr(Tb[:3, 3] - Tw[:3, 3]) / (lim.tool_speed * dt) ** 2]
            if lim.tool_rotation * dt < np.pi:  # else any rotation is within the limit
                rows.append((3 - ca.sum1(ca.sum2(Tw[:3, :3] * Tb[:3, :3])))
                            / (2 - 2 * np.cos(lim.tool_rotation * dt)))
            out = ca.vertcat(*rows)
            windows, weights = [[t, t + 1] for t in range(T)], [np.zeros(2 * win)] * T
        self.tool_point = ca.Function("tool_point", [w, c], [out])
        self.tool_windows = windows  # per point: the waypoints (node indices) it depends on
        self.tool_weights = ca.DM(np.array(weights).T)  # (2 win, points)
        self.tool_k = out.shape[0]
        self.n_tool = self.tool_k * len(windows)
        lin = ca.mtimes(ca.sparsify(ca.DM(self.A)), x)
        W = ca.horzcat(*[ca.vertcat(*[qs[m] for m in nodes]) for nodes in windows])
        tool = ca.vec(self.tool_point.map(len(windows))(W, self.tool_weights))
        g += [lin, tool]
        self.limit_g = ca.Function("limit_g", [x], [ca.vertcat(lin, tool)])
        self.rcm_bound = lm.rcm_insertion_bound(self.robot, lim.rcm_min_distance)

    def _q_index(self) -> list[np.ndarray]:
        offsets = dict(zip((name for name, _, _ in self.layout.blocks),
                           np.cumsum([0] + [size for _, size, _ in self.layout.blocks])))
        return [np.arange(offsets[f"q{t}"], offsets[f"q{t}"] + self.robot.nq)
                for t in range(self.T + 1)]

    def g_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """lbg, ubg: the equalities at 0, every normalised limit row at most 1 (the linear ones at
        least -1)."""
        off = self.A_offset if self.n_lin else np.zeros(0)
        lo = np.concatenate([np.zeros(self.ng_eq), -1.0 - off, np.full(self.n_tool, -np.inf)])
        hi = np.concatenate([np.zeros(self.ng_eq), 1.0 - off, np.ones(self.n_tool)])
        return lo, hi

    def _violation(self, g: np.ndarray) -> float:
        """Largest violation of the constraint rows (the equalities' |g|, the limit rows' excess
        over 1)."""
        lo, hi = self.g_bounds()
        return float(np.max(np.maximum(lo - g, 0) + np.maximum(g - hi, 0))) if len(g) else 0.0

    def _staged_derivatives(self, pose: ca.Function, sigma0, trace_ref, smoothness) -> dict:
        """Objective gradient, constraint Jacobian and a structured Hessian of the Lagrangian, built
        stage-wise.

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
        a, b = ca.SX.sym("a", NM), ca.SX.sym("b", NM)
        # the joint-space term: its own (q_t, q_t+1) stage
        jv = ca.SX.sym("w_q", NV) if m.joint_noise else None
        (res_m, res_o), coefficients, (wm, wo, wj), weighted = interval_terms(m, a, b, jv)
        coef = ca.Function("coef", [a, b], list(coefficients[:2]))
        ab = ca.vertcat(a, b)
        if self.hessian == "surrogate":  # exact curvature of the weighted coefficients
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
        q, lam, Tcb = (ca.SX.sym("q", nq), ca.SX.sym("lam", NM),
                       ca.SX.sym("camera", CAMERA_PARAMETERS))
        # g_t = mu_t - pose(q_t): Jacobian -d pose/dq (and I in the mean); curvature -Hess(lam .
        # pose)
        node_jac = ca.Function("node_jac", [q, Tcb], [ca.densify(-ca.jacobian(pose(q, Tcb), q))])
        node_hess = ca.Function("node_hess", [q, lam, Tcb],
                                [ca.densify(ca.hessian(-ca.dot(lam, pose(q, Tcb)), q)[0])])

        # Where each stage output's entries go (column-major within each stage block).
        offsets = dict(zip((name for name, _, _ in self.layout.blocks),
                           np.cumsum([0] + [size for _, size, _ in self.layout.blocks])))
        mu_idx = [np.arange(offsets[f"mu{t}"], offsets[f"mu{t}"] + NM) for t in range(T + 1)]
        q_idx = [np.arange(offsets[f"q{t}"], offsets[f"q{t}"] + nq) for t in range(T + 1)]
        ab_idx = [np.concatenate([mu_idx[t], mu_idx[t + 1]]) for t in range(T)]
        g_idx = [np.arange(NM * t, NM * (t + 1)) for t in range(T + 1)]

        D = smoothness_matrix(n, q_idx, smoothness)

        X, P = ca.MX.sym("x", n), ca.MX.sym("p", self.p.shape[0])
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", self.ng)
        Tcb_x, sigma0_x, ref_x = ca.Function("params", [self.p],
                                             [self.p[:CAMERA_PARAMETERS], sigma0, trace_ref])(P)
        mus = ca.horzcat(*[X[i[0]:i[0] + NM] for i in mu_idx])
        qs = ca.horzcat(*[X[i[0]:i[0] + nq] for i in q_idx])
        qq_idx = [np.concatenate([q_idx[t], q_idx[t + 1]]) for t in range(T)]
        qab_x = ca.vertcat(qs[:, :T], qs[:, 1:])
        joint = self._joint_stages(wj, Tcb) if jv is not None else None
        cj = joint["coef"].map(T)(qab_x, Tcb_x) if joint else ca.MX(0, T)
        S_x, w_m, w_o, w_j = weights(*coef.map(T)(mus[:, :T], mus[:, 1:]), cj, sigma0_x, ref_x)
        G = interval_grad.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        B = interval_hess.map(T)(mus[:, :T], mus[:, 1:], w_m, w_o)
        Jq = node_jac.map(T + 1)(qs, Tcb_x)
        K = node_hess.map(T + 1)(qs, ca.reshape(lam_g[:NM * (T + 1)], NM, T + 1), Tcb_x)
        smooth_f = 0.5 * ca.bilin(ca.DM(D), X, X) if smoothness > 0 else 0

        grad_parts = ([entries([(i, [0]) for i in ab_idx])]
                      + ([entries([(i, [0]) for i in qq_idx])] if joint else []))
        grad_sp, sc_g, _ = assemble((n, 1), grad_parts)
        grad_nz = ca.mtimes(sc_g[0], ca.vec(G))
        if joint:
            grad_nz += ca.mtimes(sc_g[1], ca.vec(joint["grad"].map(T)(qab_x, w_j, Tcb_x)))
        grad = ca.MX(grad_sp, grad_nz)
        if smoothness > 0:
            grad = ca.densify(grad) + ca.mtimes(ca.DM(D), X)
        grad_f = ca.Function("nlp_grad_f", [X, P], [S_x + smooth_f, ca.densify(grad)], ["x", "p"],
                             ["f", "grad"])

        jac_parts = [entries(list(zip(g_idx, q_idx))), entries(list(zip(g_idx, mu_idx)))]
        hess_parts = [entries([(i, i) for i in ab_idx]), entries([(i, i) for i in q_idx])]
        g_x = ca.vec(mus - ca.Function("poses", [q, Tcb], [pose(q, Tcb)]).map(T + 1)(qs, Tcb_x))
        lin_const, g_lim = None, []
        # the limit rows: A x (constant Jacobian), then the tool rows per point
        if self.limits is not None:
            k, npts = self.tool_k, len(self.tool_windows)
            tool_jac, tool_hess = self._tool_stages()
            win_idx = [np.concatenate([q_idx[m] for m in nodes]) for nodes in self.tool_windows]
            t_idx = [self.ng_eq + self.n_lin + np.arange(k * p, k * (p + 1)) for p in range(npts)]
            jac_parts.append(entries(list(zip(t_idx, win_idx))))
            hess_parts.append(entries([(i, i) for i in win_idx]))
            lin_const = np.zeros((self.ng, n))
            lin_const[self.ng_eq:self.ng_eq + self.n_lin] = self.A
            W_x = ca.reshape(X[np.concatenate(win_idx).tolist()], tool_jac.size1_in(0), npts)
            Jt = tool_jac.map(npts)(W_x, self.tool_weights)
            Ht = tool_hess.map(npts)(W_x, self.tool_weights,
                                     ca.reshape(lam_g[self.ng_eq + self.n_lin:], k, npts))
            A_sp = ca.sparsify(ca.DM(self.A))
            g_lim = [ca.mtimes(A_sp, X), ca.vec(self.tool_point.map(npts)(W_x, self.tool_weights))]
        jac_sp, sc_j, jconst = assemble((self.ng, n), jac_parts, lin_const)
        J_nz = (ca.mtimes(sc_j[0], ca.vec(Jq))
                + ca.mtimes(sc_j[1], ca.DM(np.tile(np.eye(NM).ravel(order="F"), T + 1))))
        if self.limits is not None:
            J_nz += jconst + ca.mtimes(sc_j[2], ca.vec(Jt))
        jac_g = ca.Function("nlp_jac_g", [X, P], [ca.vertcat(g_x, *g_lim), ca.MX(jac_sp, J_nz)],
                            ["x", "p"], ["g", "jac"])

        if joint:
            hess_parts.append(entries([(i, i) for i in qq_idx]))
        hess_sp, sc_h, const = assemble((n, n), hess_parts, np.triu(D))
        sc_b, sc_k = sc_h[:2]
        H_nz = lam_f * (ca.mtimes(sc_b, ca.vec(B)) + const) + ca.mtimes(sc_k, ca.vec(K))
        if self.limits is not None:
            H_nz += ca.mtimes(sc_h[2], ca.vec(Ht))
        if joint:
            H_nz += lam_f * ca.mtimes(sc_h[-1], ca.vec(joint["hess"].map(T)(qab_x, w_j, Tcb_x)))
        hess_lag = ca.Function("nlp_hess_l", [X, P, lam_f, lam_g], [ca.MX(hess_sp, H_nz)],
                               ["x", "p", "lam_f", "lam_g"], ["hess"])
        return {"grad_f": grad_f, "jac_g": jac_g, "hess_lag": hess_lag}

    def _tool_stages(self) -> tuple[ca.Function, ca.Function]:
        """One tool point's Jacobian `(w, c) -> d rows / d w` and curvature
        `(w, c, lam) -> Hess_w (lam . rows)` over its window `w` of waypoints (`tool_point`).

        On the played curve a point's joints and joint velocities are linear in the window,
        `z = (q(s), q'(s)) = M w` with `M = [c_q^T kron I; c_v^T kron I]`, so the derivatives are
        the rate's in z (2 nq variables) mapped by M:
        `J = J_z M`, `H = M^T H_z M`, the same matrices as differentiating the composed rows over w
        (4 nq variables) in fewer instructions (docs/motion_limits_and_export.md, "The enforced
        solve's speed"). The finite-difference rows ("steps") are differentiated directly."""
        w_in, c_in = self.tool_point.sx_in()
        lam_k = ca.SX.sym("lam_k", self.tool_k)
        if self.tool_rate is None:
            rows_w = self.tool_point(w_in, c_in)
            return (ca.Function("tool_jac", [w_in, c_in], [ca.densify(ca.jacobian(rows_w, w_in))]),
                    ca.Function("tool_hess", [w_in, c_in, lam_k],
                                [ca.densify(ca.hessian(ca.dot(lam_k, rows_w), w_in)[0])]))
        nq = self.robot.nq
        win = c_in.shape[0] // 2
        z_a, z_d = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
        z = ca.vertcat(z_a, z_d)
        rows_z = self.tool_rate(z_a, z_d)
        jz = ca.Function("tool_jac_z", [z], [ca.densify(ca.jacobian(rows_z, z))])
        hz = ca.Function("tool_hess_z", [z, lam_k],
                         [ca.cse(ca.densify(ca.hessian(ca.dot(lam_k, rows_z), z)[0]))])
        ws = ca.reshape(w_in, nq, win)
        z_w = ca.vertcat(ws @ c_in[:win], ws @ c_in[win:])
        M = ca.vertcat(ca.kron(c_in[:win].T, ca.SX.eye(nq)), ca.kron(c_in[win:].T, ca.SX.eye(nq)))
        return (ca.Function("tool_jac", [w_in, c_in], [ca.densify(jz(z_w) @ M)]),
                ca.Function("tool_hess", [w_in, c_in, lam_k],
                            [ca.densify(M.T @ hz(z_w, lam_k) @ M)]))

    def _joint_stages(self, wj, Tcb) -> dict:
        """The joint-space motion noise's stage Functions of `(q_t, q_t+1)`: its vech (the
        recursion's coefficients `cj`), and the gradient and Hessian of the surrogate's term
        `wj . vech(W_q)` with the weights frozen (the Hessian: exact, or Gauss-Newton's
        `2 sum_k du_k^T G du_k` with `W_q = sum_k u_k u_k^T`, G = dS/dW)."""
        nq = self.robot.nq
        qab = ca.SX.sym("qab", 2 * nq)
        w = vech(joint_noise_expr(self.robot, self.model.noise.joint_sigma, qab[:nq], qab[nq:],
                                  Tcb))
        term = ca.dot(wj, w)
        if self.hessian == "surrogate":
            hess = ca.hessian(term, qab)[0]
        else:
            G = weight_matrix(wj)
            U = joint_noise_factor(self.robot, self.model.noise.joint_sigma, qab[:nq], qab[nq:],
                                   Tcb)
            hess = 0
            for k in range(nq):
                dU = ca.jacobian(U[:, k], qab)
                hess += 2 * dU.T @ G @ dU
        return {"coef": ca.Function("joint_coef", [qab, Tcb], [w]),
                "grad": ca.Function("joint_grad", [qab, wj, Tcb],
                                    [ca.densify(ca.gradient(term, qab))]),
                "hess": ca.Function("joint_hess", [qab, wj, Tcb], [ca.densify(hess)])}

    def _step(self, x0, x1, s, K, w=None):
        m = self.model
        if self.form == "diagonal":
            p = s + ca.diag(m.motion_noise(x0, x1))
            v = ca.diag(m.planning_noise(x1, vech(ca.diag(p))))
            return (1 - K) ** 2 * p + K**2 * v  # scalar Joseph form, gains free (as in `full`)
        p = m.predict_expr(x0, x1, s, w)
        S, H = m.innovation_expr(x0, x1, p)
        P = unvech(p)
        K = ca.reshape(K, NX, NX)
        IKH = ca.DM.eye(NX) - K @ H
        post = IKH @ P @ IKH.T + K @ (S - H @ P @ H.T) @ K.T  # Joseph form; S - H P H^T = R V R^T
        return vech(0.5 * (post + post.T))

    # ------------------------------------------------------------------ one solve
    def guess(self, setup: Setup, q: np.ndarray) -> tuple[dict, np.ndarray]:
        """Consistent primal point (mean, covariance, gains) from a joint trajectory; and the
        scales."""
        model, T = setup.model, self.T  # this setup's Sigma_0 (the cached model may hold another)
        mu = setup.means_of(q)
        sig, pred = model.propagate_means(mu, joint=setup.joint_noises(q))
        out = {}
        for t in range(T + 1):
            out[f"q{t}"], out[f"mu{t}"] = q[t], mu[t]
            out[f"s{t}"] = np.diag(sig[t]) if self.form == "diagonal" else vech(sig[t])
            if t < T and self.form == "diagonal":
                v = np.diag(np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))))
                out[f"K{t}"] = np.diag(pred[t]) / (np.diag(pred[t]) + v)
            elif t < T:
                _, _, H, Rm = (np.asarray(M) for M in model.jacobians(mu[t], mu[t + 1]))
                S = (H @ pred[t] @ H.T + Rm
                     @ np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))) @ Rm.T)
                out[f"K{t}"] = np.linalg.solve(S, H @ pred[t]).T.ravel(order="F")
        scale = np.array([max(np.trace(s) / NX, 1e-14) for s in sig])
        return out, scale

    def bounds(self, setup: Setup, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prob, T, nq = setup.ocp, self.T, self.robot.nq
        movable = set(self.robot.supporting_joints())
        s0 = np.asarray(prob.noise.Sigma0, float)
        lo, hi = {}, {}
        for t in range(T + 1):
            ql, qh = self.robot.lower.copy(), self.robot.upper.copy()
            for j in range(nq):
                if t == 0 or j not in movable:
                    ql[j] = qh[j] = setup.q_start[j]
                elif self.rcm_bound is not None and j == self.rcm_bound[0]:
                    # the RCM distance (limits)
                    ql[j] = min(max(ql[j], self.rcm_bound[1]), qh[j])
            lo[f"q{t}"], hi[f"q{t}"] = ql, qh
            ml, mh = np.full(NM, -np.inf), np.full(NM, np.inf)
            ml[2] = prob.min_depth
            if t == 0:
                ml = mh = setup.m_start
            if t == T:
                ml = mh = setup.m_goal
            lo[f"mu{t}"], hi[f"mu{t}"] = ml, mh
            if t == 0:
                lo["s0"] = hi["s0"] = (np.diag(s0) if self.form == "diagonal"
                                       else vech(s0)) / scale[0]
            else:
                lo[f"s{t}"], hi[f"s{t}"] = np.full(self.ns, -np.inf), np.full(self.ns, np.inf)
                lo[f"s{t}"][slice(None) if self.form == "diagonal" else DIAG] = 0.0
            if t < T:
                nk = NX * NX if self.form == "full" else NX
                lo[f"K{t}"], hi[f"K{t}"] = np.full(nk, -np.inf), np.full(nk, np.inf)
        return self.layout.join(lo), self.layout.join(hi)

    def _parameters(self, setup: Setup, scale: np.ndarray, trace_ref: float) -> np.ndarray:
        sigma0 = np.asarray(setup.ocp.sigma0, float)
        # the scalar recursions start from their channel variances (the trace is the same)
        s0 = setup.model.recursion_sigma0(sigma0) if self.form == "condensed" else vech(sigma0)
        return np.concatenate([setup.camera_parameter(), scale, [trace_ref], s0])

    def _condensed_start(self, setup: Setup,
                         init: InitialGuess) -> tuple[np.ndarray, np.ndarray, float]:
        """Initial point of the condensed form (joints, and their means by FK), scales, and its
        trace."""
        T, q = self.T, np.asarray(init.q, float)
        mu = np.asarray(self.poses(q.T, setup.camera_parameter())).T
        x0 = self.layout.join({**{f"q{t}": q[t] for t in range(T + 1)},
                               **{f"mu{t}": mu[t] for t in range(T + 1)}})
        scale = np.ones(T + 1)  # unused by this form
        return x0, scale, float(self.trace(x0, self._parameters(setup, scale, 1.0)))

    def start_solution(self, setup: Setup, init: InitialGuess,
                       method: str = "ocp") -> Solution | None:
        """The initial guess itself as a plan, if it is feasible (every bound to 1e-9; the kinematic
        constraints hold by construction in the condensed form); None otherwise."""
        if self.form != "condensed":
            return None
        x0, scale, trace_ref = self._condensed_start(setup, init)
        lbx, ubx = self.bounds(setup, scale)
        violation = float(np.max(np.maximum(lbx - x0, 0) + np.maximum(x0 - ubx, 0)))
        # the motion limits too (the kinematic rows hold by construction)
        if self.limit_g is not None:
            violation = max(violation, self._violation(np.concatenate(
                [np.zeros(self.ng_eq), np.asarray(self.limit_g(x0)).ravel()])))
        if violation > 1e-9:
            return None
        q = np.asarray(init.q, float)
        return evaluate(setup, method, setup.poses_of(q), list(q), success=True,
                        status="Initial_Guess_Kept", solve_time_s=0.0, iterations=0,
                        objective=trace_ref,
                        run=SolveRecord(solver="ipopt", init=init.source,
                                        covariance_form=self.form,
                                        build_time_s=self.build_time_s, compiled=self.codegen,
                                        initial_trace=trace_ref, ocp_trace_final=trace_ref,
                                        constraint_violation=violation))

    def solve(self, setup: Setup, init: InitialGuess, method: str = "ocp",
              warm: PrimalDual | None = None) -> tuple[Solution, PrimalDual]:
        T = self.T
        # the solve time counts the set-up of the call (initial point, scales, bounds)
        t0 = time.perf_counter()
        # no covariance variables: means and the trace only
        if warm is None and self.form == "condensed":
            x0, scale, trace_ref = self._condensed_start(setup, init)
        elif warm is None:
            x0, scale = self.guess(setup, np.asarray(init.q, float))
            trace_ref = float(np.sum(np.asarray(x0[f"s{T}"])[slice(None) if self.form == "diagonal"
                                                             else DIAG]))
            for t in range(T + 1):
                x0[f"s{t}"] = x0[f"s{t}"] / scale[t]
            x0 = self.layout.join(x0)
        else:
            x0, scale, trace_ref = warm.x, warm.scale, warm.trace_ref
        lbx, ubx = self.bounds(setup, scale)
        p = self._parameters(setup, scale, trace_ref)
        lbg, ubg = self.g_bounds()
        args = dict(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, p=p)
        if warm is not None:
            args.update(lam_x0=warm.lam_x, lam_g0=warm.lam_g)
        res = self.solver(**args)
        solve_s = time.perf_counter() - t0
        vals = self.layout.split(np.asarray(res["x"]).ravel())
        q = np.array([vals[f"q{t}"] for t in range(T + 1)])
        if self.form == "condensed":
            ocp_trace = float(res["f"]) * trace_ref
        else:
            sT = vals[f"s{T}"] * scale[T]
            ocp_trace = float(np.sum(sT) if self.form == "diagonal" else np.trace(unvech(sT)))
        return ipopt_solution(self, setup, method, init, warm, q, res, solve_s, scale, trace_ref,
                              ocp_trace, self._violation(np.asarray(res["g"]).ravel()), self.form)


def ipopt_solution(tr, setup: Setup, method: str, init, warm, q: np.ndarray, res: dict,
                   solve_s: float, scale: np.ndarray, trace_ref: float, ocp_trace: float,
                   violation: float,
                   form: str) -> tuple[Solution, PrimalDual]:
    """The Solution of one IPOPT solve of transcription `tr` (the exact EKF re-evaluates the plan
    from the Pinocchio FK of its joints), and its primal-dual point as a warm start."""
    stats = tr.solver.stats()
    poses = setup.poses_of(q)
    sol = evaluate(
        setup, method, poses, list(q),
        success=bool(stats["success"]), status=str(stats["return_status"]), solve_time_s=solve_s,
        iterations=int(stats["iter_count"]), objective=float(res["f"]) * trace_ref,
        run=SolveRecord(
            solver="ipopt",
            init=init.source if warm is None else f"warm start ({init.source})",
            covariance_form=form,
            build_time_s=tr.build_time_s,
            compiled=tr.codegen,  # derivatives compiled to C (solver.codegen)
            codegen_note=tr.codegen_note or None,
            initial_trace=trace_ref,  # the planner's objective at the (cold) initial guess
            ocp_trace_final=ocp_trace,
            constraint_violation=violation,
        ),
    )
    return sol, PrimalDual(np.asarray(res["x"]).ravel(), np.asarray(res["lam_x"]).ravel(),
                          np.asarray(res["lam_g"]).ravel(), scale, trace_ref)
