"""A plan's certificate from the problem's own functions, whichever backend made it.

The OCP in joint space: minimise `f(q) = Tr(Sigma_T(q)) / trace_ref + smoothness sum |dq_t|^2`
over the moving joints of q_1..q_T, subject to the terminal mean `mu(q_T) = mu_goal`, the joint
bounds (the RCM distance on the insertion with enforced limits), `z(q_t) >= min_depth` and, with
`limits.enforce`, the played curve's rows (`model/limits/curve.py`). The covariance is the model's
6x6 EKF (`BeliefModel.step_pair`, whatever recursion the backend used), differentiated by CasADi's
reverse mode; the multipliers are estimated by bounded least squares on the active rows; the trace
is recomputed by a NumPy EKF written here (Joseph form, no CasADi recursion). `certify` computes the
record, `judge` gives a Solution its meaning of success (docs/certificate.md).

What it costs (docs/certificate.md, "What it costs"): everything a structure (robot, belief model,
horizon, smoothness, enforced limits) fixes is built once per process and kept here; the one
CasADi Function (objective, its gradient, the means and their Jacobians, the noise maps the NumPy
EKF takes) is evaluated in place (`buffered.py`), interpreted at first and compiled to C (or loaded
from the compile cache, `codegen.py`) at the structure's `COMPILE_AFTER`-th certificate in the
process, as `solver.codegen` allows; the multipliers' bounded least squares runs only when an
inequality row is active, as a non-negative least squares on the rows the equality multipliers
leave; the limit rows and their gradients are NumPy arrays over all rows at once. A re-plan (a
Planner's, from a moving start: docs/certificate.md, "Re-plans") keeps its horizon's rows with the
start state as values (`_Rows.at`) and is evaluated by the padded Function of its horizon's bucket
(`PAD_STEPS`, `_padded_call`; its tool rates likewise, `PAD_POINTS`): a loop's horizons share a
few Functions, with the values each horizon's own would give.
"""

from __future__ import annotations

import math
import time
from copy import copy
from dataclasses import replace

import casadi as ca
import numpy as np
from scipy.optimize import lsq_linear, nnls
from scipy.sparse import csr_matrix

from ..buffered import thread_buffered
from ..model import limits as lm
from ..model.belief import DIAG, NV, NX, unvech_many, vech
from ..model.joint_noise import joint_noise_function
from ..model.lie import np_means
from ..model.limits import problem_limits
from ..model.robot import CAMERA_PARAMETERS
from ..output.certificate import Certificate, Tolerances, level_of
from ..output.solution import Solution
from ..output.solution_records import StartState
from ..problem.setup import Setup
from .codegen import available as compiler_available
from .codegen import compiled_or_interpreted

FEASIBILITY = 1e-6  # IPOPT's acceptable_constr_viol_tol (nlp_cache.solver_options)
ACCEPTABLE = 1e-3  # IPOPT's acceptable_tol where the problem stops at that level (ENFORCED_OPTIONS)
TRACE_RTOL = 1e-6  # two EKF passes in double precision agree far better
ACTIVE = 1e-4  # an inequality row within this of its bound (its own units) is active
S_MAX = 100.0  # IPOPT's s_max of the dual scale
# the certificate of one structure in a process at which its Function is compiled (or loaded from
# the compile cache): `surestep solve` (its plan and the baseline it is compared with: two) stays
# interpreted (a compile takes about 1 s, a cached load about 20 ms, one interpreted evaluation
# 0.5-1.5 ms); a process that plans the structure again (compare, evaluate, a benchmark, a
# re-planning loop) evaluates it compiled from its third certificate on
COMPILE_AFTER = 3
# a re-plan's certificate is evaluated by the Function of its horizon rounded up to a multiple of
# this (padded; `_padded_call`): a re-planning loop's horizons share a few Functions, compiled in
# its first episode, instead of one per horizon, each compiled at its third use
PAD_STEPS = 16
PAD_POINTS = 64  # ... and its tool rates' map of points (rounded up to a multiple of this)
_OFF_DIAGONAL = ~np.eye(NX, dtype=bool)


