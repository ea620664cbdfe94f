"""A plan's certificate from the problem's own functions, whichever backend made it.

The OCP in joint space: minimise `f(q) = Tr(Sigma_T(q)) / trace_ref + smoothness sum |dq_t|^2`
over the moving joints of q_1..q_T, subject to the terminal mean `mu(q_T) = mu_goal`, the joint
bounds (the RCM distance on the insertion with enforced limits), `z(q_t) >= min_depth` and, with
`limits.enforce`, the played curve's rows (`model/limits/curve.py`). The covariance is the model's
6x6 EKF (`BeliefModel.step_pair`, whatever recursion the backend used), differentiated by CasADi's
reverse mode; the multipliers are estimated by bounded least squares on the rows within WINDOW of
their bound, the active set chosen by complementarity (multiplier x slack small); the trace
is recomputed by a NumPy EKF of its own (Joseph form, no CasADi recursion). `certify` computes the
record, `judge` gives a Solution its meaning of success (docs/certificate.md).

What it costs (docs/certificate.md, "What it costs"): everything a structure (robot, belief model,
horizon, smoothness, enforced limits) fixes is built once per process and kept here; the one CasADi
Function (objective, its gradient, the means and their Jacobians, the noise maps the NumPy EKF
takes) is evaluated in place (`buffered.py`), interpreted at first and compiled to C (or loaded
from the compile cache, `codegen.py`) at the structure's `COMPILE_AFTER`-th certificate in the
process, as `solver.codegen` allows; the multipliers' bounded least squares runs only when an
inequality row is near its bound, as a non-negative least squares on the rows the equality
multipliers leave; the limit rows and their gradients are NumPy arrays over all rows at once. A
re-plan (a Planner's, from a moving start: docs/certificate.md, "Re-plans") keeps its horizon's rows
with the start state as values (`_Rows.at`) and is evaluated by the padded Function of its
horizon's bucket (`PAD_STEPS`, `_padded_call`; its tool rates likewise, `PAD_POINTS`): a loop's
horizons share a few Functions, with the values each horizon's own would give.

Here: the measures, the multipliers and the verdict. Its parts: the Function per structure
(`certificate_function.py`), the layout and the limit rows (`certificate_rows.py`), the NumPy EKF
and the finite-difference gradient (`certificate_ekf.py`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import lsq_linear, nnls

from ..buffered import thread_buffered
from ..model.belief import NV, unvech_many, vech
from ..model.lie import np_means
from ..output.certificate import ACCEPTABLE as ACCEPTABLE_LEVEL
from ..output.certificate import (FEASIBLE, INFEASIBLE, OPTIMAL, Certificate, Tolerances,
                                  level_of)
from ..output.solution import Solution
from ..output.solution_records import StartState
from ..problem.setup import Setup
from .certificate_ekf import _fd_gradient, _out_blocks, numpy_trace
from .certificate_function import (COMPILE_AFTER, PAD_STEPS, _Function, _function,  # noqa: F401
                                   _padded_call)
from .certificate_rows import _layout, _limit_rows, _rows
# (the per-structure caches and the parts as they were here: the tests and benchmarks use them)
from .certificate_ekf import _MAPS  # noqa: F401
from .certificate_function import _FUNCTIONS, padded_steps  # noqa: F401
from .certificate_rows import (_LAYOUTS, _LIMITS, _RATES, _ROWS, PAD_POINTS,  # noqa: F401
                               _Layout, _limits, _Rows)
from ..status import Status

FEASIBILITY = 1e-6  # IPOPT's acceptable_constr_viol_tol (nlp_cache.solver_options)
ACCEPTABLE = 1e-3  # IPOPT's acceptable_tol where the problem stops at that level (ENFORCED_OPTIONS)
TRACE_RTOL = 1e-6  # two EKF passes in double precision agree far better
# an inequality row within this of its bound (its own units) is a candidate for the active set;
# which candidates carry a multiplier is chosen by complementarity (`_multipliers`)
WINDOW = 1e-2
NARROW = 1e-4  # the rows at their bound, tried first (`Feasibility.complete`)
LEVELS = (INFEASIBLE, FEASIBLE, ACCEPTABLE_LEVEL, OPTIMAL)  # worst first
S_MAX = 100.0  # IPOPT's s_max of the dual scale


def tolerances(setup: Setup) -> Tolerances:
    """The problem's tolerances: `solver.tol` for stationarity and complementarity, IPOPT's
    acceptable level, the constraints' acceptable violation."""
    tol = float(setup.ocp.solver.tol)
    acceptable = float(setup.ocp.solver.options.get("acceptable_tol", ACCEPTABLE))
    return Tolerances(FEASIBILITY, tol, max(acceptable, tol), tol, TRACE_RTOL)


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


