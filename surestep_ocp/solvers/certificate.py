"""A plan's certificate from the problem's own functions, whichever backend made it.

The OCP in joint space: minimise `f(q) = Tr(Sigma_T(q)) / trace_ref + smoothness sum |dq_t|^2`
over the moving joints of q_1..q_T, subject to the terminal mean `mu(q_T) = mu_goal`, the joint
bounds (the RCM distance on the insertion with enforced limits), `z(q_t) >= min_depth` and, with
`limits.enforce`, the played curve's rows (`model/limits/curve.py`). The covariance is the model's
6x6 EKF (`BeliefModel.step_pair`, whatever recursion the backend used), differentiated by CasADi's
reverse mode; the multipliers are estimated by bounded least squares on the active rows; the trace
is recomputed by a NumPy EKF written here (Joseph form, no CasADi recursion). `certify` computes the
record, `judge` gives a Solution its meaning of success (docs/certificate.md).
"""

from __future__ import annotations

import time
from dataclasses import replace

import casadi as ca
import numpy as np
from scipy.optimize import lsq_linear

from ..model import limits as lm
from ..model.belief import DIAG, NV, NX, unvech, vech
from ..model.joint_noise import joint_noise_function
from ..model.limits import problem_limits
from ..model.robot import CAMERA_PARAMETERS
from ..output.certificate import Certificate, Tolerances, level_of
from ..output.solution import Solution
from ..problem.setup import Setup

FEASIBILITY = 1e-6  # IPOPT's acceptable_constr_viol_tol (nlp_cache.solver_options)
ACCEPTABLE = 1e-3  # IPOPT's acceptable_tol where the problem stops at that level (ENFORCED_OPTIONS)
TRACE_RTOL = 1e-6  # two EKF passes in double precision agree far better
ACTIVE = 1e-4  # an inequality row within this of its bound (its own units) is active
S_MAX = 100.0  # IPOPT's s_max of the dual scale
_FUNCTIONS: dict[tuple, ca.Function] = {}


def tolerances(setup: Setup) -> Tolerances:
    """The problem's tolerances: `solver.tol` for stationarity and complementarity, IPOPT's
    acceptable level, the constraints' acceptable violation."""
    tol = float(setup.ocp.solver.tol)
    acceptable = float(setup.ocp.solver.options.get("acceptable_tol", ACCEPTABLE))
    return Tolerances(FEASIBILITY, tol, max(acceptable, tol), tol, TRACE_RTOL)


def _functions(setup: Setup) -> ca.Function:
    """`(Q, camera, sigma0, trace_ref) -> (f, trace, grad f, means, mean Jacobians)`, per
    structure."""
    robot, model, T = setup.robot, setup.model, setup.ocp.horizon
    key = (str(robot.urdf), robot.frame, robot.offset.tobytes(), model.key(), T,
           setup.ocp.smoothness)
    if key in _FUNCTIONS:
        return _FUNCTIONS[key]
    nq = robot.nq
    Q = ca.MX.sym("Q", nq, T + 1)
    cam, s0, ref = ca.MX.sym("camera", CAMERA_PARAMETERS), ca.MX.sym("sigma0", NV), ca.MX.sym("r")
    M = robot.camera_pose.map(T + 1)(Q, cam)
    if model.joint_noise:
        w = joint_noise_function(robot, model.noise.joint_sigma).map(T)(Q[:, :T], Q[:, 1:], cam)
    else:
        w = ca.MX.zeros(NV, T)
    roll = model.step_pair.mapaccum("certificate_roll", T, [2], [0])
    post, prior = roll(M[:, :T], M[:, 1:], s0, w)
    last = (prior if model.noise.objective == "predicted" else post)[:, T - 1]
    trace = sum(last[i] for i in DIAG)
    f = trace / ref + setup.ocp.smoothness * ca.sumsqr(Q[:, 1:] - Q[:, :T])
    q1 = ca.SX.sym("q", nq)
    c1 = ca.SX.sym("camera", CAMERA_PARAMETERS)
    jac = ca.Function("mean_jacobian", [q1, c1],
                      [ca.densify(ca.jacobian(robot.camera_pose(q1, c1), q1))])
    J = jac.map(T + 1)(Q, cam)  # 7 x nq (T+1)
    fn = ca.Function("certificate", [Q, cam, s0, ref],
                     [f, trace, ca.reshape(ca.gradient(f, ca.vec(Q)), nq, T + 1), M, J])
    _FUNCTIONS[key] = fn
    return fn