def tolerances(setup: Setup) -> Tolerances:
    """The problem's tolerances: `solver.tol` for stationarity and complementarity, IPOPT's
    acceptable level, the constraints' acceptable violation."""
    tol = float(setup.ocp.solver.tol)
    acceptable = float(setup.ocp.solver.options.get("acceptable_tol", ACCEPTABLE))
    return Tolerances(FEASIBILITY, tol, max(acceptable, tol), tol, TRACE_RTOL)


class _Function:
    """A certificate's Function of one structure: interpreted at first, compiled to C (or loaded
    from the compile cache) at its `COMPILE_AFTER`-th use in the process where the problem's
    `solver.codegen` allows (auto with a C compiler, or true; a compile that fails leaves it
    interpreted, `note` says why: the certificate never stops a solve)."""

    def __init__(self, fn: ca.Function, **facts):
        self.fn, self.facts = fn, facts
        self.uses, self.settled, self.compiled, self.note = 0, False, False, None

    def current(self, codegen, built: list[float]) -> ca.Function:
        """The Function to evaluate now (`built[0]` += the seconds a compile or load took)."""
        self.uses += 1
        if not self.settled and self.uses >= COMPILE_AFTER:
            self.settled = True
            if codegen is True or (codegen == "auto" and compiler_available()):
                t0 = time.perf_counter()
                name = self.fn.name()
                fns, self.note = compiled_or_interpreted({name: self.fn}, required=False)
                self.fn, self.compiled = fns[name], self.note is None
                built[0] += time.perf_counter() - t0
        return self.fn

    def settle(self, codegen, built: list[float]) -> None:
        """Compiled (or loaded) now where `codegen` allows, as at its `COMPILE_AFTER`-th use."""
        self.uses = max(self.uses, COMPILE_AFTER - 1)
        self.current(codegen, built)
        self.uses -= 1  # (not a use)


_FUNCTIONS: dict[tuple, _Function] = {}