def certify(setup: Setup, sol: Solution, fd_step: float | None = None,
            padded: bool | None = None) -> Certificate | None:
    """The certificate of `sol`'s plan for `setup`'s OCP (the method's own setup); None where a
    waypoint has no joints (a pose-space plan not reachable). `fd_step` [rad, m]: the objective's
    gradient by central differences of the NumPy EKF instead (an independent check, slow).
    `padded`: evaluated by the Function of the horizon rounded up to a multiple of PAD_STEPS (the
    same values: a re-planning loop's horizons share a few Functions); default: for a plan from a
    moving start (a re-plan within enforced limits)."""
    part = feasibility(setup, sol, padded)
    return None if part is None else part.complete(fd_step)


@dataclass
class Feasibility:
    """A plan's certificate up to its primal measures (`feasibility`: what decides whether it is
    infeasible, the Planner's gate), and what `complete` needs for the rest (stationarity,
    complementarity)."""

    setup: Setup
    q: np.ndarray
    ref: float
    out: list
    lay: _Layout
    limit_values: tuple | None  # (rows, linear rows' values, tool rows' values, Jz) with limits
    term_p: float
    term_a: float
    bound_violation: float
    depth_slack: np.ndarray
    depth: float
    limit_violation: float | None
    trace: float  # by the NumPy EKF
    trace_error: float
    tolerances: Tolerances
    time_s: float  # its time, builds apart

    def complete(self, fd_step: float | None = None) -> Certificate:
        """The full certificate: the multipliers, stationarity and complementarity added (its
        time: this part's and that)."""
        t0 = time.perf_counter()
        setup, q, out = self.setup, self.q, self.out
        T, nq = setup.ocp.horizon, setup.robot.nq
        g = out[2] if fd_step is None else _fd_gradient(setup, q, self.ref, fd_step)
        J = out[4].reshape(T + 1, nq, 7)  # J[t, j]: d mean_t / d q_t,j (node-major)
        # multipliers that meet the tolerances certify the plan, whichever rows carry them: the
        # rows at their bound first (most optima need no others), the wider window only where
        # they do not make the plan optimal (its NNLS over ~200 rows costs a few ms), the better
        # level of the two kept
        cert = self._judged(g, J, NARROW)
        if cert.level != OPTIMAL and WINDOW > NARROW:
            wide = self._judged(g, J, WINDOW)
            if LEVELS.index(wide.level) >= LEVELS.index(cert.level):
                cert = wide
        return replace(cert, time_s=self.time_s + time.perf_counter() - t0)

    def _judged(self, g: np.ndarray, J: np.ndarray, window: float) -> Certificate:
        """The certificate with the multipliers of the rows within `window` of their bound."""
        T = self.setup.ocp.horizon
        cols, slack = _candidate_rows(self.lay, self.q, J, self.depth_slack, self.limit_values,
                                      window)
        r, mult, compl, s_d = _stationarity(g, self.lay, J, T, cols, slack)
        cert = Certificate(
            terminal_position_m=self.term_p, terminal_angle_rad=self.term_a,
            bound_violation=self.bound_violation, depth_violation=self.depth,
            limit_violation=self.limit_violation,
            stationarity=float(np.max(np.abs(r), initial=0.0)) / s_d,
            complementarity=compl / s_d, dual_scale=s_d,
            active_rows=int(np.count_nonzero(mult[7:] > 0)),
            trace=self.trace, trace_error=self.trace_error, tolerances=self.tolerances,
            level="infeasible", time_s=0.0)
        return replace(cert, level=level_of(cert))


def feasibility(setup: Setup, sol: Solution, padded: bool | None = None) -> Feasibility | None:
    """`certify`'s primal part (`Feasibility`): the Function's evaluation, the terminal, bound,
    depth and limit-row measures, the trace by the NumPy EKF; None where `certify` gives None."""
    t0 = time.perf_counter()
    if any(q is None for q in sol.q) or len(sol.q) != setup.ocp.horizon + 1:
        return None
    # built once per structure, their time not the certificate's: the Function (compiled at its
    # COMPILE_AFTER-th use), the layout, the rows
    built = [0.0]
    q = np.asarray(sol.q, float)
    ref = sol.run.initial_trace if sol.run.initial_trace else max(sol.trace_final, 1e-300)
    holder, out = _evaluated(setup, sol, q, ref, padded, built)
    lay = _layout(setup, built)
    rows_at = _limit_rows(setup, sol, built) if setup.ocp.limits.enforce else None
    T = setup.ocp.horizon
    M = out[3].reshape(T + 1, 7)
    term_p, term_a, beyond, moved, depth_slack, depth = _primal_measures(setup, lay, q, M)
    values, limit_violation = _limit_values(rows_at, q)
    trace_np, trace_error = _trace_check(setup, sol, holder, out, M, q, float(out[1][0]))
    return Feasibility(setup, q, ref, out, lay, values, term_p, term_a,
                       max(beyond, moved), depth_slack, depth, limit_violation, trace_np,
                       float(trace_error), tolerances(setup),
                       time.perf_counter() - t0 - built[0])