def numpy_trace(setup: Setup, means: np.ndarray, q: np.ndarray) -> float:
    """Tr(Sigma_T) of the planning model by a plain NumPy EKF (Joseph form) along the means, with
    the model's noise maps evaluated at the waypoints (all at once where they do not depend on
    the prediction)."""
    model = setup.model
    T = len(means) - 1
    a, b = means[:-1].T, means[1:].T
    W = _blocks(_mapped(model, "motion_noise", T)(a, b), T)
    joint = setup.joint_noises(q)
    if joint is not None:
        W = W + np.array([unvech(w) for w in joint])
    if model.identity_maps:
        F = Qm = H = R = np.broadcast_to(np.eye(NX), (T, NX, NX))
    else:
        F, Qm, H, R = (_blocks(m, T) for m in _mapped(model, "jacobians", T)(a, b))
    V = (_blocks(_mapped(model, "observation_noise", T)(b), T)
         if model.noise.observation_noise == "mean" else None)
    S = P = np.asarray(setup.ocp.sigma0, float)
    if V is not None and model.identity_maps and all(_diagonal(X) for X in (S, W, V)):
        # every covariance stays diagonal: six scalar Kalman filters, elementwise
        s, w, v = np.diag(S), np.diagonal(W, axis1=1, axis2=2), np.diagonal(V, axis1=1, axis2=2)
        for t in range(T):
            p = s + w[t]
            k = p / (p + v[t])
            s = (1 - k) ** 2 * p + k**2 * v[t]  # Joseph form
        return float(np.sum(p if model.noise.objective == "predicted" else s))
    for t in range(T):
        P = F[t] @ S @ F[t].T + Qm[t] @ W[t] @ Qm[t].T
        P = 0.5 * (P + P.T)
        Vt = V[t] if V is not None else np.asarray(model.planning_noise(means[t + 1], vech(P)))
        Mo = R[t] @ Vt @ R[t].T
        K = np.linalg.solve(H[t] @ P @ H[t].T + Mo, H[t] @ P).T
        IKH = np.eye(NX) - K @ H[t]
        S = IKH @ P @ IKH.T + K @ Mo @ K.T
        S = 0.5 * (S + S.T)
    return float(np.trace(P if model.noise.objective == "predicted" else S))


def _diagonal(X: np.ndarray) -> bool:
    """Every matrix of X (6x6 or a stack of them) is diagonal."""
    return not np.any(X * (1 - np.eye(NX)))


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


def _quat_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle [rad] between two unit quaternions `(w, x, y, z)` (either sign), from the
    relative rotation's vector part (accurate for small angles, unlike arccos)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    vec = a[0] * b[1:] - b[0] * a[1:] - np.cross(a[1:], b[1:])
    return float(2 * np.arctan2(np.linalg.norm(vec), abs(float(a @ b))))