def padded_steps(T: int) -> int:
    """The steps of the padded Function a re-plan over T steps is certified with: T rounded up
    to a multiple of PAD_STEPS (a re-planning loop's horizons share a few Functions)."""
    return -(-T // PAD_STEPS) * PAD_STEPS


def _function(setup: Setup, built: list[float], padded: bool = False) -> _Function:
    """The certificate's Function of this setup's structure, `(Q, camera, sigma0, trace_ref) ->
    (f, trace, grad f, means, mean Jacobians, W, V, F, Q, H, R, W_q)` (built once per process).
    `padded`: over `padded_steps(T)` steps N instead, with two more inputs, `(select, steps)` (1 x
    N each): the trace is `select`'s weighted sum of the steps' traces (one-hot at step T) and the
    smoothness sums the steps `steps` weighs (ones on the first T); the joints after q_T repeat it
    (`_padded_call`)."""
    robot, model, T = setup.robot, setup.model, setup.ocp.horizon
    if padded:
        T = padded_steps(T)
    key = (str(robot.urdf), robot.frame, robot.offset.tobytes(), model.key(), T,
           setup.ocp.smoothness, padded)
    if key in _FUNCTIONS:
        return _FUNCTIONS[key]
    t0 = time.perf_counter()
    nq = robot.nq
    Q = ca.MX.sym("Q", nq, T + 1)
    cam, s0, ref = ca.MX.sym("camera", CAMERA_PARAMETERS), ca.MX.sym("sigma0", NV), ca.MX.sym("r")
    M = robot.camera_pose.map(T + 1)(Q, cam)
    a, b = M[:, :T], M[:, 1:]
    if model.joint_noise:
        w = joint_noise_function(robot, model.noise.joint_sigma).map(T)(Q[:, :T], Q[:, 1:], cam)
    else:
        w = ca.MX.zeros(NV, T)
    roll = model.step_pair.mapaccum("certificate_roll", T, [2], [0])
    post, prior = roll(a, b, s0, w)
    kept = prior if model.noise.objective == "predicted" else post
    extra = []
    if padded:
        select, steps = ca.MX.sym("select", 1, T), ca.MX.sym("steps", 1, T)
        extra = [select, steps]
        trace = ca.dot(select, sum(kept[i, :] for i in DIAG))
        dQ = Q[:, 1:] - Q[:, :T]
        f = trace / ref + setup.ocp.smoothness * ca.dot(steps, ca.sum1(dQ * dQ))
    else:
        last = kept[:, T - 1]
        trace = sum(last[i] for i in DIAG)
        f = trace / ref + setup.ocp.smoothness * ca.sumsqr(Q[:, 1:] - Q[:, :T])
    q1 = ca.SX.sym("q", nq)
    c1 = ca.SX.sym("camera", CAMERA_PARAMETERS)
    jac = ca.Function("mean_jacobian", [q1, c1],
                      [ca.densify(ca.jacobian(robot.camera_pose(q1, c1), q1))])
    J = jac.map(T + 1)(Q, cam)  # 7 x nq (T+1)
    # what the NumPy EKF takes: the model's noise (and, not identity, its maps) at the means
    has_v = model.noise.observation_noise == "mean"
    none = ca.MX.zeros(1, 1)
    W = model.motion_noise.map(T)(a, b)
    V = model.observation_noise.map(T)(b) if has_v else none
    maps = list(model.jacobians.map(T)(a, b)) if not model.identity_maps else [none] * 4
    fn = ca.Function("certificate_padded" if padded else "certificate", [Q, cam, s0, ref, *extra],
                     [ca.densify(v) for v in
                      (f, trace, ca.gradient(f, ca.vec(Q)), M, J, W, V, *maps,
                       w if model.joint_noise else none)])
    _FUNCTIONS[key] = _Function(fn, has_v=has_v, has_maps=not model.identity_maps,
                                has_joint=model.joint_noise, steps=T)
    built[0] += time.perf_counter() - t0
    return _FUNCTIONS[key]


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


def _quat_angle(a, b) -> float:
    """The angle [rad] between two unit quaternions `(w, x, y, z)` (either sign), from the
    relative rotation's vector part (accurate for small angles, unlike arccos); in plain floats."""
    aw, ax, ay, az = (float(v) for v in a)
    bw, bx, by, bz = (float(v) for v in b)
    na, nb = math.sqrt(aw * aw + ax * ax + ay * ay + az * az), math.sqrt(
        bw * bw + bx * bx + by * by + bz * bz)
    aw, ax, ay, az = aw / na, ax / na, ay / na, az / na
    bw, bx, by, bz = bw / nb, bx / nb, by / nb, bz / nb
    # a_w b_v - b_w a_v - a_v x b_v
    vx = aw * bx - bw * ax - (ay * bz - az * by)
    vy = aw * by - bw * ay - (az * bx - ax * bz)
    vz = aw * bz - bw * az - (ax * by - ay * bx)
    dot = aw * bw + ax * bx + ay * by + az * bz
    return 2 * math.atan2(math.sqrt(vx * vx + vy * vy + vz * vz), abs(dot))


_GOALS: dict[bytes, np.ndarray] = {}


def _goal_mean(setup: Setup) -> np.ndarray:
    """The goal's mean `(p, Q)` up to the quaternion's sign (`Setup.m_goal` on its sheet; the
    terminal measures do not depend on it), kept per goal pose."""
    x = np.asarray(setup.x_goal, float)
    key = x.tobytes()
    if key not in _GOALS:
        if len(_GOALS) > 4096:
            _GOALS.clear()
        _GOALS[key] = np_means(x)[0]
    return _GOALS[key]


class _Rows:
    """The enforced motion-limit rows of the joint trajectory, `|A x + a| <= 1` (linear, over the
    node-major joints) and the tool's rates `<= 1` (nonlinear), each normalised by its limit."""

    def __init__(self, setup: Setup, start_state=None):
        robot, T, dt = setup.robot, setup.ocp.horizon, float(setup.ocp.timing.step_s)
        lim = _limits(setup)
        nq, mov = robot.nq, robot.supporting_joints()
        moving = start_state is not None
        rows, joints = lm.curve_limit_rows(T, dt, lim, mov, moving)
        lower, upper = lm.joint_bounds(robot, lim.rcm_min_distance)
        Rp, jp, off = lm.curve_position_rows(T, dt, lower, upper, mov, moving)
        R = np.vstack([rows, Rp])
        J = np.concatenate([joints, jp])
        a = np.concatenate([np.zeros(len(rows)), off])
        # each row acts on one joint at every node: its entries at (node t, joint J) node-major
        W = R[:, :T + 1]
        keep = np.any(np.abs(W) > 1e-12 * np.abs(W).max(), axis=1)
        W, cols = W[keep], np.arange(T + 1)[None, :] * nq + J[keep][:, None]
        A = np.zeros((len(W), (T + 1) * nq))
        A[np.arange(len(W))[:, None], cols] = W
        self.A, self.a = A, a[keep]  # (dense: the active rows' gradients are its rows)
        # (sparse: each row touches one joint at a few nodes)
        self.sparse = csr_matrix((W.ravel(), cols.ravel(), np.arange(len(W) + 1) * (T + 1)),
                                 shape=A.shape)
        self.sparse.eliminate_zeros()
        windows, weights, consts = lm.tool_point_windows(T, dt, moving)
        self.windows, self.weights = np.array(windows), weights
        self.offsets = np.zeros((len(windows), 2 * nq))
        # a moving start's rows: the start's velocity and acceleration enter as values only
        # (`at`), in the kept rows' constants and the tool points' offsets
        self.base_a = self.a
        self.start_rows = (R[keep, T + 1], R[keep, T + 2], J[keep]) if moving else None
        self.start_consts = consts if moving else None
        # each point's weights on every node (a repeated end node has its weight in one slot)
        npts = len(windows)
        self.node_q = np.zeros((npts, T + 1))
        self.node_v = np.zeros((npts, T + 1))
        for slot in range(4):
            np.add.at(self.node_q, (np.arange(npts), self.windows[:, slot]), weights[:, slot])
            np.add.at(self.node_v, (np.arange(npts), self.windows[:, slot]), weights[:, 4 + slot])
        # a moving start's (a re-plan's): the tool rates' map over the points rounded up to a
        # multiple of PAD_POINTS (zeros after the points), shared by a loop's horizons
        self.mapped = -(-npts // PAD_POINTS) * PAD_POINTS if moving else npts
        self.rate = _tool_rate(robot, lim, self.mapped)
        self.nq, self.T = nq, T
        if moving:
            self.a, self.offsets = self._start_values(start_state)

    def _start_values(self, start_state) -> tuple[np.ndarray, np.ndarray]:
        """(the linear rows' constants, the tool points' offsets) from a moving start's velocity
        and acceleration."""
        rv, ra, J = self.start_rows
        v0 = np.asarray(start_state.velocity, float)
        a0 = np.asarray(start_state.acceleration, float)
        c = self.start_consts
        return (self.base_a + rv * v0[J] + ra * a0[J],
                np.hstack([np.outer(c[:, 0], v0) + np.outer(c[:, 1], a0),
                           np.outer(c[:, 2], v0) + np.outer(c[:, 3], a0)]))

    def at(self, start_state) -> _Rows:
        """These rows (built for a moving start) from `start_state`: a shallow copy sharing the
        rows' structure (built once per horizon), with the values that state gives."""
        out = copy(self)
        out.a, out.offsets = self._start_values(start_state)
        return out

    def values(self, q: np.ndarray, codegen, built: list[float]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the linear rows A x + a, the tool rows (2 per point), the tool rates' Jacobians over
        each point's position and velocity (points x 2 x 2 nq)) at the joints q."""
        lin = self.sparse @ q.ravel() + self.a
        Wq = q[self.windows]  # points x 4 x nq
        z = np.hstack([np.einsum("pw,pwj->pj", self.weights[:, :4], Wq),
                       np.einsum("pw,pwj->pj", self.weights[:, 4:], Wq)]) + self.offsets
        fn = self.rate.current(codegen, built)
        npts = len(self.windows)
        if self.mapped > npts:
            z = np.vstack([z, np.zeros((self.mapped - npts, z.shape[1]))])
        r, Jz = thread_buffered(("tool_rate", fn), lambda: fn)(z.T)
        # (column-major: r 2 x points, Jz 2 x points 2 nq)
        r, Jz = r[:2 * npts], Jz[:4 * self.nq * npts]
        return lin, r.copy(), Jz.reshape(npts, 2 * self.nq, 2).transpose(0, 2, 1).copy()

    def tool_gradients(self, rows: np.ndarray, Jz: np.ndarray) -> np.ndarray:
        """The gradients over the node-major joints of the tool rows `rows` (row 2 p + k: point p's
        rate k): d row / d q_m = node_q[p, m] dz_q + node_v[p, m] dz_v."""
        nq, p, k = self.nq, rows // 2, rows % 2
        Jq, Jv = Jz[p, k, :nq], Jz[p, k, nq:]  # rows x nq each
        G = (self.node_q[p][:, :, None] * Jq[:, None, :]
             + self.node_v[p][:, :, None] * Jv[:, None, :])
        return G.reshape(len(rows), (self.T + 1) * nq)


class _Layout:
    """What a structure fixes for the certificate: the free joints (the moving joints of q_1..q_T,
    node-major), the bounds and where the terminal rows act."""

    def __init__(self, setup: Setup):
        robot, T = setup.robot, setup.ocp.horizon
        nq = robot.nq
        self.mov = np.array(robot.supporting_joints(), int)
        self.held = np.setdiff1d(np.arange(nq), self.mov)
        lo, hi = np.array(robot.lower, float), np.array(robot.upper, float)
        if setup.ocp.limits.enforce:
            lo, hi = lm.joint_bounds(robot, _limits(setup).rcm_min_distance)
        self.lo, self.hi = lo, hi
        free = np.zeros((T + 1, nq), bool)
        free[1:, self.mov] = True
        self.free = free.ravel()
        self.idx = np.flatnonzero(self.free)  # free -> node-major position
        self.lo_x, self.hi_x = np.tile(lo, T + 1)[self.idx], np.tile(hi, T + 1)[self.idx]
        self.terminal = len(self.idx) - len(self.mov)  # the last node's free joints start here


_LAYOUTS: dict[tuple, _Layout] = {}


_LIMITS: dict[tuple, object] = {}


def _limits(setup: Setup):
    """The problem's motion limits (`problem_limits`), kept per robot and `limits:` section."""
    key = (str(setup.robot.urdf), tuple(setup.robot.joint_names), setup.ocp.limits)
    if key not in _LIMITS:
        _LIMITS[key] = problem_limits(setup)
    return _LIMITS[key]


def _layout(setup: Setup, built: list[float]) -> _Layout:
    robot = setup.robot
    key = (str(robot.urdf), robot.frame, robot.offset.tobytes(), setup.ocp.horizon,
           setup.ocp.limits if setup.ocp.limits.enforce else None)
    if key not in _LAYOUTS:
        t0 = time.perf_counter()
        _LAYOUTS[key] = _Layout(setup)
        built[0] += time.perf_counter() - t0
    return _LAYOUTS[key]


def certify(setup: Setup, sol: Solution, fd_step: float | None = None,
            padded: bool | None = None) -> Certificate | None:
    """The certificate of `sol`'s plan for `setup`'s OCP (the method's own setup); None where a
    waypoint has no joints (a pose-space plan not reachable). `fd_step` [rad, m]: the objective's
    gradient by central differences of the NumPy EKF instead (an independent check, slow).
    `padded`: evaluated by the Function of the horizon rounded up to a multiple of PAD_STEPS (the
    same values: a re-planning loop's horizons share a few Functions); default: for a plan from a
    moving start (a re-plan within enforced limits)."""
    t0 = time.perf_counter()
    if any(q is None for q in sol.q) or len(sol.q) != setup.ocp.horizon + 1:
        return None
    # built once per structure, their time not the certificate's: the Function (compiled at its
    # COMPILE_AFTER-th use), the layout, the rows
    built = [0.0]
    q = np.asarray(sol.q, float)
    ref = sol.run.initial_trace if sol.run.initial_trace else max(sol.trace_final, 1e-300)
    args = (setup.camera_parameter(), vech(setup.ocp.sigma0), ref)
    # a re-plan from a moving start (a re-planning loop: a new horizon every frame): the padded
    # Function of its horizon's bucket; else (or where padding gave a non-finite value) its own
    if padded is None:
        padded = sol.run.start_state is not None
    out = _padded_call(setup, q, args, built) if padded and setup.ocp.horizon > 0 else None
    if out is None:
        holder = _function(setup, built)
        fn = holder.current(setup.ocp.solver.codegen, built)
        evaluate = thread_buffered(("certificate", fn), lambda: fn)  # (in the time: new one too)
        out = evaluate(q.T, *args)
    else:
        holder, out = out
    lay = _layout(setup, built)
    limited = setup.ocp.limits.enforce
    rows_at = _limit_rows(setup, sol, built) if limited else None
    T, nq = setup.ocp.horizon, setup.robot.nq
    tol = tolerances(setup)
    trace = float(out[1][0])
    g = out[2] if fd_step is None else _fd_gradient(setup, q, ref, fd_step)  # node-major
    M = out[3].reshape(T + 1, 7)
    J = out[4].reshape(T + 1, nq, 7)  # J[t, j]: d mean_t / d q_t,j
    # primal measures
    goal = _goal_mean(setup)
    term_p = float(np.linalg.norm(M[T, :3] - goal[:3]))
    term_a = _quat_angle(M[T, 3:], goal[3:])
    held = lay.held
    moved = max(float(np.max(np.abs(q[0] - setup.q_start))),
                float(np.max(np.abs(q[:, held] - setup.q_start[held]), initial=0.0)))
    qm = q[1:, lay.mov]
    lo, hi = lay.lo[lay.mov], lay.hi[lay.mov]
    beyond = float(np.max(np.maximum(lo - qm, 0) + np.maximum(qm - hi, 0)))
    depth_slack = M[1:T, 2] - setup.ocp.min_depth
    depth = float(max(0.0, -depth_slack.min())) if T > 1 else 0.0
    # the inequality rows c(x) <= 0 near their bound: their gradients over the free joints
    xf = q.ravel()[lay.idx]
    at_lo = np.flatnonzero(xf - lay.lo_x <= ACTIVE)
    at_hi = np.flatnonzero(lay.hi_x - xf <= ACTIVE)
    nf = len(lay.idx)
    cols, slack = [], []
    if len(at_lo) or len(at_hi):
        C = np.zeros((nf, len(at_lo) + len(at_hi)))
        C[at_lo, np.arange(len(at_lo))] = -1.0
        C[at_hi, len(at_lo) + np.arange(len(at_hi))] = 1.0
        cols.append(C)
        slack += [xf[at_lo] - lay.lo_x[at_lo], lay.hi_x[at_hi] - xf[at_hi]]
    near = np.flatnonzero(depth_slack <= ACTIVE) + 1  # the waypoints at the depth bound
    if len(near):
        C = np.zeros((len(near), T + 1, nq))
        C[np.arange(len(near)), near] = -J[near, :, 2]
        cols.append(C.reshape(len(near), -1)[:, lay.idx].T)
        slack.append(depth_slack[near - 1])
    limit_violation = None
    if limited:
        rows, lin, tool, Jz = rows_at(q)
        limit_violation = float(max(0.0, np.max(np.abs(lin) - 1, initial=0.0),
                                    np.max(tool - 1, initial=0.0)))
        up, down = np.flatnonzero(1 - lin <= ACTIVE), np.flatnonzero(1 + lin <= ACTIVE)
        fast = np.flatnonzero(1 - tool <= ACTIVE)
        if len(up) or len(down) or len(fast):
            cols.append(np.vstack([rows.A[up], -rows.A[down],
                                   rows.tool_gradients(fast, Jz)])[:, lay.idx].T)
            slack += [1 - lin[up], 1 + lin[down], 1 - tool[fast]]
    # stationarity on the free joints: grad f + J_E^T lam + J_A^T nu = 0, nu >= 0
    gf = g[lay.idx]
    B_E = J[T, lay.mov, :]  # the terminal rows act on the last node's free joints only
    if cols:
        B_A = np.hstack(cols)
        lam, nu, r = _multipliers(gf, B_A, B_E, lay.terminal)
        mult = np.concatenate([lam, nu])
        compl = float(np.max(np.abs(nu * np.maximum(np.concatenate(slack), 0.0)), initial=0.0))
    else:  # no inequality active: the equality multipliers alone, by least squares
        r = gf.copy()
        lam = np.linalg.lstsq(B_E, -gf[lay.terminal:], rcond=None)[0]
        r[lay.terminal:] += B_E @ lam
        mult, compl = lam, 0.0
    s_d = max(S_MAX, float(np.mean(np.abs(mult)))) / S_MAX if mult.size else 1.0
    # the trace by the NumPy EKF, against the planner's report and this function's
    W = _out_blocks(out[5], T)
    if holder.facts["has_joint"]:
        W = W + unvech_many(out[11].reshape(T, NV))
    V = _out_blocks(out[6], T) if holder.facts["has_v"] else None
    maps = (tuple(_out_blocks(out[k], T) for k in (7, 8, 9, 10)) if holder.facts["has_maps"]
            else None)
    trace_np = numpy_trace(setup, M, q, (W, V, maps))
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
        complementarity=compl / s_d, dual_scale=s_d, active_rows=len(mult) - 7,
        trace=trace_np, trace_error=float(trace_error), tolerances=tol, level="infeasible",
        time_s=0.0)
    return replace(cert, level=level_of(cert), time_s=time.perf_counter() - t0 - built[0])


def _padded_call(setup: Setup, q: np.ndarray, args: tuple, built: list[float]):
    """(holder, outputs) of the padded Function at the plan `q` (T + 1 waypoints): the joints
    after q_T repeat it, the trace selected at step T, the smoothness over the first T steps;
    each output cut to what the plan's own Function gives (every output's first T or T + 1
    columns: the steps after T do not reach them). None where an output is not finite."""
    T = len(q) - 1
    holder = _function(setup, built, padded=True)
    N = holder.facts["steps"]
    fn = holder.current(setup.ocp.solver.codegen, built)
    Q = np.vstack([q, np.repeat(q[-1:], N - T, axis=0)])
    select, steps = np.zeros(N), np.zeros(N)
    select[T - 1], steps[:T] = 1.0, 1.0
    out = thread_buffered(("certificate", fn), lambda: fn)(Q.T, *args, select, steps)
    nq = q.shape[1]
    # per column: f, trace, grad f, M, J, W, V, F, Q, H, R, W_q (one-column outputs: the whole)
    size = [1, 1, nq * (T + 1), 7 * (T + 1), 7 * nq * (T + 1)] + [NX * NX * T] * 6 + [NV * T]
    cut = [v if v.size <= 1 else v[:n] for v, n in zip(out, size)]
    if not all(np.all(np.isfinite(v)) for v in cut[:5]):
        return None
    return holder, cut


def _out_blocks(v: np.ndarray, T: int) -> np.ndarray:
    """(T, 6, 6) from the flat (column-major) values of a 6 x 6T output."""
    return v.reshape(T, NX, NX).transpose(0, 2, 1)


def _multipliers(g: np.ndarray, B_A: np.ndarray, B_E: np.ndarray, start: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lam, nu >= 0, residual g + B_E lam + B_A nu) minimising the residual's 2-norm, where the
    equality rows' gradients `B_E` (the last node's free joints x 7) act on the free joints from
    `start` on: nu by non-negative least squares on what the equality rows' span leaves (projected
    out), over the free joints an active row touches (the others' residual is g's whatever nu),
    then lam by least squares: the minimum of the bounded least squares over (lam, nu) together,
    whose residual is unique."""
    U, sv, _ = np.linalg.svd(B_E, full_matrices=False)
    U = U[:, sv > (sv[0] if sv.size else 0.0) * max(B_E.shape) * np.finfo(float).eps]

    def project(X):
        X = X.copy()
        X[start:] -= U @ (U.T @ X[start:])
        return X

    A, y = project(B_A), -project(g)
    touched = np.flatnonzero(np.any(A != 0, axis=1))
    try:
        nu = nnls(A[touched], y[touched], maxiter=50 * A.shape[1])[0]
    except RuntimeError:  # (not converged: the bounded least squares over both at once)
        lb = np.concatenate([np.full(B_E.shape[1], -np.inf), np.zeros(B_A.shape[1])])
        full = np.hstack([np.vstack([np.zeros((start, B_E.shape[1])), B_E]), B_A])
        x = lsq_linear(full, -g, bounds=(lb, np.inf), method="bvls", tol=1e-14).x
        lam, nu = x[:B_E.shape[1]], x[B_E.shape[1]:]
        return lam, nu, g + full @ x
    r = g + B_A @ nu
    lam = np.linalg.lstsq(B_E, -r[start:], rcond=None)[0]
    r[start:] += B_E @ lam
    return lam, nu, r


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
_RATES: dict[tuple, _Function] = {}


def _tool_rate(robot, lim, npts: int) -> _Function:
    """`z (2 nq x points) -> (rates 2 x points, their Jacobians 2 x 2 nq points)`: the tool's
    squared speed and rotation rate over their limits at each point's joints and velocities
    (shared by a structure's rows and its moving starts')."""
    key = (str(robot.urdf), robot.frame, robot.offset.tobytes(), float(lim.tool_speed),
           float(lim.tool_rotation), lm.TOOL_MARGIN, npts)
    if key not in _RATES:
        nq = robot.nq
        qa, qd = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
        Ta = robot.fk_expr(qa, robot.frame)
        k = 1 - lm.TOOL_MARGIN
        rate = ca.vertcat(ca.sumsqr(ca.jtimes(Ta[:3, 3], qa, qd)) / (k * lim.tool_speed) ** 2,
                          0.5 * ca.sumsqr(ca.jtimes(ca.vec(Ta[:3, :3]), qa, qd))
                          / (k * lim.tool_rotation) ** 2)
        z = ca.vertcat(qa, qd)
        one = ca.Function("tool_rate", [z], [rate, ca.densify(ca.jacobian(rate, z))])
        _RATES[key] = _Function(one.map("certificate_tool_rate", "serial", npts, [], []))
    return _RATES[key]


def _limit_rows(setup: Setup, sol: Solution, built: list[float]):
    """The limit rows' values at q: `(rows, linear rows, tool rows, tool Jacobians)` (cached per
    structure; a moving start's built each time; `built[0]` += the seconds building took)."""
    t0 = time.perf_counter()
    state = sol.run.start_state
    rows = _rows(setup, state)
    built[0] += time.perf_counter() - t0
    if state is not None:  # (its values from the start state; the structure kept)
        rows = rows.at(state)
    codegen = setup.ocp.solver.codegen
    return lambda q: (rows, *rows.values(q, codegen, built))