def _evaluated(setup: Setup, sol: Solution, q: np.ndarray, ref: float, padded: bool | None,
               built: list[float]) -> tuple[_Function, list]:
    """(holder, outputs) of the certificate's Function at the plan `q` (`certify`'s `padded`)."""
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
    return holder, out


def _primal_measures(setup: Setup, lay, q: np.ndarray, M: np.ndarray) -> tuple:
    """The primal measures: (terminal position error, terminal angle, the largest excess over a
    joint bound, the largest move of a held joint or of q_0, the depth slacks, the depth
    violation)."""
    T = setup.ocp.horizon
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
    return term_p, term_a, beyond, moved, depth_slack, depth


def _limit_values(rows_at, q: np.ndarray) -> tuple[tuple | None, float | None]:
    """The limit rows at the plan `q` (rows, linear rows' values, tool rows' values, Jz) and their
    violation (beyond 1, normalised); (None, None) without enforced limits."""
    if rows_at is None:
        return None, None
    rows, lin, tool, Jz = rows_at(q)
    limit_violation = float(max(0.0, np.max(np.abs(lin) - 1, initial=0.0),
                                np.max(tool - 1, initial=0.0)))
    return (rows, lin, tool, Jz), limit_violation


def _candidate_rows(lay, q: np.ndarray, J: np.ndarray, depth_slack: np.ndarray, values,
                    window: float) -> tuple[list, list]:
    """The inequality rows c(x) <= 0 within `window` of their bound: (their gradients over the
    free joints as column blocks, their slacks); `values` the limit rows' (`_limit_values`)."""
    T, nq = len(q) - 1, q.shape[1]
    xf = q.ravel()[lay.idx]
    at_lo = np.flatnonzero(xf - lay.lo_x <= window)
    at_hi = np.flatnonzero(lay.hi_x - xf <= window)
    nf = len(lay.idx)
    cols, slack = [], []
    if len(at_lo) or len(at_hi):
        C = np.zeros((nf, len(at_lo) + len(at_hi)))
        C[at_lo, np.arange(len(at_lo))] = -1.0
        C[at_hi, len(at_lo) + np.arange(len(at_hi))] = 1.0
        cols.append(C)
        slack += [xf[at_lo] - lay.lo_x[at_lo], lay.hi_x[at_hi] - xf[at_hi]]
    near = np.flatnonzero(depth_slack <= window) + 1  # the waypoints at the depth bound
    if len(near):
        C = np.zeros((len(near), T + 1, nq))
        C[np.arange(len(near)), near] = -J[near, :, 2]
        cols.append(C.reshape(len(near), -1)[:, lay.idx].T)
        slack.append(depth_slack[near - 1])
    if values is not None:
        rows, lin, tool, Jz = values
        up, down = np.flatnonzero(1 - lin <= window), np.flatnonzero(1 + lin <= window)
        fast = np.flatnonzero(1 - tool <= window)
        if len(up) or len(down) or len(fast):
            cols.append(np.vstack([rows.A[up], -rows.A[down],
                                   rows.tool_gradients(fast, Jz)])[:, lay.idx].T)
            slack += [1 - lin[up], 1 + lin[down], 1 - tool[fast]]
    return cols, slack