class _Rows:
    """The enforced motion-limit rows of the joint trajectory, `|A x + a| <= 1` (linear, over the
    node-major joints) and the tool's rates `<= 1` (nonlinear), each normalised by its limit."""

    def __init__(self, setup: Setup, start_state=None):
        robot, T, dt = setup.robot, setup.ocp.horizon, float(setup.ocp.timing.step_s)
        lim = problem_limits(setup)
        nq, mov = robot.nq, robot.supporting_joints()
        moving = start_state is not None
        rows, joints = lm.curve_limit_rows(T, dt, lim, mov, moving)
        lower, upper = lm.joint_bounds(robot, lim.rcm_min_distance)
        Rp, jp, off = lm.curve_position_rows(T, dt, lower, upper, mov, moving)
        R = np.vstack([rows, Rp])
        J = np.concatenate([joints, jp])
        a = np.concatenate([np.zeros(len(rows)), off])
        if moving:
            v0 = np.asarray(start_state.velocity, float)
            a0 = np.asarray(start_state.acceleration, float)
            a = a + R[:, T + 1] * v0[J] + R[:, T + 2] * a0[J]
        A = np.zeros((len(R), (T + 1) * nq))
        for i, (row, j) in enumerate(zip(R, J)):
            A[i, np.arange(T + 1) * nq + j] = row[:T + 1]
        keep = np.any(np.abs(A) > 1e-12 * np.abs(A).max(), axis=1)
        self.A, self.a = A[keep], a[keep]
        windows, weights, consts = lm.tool_point_windows(T, dt, moving)
        self.windows, self.weights = np.array(windows), weights
        self.offsets = np.zeros((len(windows), 2 * nq))
        if moving:
            self.offsets = np.hstack([np.outer(consts[:, 0], v0) + np.outer(consts[:, 1], a0),
                                      np.outer(consts[:, 2], v0) + np.outer(consts[:, 3], a0)])
        qa, qd = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
        Ta = robot.fk_expr(qa, robot.frame)
        k = 1 - lm.TOOL_MARGIN
        rate = ca.vertcat(ca.sumsqr(ca.jtimes(Ta[:3, 3], qa, qd)) / (k * lim.tool_speed) ** 2,
                          0.5 * ca.sumsqr(ca.jtimes(ca.vec(Ta[:3, :3]), qa, qd))
                          / (k * lim.tool_rotation) ** 2)
        z = ca.vertcat(qa, qd)
        self.rate = ca.Function("tool_rate", [z], [rate, ca.jacobian(rate, z)]).map(len(windows))
        self.nq = nq

    def values(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(linear rows A x + a, their Jacobian, tool rows, their Jacobian) at the joints q."""
        nq, x = self.nq, q.ravel()
        Wq = q[self.windows]  # points x 4 x nq
        z = np.hstack([np.einsum("pw,pwj->pj", self.weights[:, :4], Wq),
                       np.einsum("pw,pwj->pj", self.weights[:, 4:], Wq)]) + self.offsets
        r, Jz = (np.asarray(v) for v in self.rate(z.T))
        npts = len(self.windows)
        Jt = np.zeros((npts * 2, x.size))
        for p, nodes in enumerate(self.windows):
            for slot, m in enumerate(nodes):
                cq, cv = self.weights[p, slot], self.weights[p, 4 + slot]
                if cq == 0 and cv == 0:
                    continue
                Jp = Jz[:, 2 * nq * p:2 * nq * (p + 1)]
                block = Jp[:, :nq] * cq + Jp[:, nq:] * cv
                Jt[2 * p:2 * p + 2, m * nq:(m + 1) * nq] += block
        return self.A @ x + self.a, self.A, r.T.ravel(), Jt


def certify(setup: Setup, sol: Solution, fd_step: float | None = None) -> Certificate | None:
    """The certificate of `sol`'s plan for `setup`'s OCP (the method's own setup); None where a
    waypoint has no joints (a pose-space plan not reachable). `fd_step` [rad, m]: the objective's
    gradient by central differences of the NumPy EKF instead (an independent check, slow)."""
    if any(q is None for q in sol.q) or len(sol.q) != setup.ocp.horizon + 1:
        return None
    fn = _functions(setup)  # built once per structure: not in the certificate's time
    rows_at = _limit_rows(setup, sol) if setup.ocp.limits.enforce else None
    t0 = time.perf_counter()
    q = np.asarray(sol.q, float)
    T, nq, robot = setup.ocp.horizon, setup.robot.nq, setup.robot
    tol = tolerances(setup)
    ref = sol.run.initial_trace if sol.run.initial_trace else max(sol.trace_final, 1e-300)
    f, trace, g, M, J = (np.asarray(v) for v in fn(
        q.T, setup.camera_parameter(), vech(setup.ocp.sigma0), ref))
    M, trace = M.T, float(trace.item())
    g = g.T.ravel()  # node-major
    if fd_step is not None:
        g = _fd_gradient(setup, q, ref, fd_step)
    mov = robot.supporting_joints()
    held = np.setdiff1d(np.arange(nq), mov)
    lo, hi = np.array(robot.lower, float), np.array(robot.upper, float)
    limited = setup.ocp.limits.enforce
    if limited:
        lo, hi = lm.joint_bounds(robot, problem_limits(setup).rcm_min_distance)
    # primal measures
    goal = setup.m_goal
    term_p = float(np.linalg.norm(M[T, :3] - goal[:3]))
    term_a = _quat_angle(M[T, 3:], goal[3:])
    moved = max(float(np.max(np.abs(q[0] - setup.q_start))),
                float(np.max(np.abs(q[:, held] - setup.q_start[held]), initial=0.0)))
    qm = q[1:, mov]
    beyond = float(np.max(np.maximum(lo[mov] - qm, 0) + np.maximum(qm - hi[mov], 0)))
    depth = float(max(0.0, setup.ocp.min_depth - M[1:T, 2].min())) if T > 1 else 0.0
    # the inequality rows c(x) <= 0 near their bound, with their gradients (node-major x)
    n = nq * (T + 1)
    free = np.zeros((T + 1, nq), bool)
    free[1:, mov] = True
    free = free.ravel()
    x = q.ravel()
    lo_x, hi_x = np.tile(lo, T + 1), np.tile(hi, T + 1)
    idx = np.flatnonzero(free)
    at_lo = idx[x[idx] - lo_x[idx] <= ACTIVE]
    at_hi = idx[hi_x[idx] - x[idx] <= ACTIVE]
    rows = np.zeros((len(at_lo) + len(at_hi), n))
    rows[np.arange(len(at_lo)), at_lo] = -1.0
    rows[len(at_lo) + np.arange(len(at_hi)), at_hi] = 1.0
    rows = list(rows)
    slack = [*(x[at_lo] - lo_x[at_lo]), *(hi_x[at_hi] - x[at_hi])]
    for t in range(1, T):
        s = M[t, 2] - setup.ocp.min_depth
        if s <= ACTIVE:
            e = np.zeros(n)
            e[t * nq:(t + 1) * nq] = -J[2, t * nq:(t + 1) * nq]
            rows.append(e)
            slack.append(s)
    limit_violation = None
    if limited:
        lin, A, tool, Jt = rows_at(q)
        limit_violation = float(max(0.0, np.max(np.abs(lin) - 1, initial=0.0),
                                    np.max(tool - 1, initial=0.0)))
        for v, grad in ((lin - 1, A), (-lin - 1, -A), (tool - 1, Jt)):
            for i in np.flatnonzero(-v <= ACTIVE):
                rows.append(grad[i])
                slack.append(-v[i])
    # stationarity on the free joints: grad f + J_E^T lam + J_A^T nu = 0, nu >= 0
    E = np.zeros((7, n))
    E[:, T * nq:] = J[:, T * nq:]
    cols = [E] + ([np.array(rows)] if rows else [])
    B = np.vstack(cols)[:, free].T  # free x (7 + active)
    ub = np.full(B.shape[1], np.inf)
    lb = np.concatenate([np.full(7, -np.inf), np.zeros(len(rows))])
    gf = g[free]
    if rows:
        mult = lsq_linear(B, -gf, bounds=(lb, ub), method="bvls", tol=1e-14).x
    else:
        mult = np.linalg.lstsq(B, -gf, rcond=None)[0]
    r = gf + B @ mult
    s_d = max(S_MAX, float(np.mean(np.abs(mult)))) / S_MAX if mult.size else 1.0
    compl = float(np.max(np.abs(mult[7:] * np.maximum(np.array(slack), 0.0)), initial=0.0))
    # the trace by the NumPy EKF, against the planner's report and this function's
    trace_np = numpy_trace(setup, M, q)
    reported = [trace]
    if sol.run.ocp_trace_final is not None:
        reported.append(float(sol.run.ocp_trace_final))
    scale = max(abs(trace_np), 1e-300)
    trace_error = max(abs(v - trace_np) for v in reported) / scale
    cert = Certificate(
        terminal_position_m=term_p, terminal_angle_rad=term_a,
        bound_violation=max(beyond, moved), depth_violation=depth,
        limit_violation=limit_violation,
        stationarity=float(np.max(np.abs(r), initial=0.0)) / s_d,
        complementarity=compl / s_d, dual_scale=s_d, active_rows=len(rows),
        trace=trace_np, trace_error=float(trace_error), tolerances=tol, level="infeasible",
        time_s=0.0)
    return replace(cert, level=level_of(cert), time_s=time.perf_counter() - t0)


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


_ROWS: dict[tuple, _Rows] = {}


def _limit_rows(setup: Setup, sol: Solution):
    """The limit rows' values at q (cached per structure; a moving start's built each time)."""
    state = sol.run.start_state
    if state is not None:
        return _Rows(setup, state).values
    lim = problem_limits(setup)
    key = (str(setup.robot.urdf), setup.robot.frame, setup.ocp.horizon,
           float(setup.ocp.timing.step_s), repr(lim.to_dict()))
    if key not in _ROWS:
        _ROWS[key] = _Rows(setup)
    return _ROWS[key].values


def claims_optimum(method: str) -> bool:
    """Whether the method's plan claims to be an optimum of the OCP (the OCP methods; not the
    baseline, not the gradient variants)."""
    return method.startswith("ocp")


def judge(setup: Setup, sol: Solution, gate: bool = True) -> Solution:
    """Certify `sol` and give it the one meaning of success: an OCP plan succeeds only when its
    certificate is met (optimal, or acceptable where the problem stops at that level); a backend
    success without it is `Not_Certified`. The baseline and the gradient variants claim a completed
    plan, not an optimum: their success stays their own, with the certificate beside it. The
    backend's own status is kept as `sol.backend_status`. `gate` false: certified, success left
    as it is."""
    sol.backend_status = sol.status
    sol.backend_success = sol.success
    sol.certificate = certify(setup, sol)
    if gate and claims_optimum(sol.method) and sol.success and (
            sol.certificate is None or not sol.certificate.certified):
        sol.success, sol.status = False, NOT_CERTIFIED
    return sol


NOT_CERTIFIED = "Not_Certified"