def _rows(setup: Setup, state) -> _Rows:
    """The limit rows' structure of this setup's horizon, from rest or (`state` given) from a
    moving start, built once per process."""
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(),
           setup.ocp.horizon, float(setup.ocp.timing.step_s), setup.ocp.limits,
           state is not None)
    if key not in _ROWS:
        _ROWS[key] = _Rows(setup, state)
    return _ROWS[key]


def prepare_replans(setup: Setup) -> float:
    """Build now what certifying a re-plan over `setup`'s horizon from a moving start uses: the
    padded Function of its horizon's bucket, its limit rows' structure and their tool rates' map,
    the Functions compiled (or loaded from the compile cache) where the problem's codegen allows.
    The Planner calls it for every horizon it may re-plan over, so that no build or compile (about
    1 s) falls inside a re-planning loop. Returns the seconds it took."""
    t0, built = time.perf_counter(), [0.0]
    if setup.ocp.horizon <= 0:
        return 0.0
    codegen = setup.ocp.solver.codegen
    _function(setup, built, padded=True).settle(codegen, built)
    _layout(setup, built)
    if setup.ocp.limits.enforce:
        zero = [0.0] * setup.robot.nq
        _rows(setup, StartState(zero, zero)).rate.settle(codegen, built)
    return time.perf_counter() - t0


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