def _stationarity(g: np.ndarray, lay, J: np.ndarray, T: int, cols: list, slack: list
                  ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Stationarity on the free joints, grad f + J_E^T lam + J_A^T nu = 0 with nu >= 0 over the
    candidate rows, nu x slack small: (its residual, the multipliers, the complementarity (the
    largest multiplier x slack), the dual scale)."""
    gf = g[lay.idx]
    B_E = J[T, lay.mov, :]  # the terminal rows act on the last node's free joints only
    if cols:
        B_A = np.hstack(cols)
        s = np.maximum(np.concatenate(slack), 0.0)
        lam, nu, r = _multipliers(gf, B_A, B_E, lay.terminal, s)
        mult = np.concatenate([lam, nu])
        compl = float(np.max(nu * s, initial=0.0))
    else:  # no inequality near its bound: the equality multipliers alone, by least squares
        r = gf.copy()
        lam = np.linalg.lstsq(B_E, -gf[lay.terminal:], rcond=None)[0]
        r[lay.terminal:] += B_E @ lam
        mult, compl = lam, 0.0
    s_d = max(S_MAX, float(np.mean(np.abs(mult)))) / S_MAX if mult.size else 1.0
    return r, mult, compl, s_d


def _trace_check(setup: Setup, sol: Solution, holder: _Function, out: list, M: np.ndarray,
                 q: np.ndarray, trace: float) -> tuple[float, float]:
    """The trace by the NumPy EKF, and its relative difference from the planner's report and
    this Function's: (trace, error)."""
    T = setup.ocp.horizon
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
    return trace_np, trace_error


def _multipliers(g: np.ndarray, B_A: np.ndarray, B_E: np.ndarray, start: int,
                 slack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lam, nu >= 0, residual g + B_E lam + B_A nu) minimising the KKT residual of a perturbed
    (barrier-like) point, |g + B_E lam + B_A nu|^2 + |slack * nu|^2: stationarity and
    complementarity together, so that the candidate rows (`slack` >= 0 from their bound) that
    carry a multiplier are those whose multiplier x slack stays small (IPOPT's complementarity),
    the active set chosen by complementarity. `B_E` (the last node's free joints x 7, the
    equality rows) acts on the free joints from `start` on: nu by non-negative least squares on
    what its span leaves (projected out), over the free joints a row touches (the others'
    residual is g's whatever nu) with the rows `slack * nu` below, then lam by least squares: the
    minimum over (lam, nu) together, whose residual is unique."""
    U, sv, _ = np.linalg.svd(B_E, full_matrices=False)
    U = U[:, sv > (sv[0] if sv.size else 0.0) * max(B_E.shape) * np.finfo(float).eps]

    def project(X):
        X = X.copy()
        X[start:] -= U @ (U.T @ X[start:])
        return X

    A, y = project(B_A), -project(g)
    touched = np.flatnonzero(np.any(A != 0, axis=1))
    m = B_A.shape[1]
    try:
        nu = nnls(np.vstack([A[touched], np.diag(slack)]),
                  np.concatenate([y[touched], np.zeros(m)]), maxiter=50 * m)[0]
    except RuntimeError:  # (not converged: the bounded least squares over both at once)
        k = B_E.shape[1]
        lb = np.concatenate([np.full(k, -np.inf), np.zeros(m)])
        full = np.hstack([np.vstack([np.zeros((start, k)), B_E]), B_A])
        weighted = np.vstack([full, np.hstack([np.zeros((m, k)), np.diag(slack)])])
        x = lsq_linear(weighted, np.concatenate([-g, np.zeros(m)]), bounds=(lb, np.inf),
                       method="bvls", tol=1e-14).x
        lam, nu = x[:k], x[k:]
        return lam, nu, g + full @ x
    r = g + B_A @ nu
    lam = np.linalg.lstsq(B_E, -r[start:], rcond=None)[0]
    r[start:] += B_E @ lam
    return lam, nu, r


def prepare_replans(setup: Setup) -> None:
    """Build now what certifying a re-plan over `setup`'s horizon from a moving start uses: the
    padded Function of its horizon's bucket, its limit rows' structure and their tool rates' map,
    the Functions compiled (or loaded from the compile cache) where the problem's codegen allows.
    The Planner calls it for every horizon it may re-plan over, so that no build or compile (about
    1 s) falls inside a re-planning loop (its time is the Planner's build time)."""
    built = [0.0]
    if setup.ocp.horizon <= 0:
        return
    codegen = setup.ocp.solver.codegen
    _function(setup, built, padded=True).settle(codegen, built)
    _layout(setup, built)
    if setup.ocp.limits.enforce:
        zero = [0.0] * setup.robot.nq
        _rows(setup, StartState(zero, zero)).rate.settle(codegen, built)


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
    sol = sol.replaced(backend_status=sol.status, backend_success=sol.success,
                       certificate=certify(setup, sol))
    if gate and claims_optimum(sol.method) and sol.success and (
            sol.certificate is None or not sol.certificate.certified):
        sol = sol.replaced(success=False, status=NOT_CERTIFIED)
    return sol


NOT_CERTIFIED = Status.NOT_CERTIFIED
