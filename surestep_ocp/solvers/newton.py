"""A projected Newton solver for the condensed OCP with the surrogate Hessian
(`solver.name: newton`).

With the condensed form of a scalar model the belief means are functions of the joints,
`mu_t = pose(q_t)`; `q_0` is fixed, and the terminal equality `mu_T = x^G` with exactly six
joints moving the tracked frame fixes `q_T` to the goal's IK solution, locally
(`solver_config.resolve`, `newton_fits`; IPOPT's solutions keep it: docs/hessian_and_newton.md,
"The solvers"). What is left is a box-constrained problem in the interior joints `q_1 .. q_T-1`:

    min f(q) = S(c(pose(q))) / S_ref + smoothness * sum |q_t+1 - q_t|^2,   q_lo <= q <= q_hi

solved by a projected Newton method (Bertsekas 1982): the Hessian is the surrogate's (the
exact Hessian of `sum_k dS/dc_k c_k(pose(q))` with the weights frozen, the same majorant as
`solver.hessian: surrogate`, here with the kinematics' curvature by the chain rule; block
tridiagonal in the nodes), on the free joints (a joint at a bound with the gradient pushing
out is held); a Cholesky factorisation with a diagonal shift when it is not positive
definite; an Armijo backtracking search along the projected path. Converged when the
projected gradient is below `solver.tol` (inf-norm; the objective is 1 at the start).

The surrogate freezes the recursion's weights, so it lacks S's own curvature and the iteration
converges linearly near the optimum. The end-game adds it back: exactly for the scalar recursion
at small sizes (`EXACT_MAX_N`, a dense step), otherwise by a limited-memory symmetric rank-one
correction learnt from the steps taken (`_SecantCorrection`, banded solves plus a small dense one).

The minimum-depth bound is not in this formulation: it is checked in the end phase and at the
end, and a violation is a failure, after which `solve_ocp_warm` runs `run_barrier`: Newton on
IPOPT's barrier problem (the bounds and the depth bound as log-barriers, IPOPT's monotone update of
the barrier parameter), which follows the central path of the IPOPT fallback it replaces in joint
space. Every evaluation is one call of a stage-wise Function (compiled with `solver.codegen`)
through CasADi's buffer interface (no conversions), so an iteration costs less than IPOPT's own
work per iteration (docs/solve_speed.md).

Here the solver and its projected Newton run; apart: the secant correction (newton_secant.py),
the barrier run (newton_barrier.py) and what the runs share (newton_run.py: parameters, scale,
line search, `NewtonRun`).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import scipy.linalg
from scipy.linalg.lapack import dpbtrf, dpbtrs

from ..model.belief import NV, BeliefModel, vech
from ..model.lie import np_poses
from ..model.joint_noise import joint_noise_curvature, joint_noise_expr
from ..model.robot import CAMERA_PARAMETERS, Robot
from ..output.solution import Solution
from ..ocp.plan_evaluation import evaluate
from ..output.solution_records import SolveRecord
from ..problem.setup import Setup
from ..buffered import Buffered
from ..ocp.codegen import SX_OPTIONS, Deferred, compiled_or_interpreted
from ..ocp.surrogate import interval_terms, pose_function, recursion_weights
# (BOUND_PUSH, TAU_MIN: re-exported for interior/)
from .newton_barrier import BOUND_PUSH, TAU_MIN, BarrierRun  # noqa: F401
from .newton_run import NewtonRun, _backtrack, _scale, parameters
from .newton_secant import _SecantCorrection
from ..status import Status

# projected gradient (objective 1 at the start) below which Newton tries the exact Hessian
EXACT_BELOW = 1e-3
# The exact Hessian is dense (S couples every interval): its cost grows as n^3 and its curvature's
# as T^2, so above this many joint variables (T of about 27 for the PSM) Newton keeps the banded
# surrogate, linear in T: at T = 40 two dense steps cost more than the surrogate iterations they
# save (docs/hessian_and_newton.md).
EXACT_MAX_N = 200
# Newton stops as "Stalled" when the objective fell by less than STALL_DECREASE (relative) over
# STALL_WINDOW iterations, so a warm re-plan that no longer progresses hands over to the fallback
# rather than running its iteration cap (docs/hessian_and_newton.md)
STALL_WINDOW, STALL_DECREASE = 10, 1e-10
# In its end phase (projected gradient below this) Newton stops as soon as an iterate is below the
# depth bound, which its formulation does not carry, and a solver that has it takes over
# (`run_barrier`, then IPOPT): most such runs converged below it anyway, and where one came back
# above it IPOPT's plan was lower (docs/solve_speed.md, "Worst case")
DEPTH_CHECK_BELOW = 1e-3


class NewtonSolver(BarrierRun):
    """The joint-space problem of one structure (robot, model, horizon, smoothness), built once; its
    runs: `run` (projected Newton) and `run_barrier` (newton_barrier.py)."""

    def __init__(self, robot: Robot, model: BeliefModel, horizon: int, smoothness: float,
                 codegen: bool, codegen_required: bool = False, background: bool = False):
        t0 = time.perf_counter()
        self.robot, self.T, nq = robot, horizon, robot.nq
        T = horizon
        Tcb, ref, sigma0 = (ca.SX.sym("camera", CAMERA_PARAMETERS), ca.SX.sym("trace_ref"),
                            ca.SX.sym("sigma0", NV))
        pose = pose_function(robot)
        weights = recursion_weights(model, T, sigma0, ref)
        qa, qb = ca.SX.sym("qa", nq), ca.SX.sym("qb", nq)
        joint = (vech(joint_noise_expr(robot, model.noise.joint_sigma, qa, qb, Tcb))
                 if model.joint_noise else None)
        _, coefficients, (wm, wo, wj), weighted = interval_terms(model, pose(qa, Tcb),
                                                                 pose(qb, Tcb), joint)
        coef = ca.Function("coef", [qa, qb, Tcb], list(coefficients), SX_OPTIONS)
        surrogate = weighted + smoothness * ca.sumsqr(qb - qa)
        g = ca.gradient(surrogate, ca.vertcat(qa, qb))
        if joint is None:
            H = ca.hessian(surrogate, ca.vertcat(qa, qb))[0]
        else:
            # the joint-space term's curvature with J held at qa (exact in qb; no third derivatives
            # of the FK)
            means_only = ca.substitute(surrogate, wj, ca.DM.zeros(wj.shape[0]))
            H = ca.hessian(means_only, ca.vertcat(qa, qb))[0] + joint_noise_curvature(
                robot, model.noise.joint_sigma, qa, Tcb, wj)
        interval = ca.Function("interval", [qa, qb, wm, wo, wj, Tcb],
                               [ca.densify(g), ca.densify(H)], SX_OPTIONS)
        # camera, trace_ref, sigma0
        Q, P = ca.MX.sym("Q", nq, T + 1), ca.MX.sym("P", CAMERA_PARAMETERS + 1 + NV)
        Tc, r, s0 = P[:CAMERA_PARAMETERS], P[CAMERA_PARAMETERS], P[CAMERA_PARAMETERS + 1:]
        S_x, w_m, w_o, w_j = weights(*coef.map(T)(Q[:, :T], Q[:, 1:], Tc), s0, r)
        G, HB = interval.map(T)(Q[:, :T], Q[:, 1:], w_m, w_o, w_j, Tc)
        smooth = smoothness * ca.sumsqr(Q[:, 1:] - Q[:, :T])
        # S's own curvature in the coefficients (dense, 5T x 5T, negative semidefinite) and the
        # coefficients' Jacobians per interval: the exact Hessian is the surrogate's plus C^T
        # (d2S/dc2) C (the end-game)
        # each node's depth, alone (the means' smallest: the end phase's check; the rows at a trial
        # point) and with its gradient and Hessian in the node's joints (the barrier of
        # `run_barrier`): the same expression of z, so the same values
        z = pose(qa, Tcb)[2]
        Z_only = ca.Function("node_z", [qa, Tcb], [z], SX_OPTIONS).map(T + 1)(Q, Tc)
        depth = ca.mmin(Z_only)
        node_depth = ca.Function("node_depth", [qa, Tcb], [z, ca.densify(ca.gradient(z, qa)),
                                                         ca.densify(ca.vec(ca.hessian(z, qa)[0]))],
                                 SX_OPTIONS)
        Z, DZ, D2Z = node_depth.map(T + 1)(Q, Tc)
        fns = {"newton_step": ca.Function("newton_step", [Q, P], [S_x, S_x + smooth, G, HB, depth]),
               "newton_f": ca.Function("newton_f", [Q, P], [S_x + smooth]),
               "newton_depth": ca.Function("newton_depth", [Q, P], [Z, DZ, D2Z]),
               "newton_fz": ca.Function("newton_fz", [Q, P], [S_x + smooth, Z_only,
                                                               ca.densify(S_x)])}
        self.nm, self.no = w_m.shape[0], w_o.shape[0]
        # S's curvature costs nc T Hessian-vector products: cheap for the scalar recursion, not for
        # the 6x6 one, where Newton keeps the surrogate throughout (docs/hessian_and_newton.md, "The
        # solvers")
        if model.scalar and nq * (T + 1) <= EXACT_MAX_N:
            fns["newton_curv"] = self._curvature(weights, coef, coefficients, qa, qb, Tcb, Q, P,
                                                 w_m, w_o)
        self.codegen, self.codegen_note, self._pending = codegen, None, None
        # compiled in the background; the Functions are loaded on first use (`ready`)
        if codegen and background:
            self._pending = Deferred(fns, codegen_required)
        else:
            if codegen:
                fns, self.codegen_note = compiled_or_interpreted(fns, codegen_required)
                self.codegen = self.codegen_note is None
            self._install(fns)
        self._index_maps(T, nq)
        self.build_time_s = time.perf_counter() - t0

    def _index_maps(self, T: int, nq: int) -> None:
        """The index maps that scatter the compiled functions' interval blocks into the gradient,
        the banded and the dense Hessian, and the coefficient Jacobians."""
        # scatter maps: interval t covers the joint vectors of nodes t, t+1 (positions t*nq ..
        # (t+2)*nq)
        n = self.n = nq * (T + 1)
        rows = [np.arange(t * nq, (t + 2) * nq) for t in range(T)]
        self.g_index = np.concatenate(rows)
        # the Hessian in LAPACK's lower band storage, ab[r - c, c] = H[r, c] (r >= c),
        # half-bandwidth 2 nq - 1: block entries above the diagonal are dropped (symmetric), the
        # others summed into their band slot
        hr = np.concatenate([np.tile(r, 2 * nq) for r in rows])
        hc = np.concatenate([np.repeat(r, 2 * nq) for r in rows])
        self.band = 2 * nq
        self.h_lower = hr >= hc
        self.h_index = ((hr - hc) * n + hc)[self.h_lower]
        # band slot (k, c) couples columns c and c + k (past the end: a padding slot, index n)
        self.band_partner = np.minimum(np.arange(n)[None, :] + np.arange(self.band)[:, None], n)
        self.h_full = hr * n + hc  # the same entries in a dense n x n matrix (both triangles)
        # one node's block (a >= b) in the band: the depth barrier's curvature
        a, b = np.tril_indices(nq)
        self.node_pairs = (a, b)
        self.node_band = np.concatenate([(a - b) * n + t * nq + b for t in range(T + 1)])
        self.h_rows, self.h_cols = hr, hc
        # the coefficient Jacobians (nc x 2nq per interval, column-major) into C (nc T x n):
        # coefficient k of interval t is row k + nm t (motion) or nm T + (k - nm) + no t
        # (observation), as d2S/dc2 orders them
        nm, no = self.nm, self.no
        c_row = [[k + nm * t if k < nm else nm * T + (k - nm) + no * t for k in range(nm + no)]
                 for t in range(T)]
        self.nc = (nm + no) * T
        self.c_index = np.array([c_row[t][k] * n + rows[t][j] for t in range(T)
                                 for j in range(2 * nq)
                                 for k in range(nm + no)])

    def _install(self, fns: dict) -> None:
        self.step, self.f = Buffered(fns["newton_step"]), Buffered(fns["newton_f"])
        self.depth, self.fz = Buffered(fns["newton_depth"]), Buffered(fns["newton_fz"])
        self.curv = Buffered(fns["newton_curv"]) if "newton_curv" in fns else None

    def ready(self) -> float:
        """Wait for a background compile and load its Functions (seconds waited; 0 when there was
        none)."""
        if self.__dict__.get("_pending") is None:
            return 0.0
        t0 = time.perf_counter()
        fns, self.codegen_note = self._pending.result()
        self.codegen, self._pending = self.codegen_note is None, None
        self._install(fns)
        return time.perf_counter() - t0

    def __getattr__(self, name: str):
        """The compiled Functions of a background compile, loaded when first used."""
        if (name in ("step", "f", "depth", "fz", "curv")
            and self.__dict__.get("_pending") is not None):
            self.ready()
            return getattr(self, name)
        raise AttributeError(f"'{type(self).__name__}' object has no attribute '{name}'")

    def _curvature(self, weights, coef, coefficients, qa, qb, Tcb, Q, P, w_m, w_o) -> ca.Function:
        """`(Q, P) -> (d2S/dc2, coefficient Jacobians per interval)`: the exact Hessian is the
        surrogate's plus C^T (d2S/dc2) C (the end-game). One Hessian-vector product of S, forward
        over the recursion's reverse sweep, mapped over the unit directions: the generated code
        holds one sweep (a symbolic dense Hessian did not compile in minutes)."""
        T, Tc, s0, r = (self.T, P[:CAMERA_PARAMETERS], P[CAMERA_PARAMETERS + 1:],
                        P[CAMERA_PARAMETERS])
        cm, co = ca.MX.sym("cm", *w_m.shape), ca.MX.sym("co", *w_o.shape)
        nc = w_m.numel() + w_o.numel()
        # scalar models only: no joint-space term
        _, dm, do, _ = weights(cm, co, ca.MX(0, T), s0, r)
        direction = ca.MX.sym("dc", nc)
        hvp = ca.Function("hvp", [cm, co, P, direction],
                          [ca.jtimes(ca.vertcat(ca.vec(dm), ca.vec(do)),
                                     ca.vertcat(ca.vec(cm), ca.vec(co)), direction)])
        CM, CO = ca.MX.sym("CM", *w_m.shape), ca.MX.sym("CO", *w_o.shape)
        curv = ca.Function("curv", [CM, CO, P], [hvp.map(nc)(CM, CO, P, ca.DM.eye(nc))])
        coef_jac = ca.Function("coef_jac", [qa, qb, Tcb],
                               [ca.densify(ca.jacobian(ca.vertcat(*coefficients[:2]),
                                                       ca.vertcat(qa, qb)))])
        return ca.Function("newton_curv", [Q, P],
                           [ca.densify(curv(*coef.map(T)(Q[:, :T], Q[:, 1:], Tc)[:2], P)),
                            coef_jac.map(T)(Q[:, :T], Q[:, 1:], Tc)])

    def solve(self, setup: Setup, init, method: str = "ocp", tol: float = 1e-6, max_iter: int = 300,
              verbose: bool = False, barrier: bool = False) -> Solution:
        """Projected Newton from `init`: converged when the projected gradient's inf-norm is at most
        `tol` (the objective is 1 at the start), at most `max_iter` iterations; `verbose` prints one
        line per iteration. With `barrier`, `run_barrier` (the depth bound kept)."""
        run = self.run_barrier if barrier else self.run
        return self.solution(setup, method, init, run(setup, init, tol, max_iter, verbose))

    def _start(self, setup: Setup, init) -> tuple:
        """(parameters, start point, lower and upper bounds, free variables, whether the start is
        within the bounds at `setup`'s start joints) of a run from `init`."""
        T, nq, robot = self.T, self.robot.nq, self.robot
        P = parameters(setup)
        x = np.array(init.q, float).ravel()  # node-major: x[t*nq + j]
        lo, hi = np.tile(robot.lower, T + 1), np.tile(robot.upper, T + 1)
        free = np.zeros((T + 1, nq), bool)
        free[1:T, robot.supporting_joints()] = True
        free = free.ravel()
        start_ok = bool(np.all(x >= lo - 1e-12) and np.all(x <= hi + 1e-12)
                        and np.allclose(x[:nq], setup.q_start, atol=1e-12))
        return P, x, lo, hi, free, start_ok

    def run(self, setup: Setup, init, tol: float = 1e-6, max_iter: int = 300, verbose: bool = False,
            exact_below: float = EXACT_BELOW, use_secant: bool = True) -> NewtonRun:
        """`solve` without the evaluation of its plan (the re-planning loop evaluates it faster,
        planner.py); exact Hessian steps (or, without them, the secant end-game unless `use_secant`
        is false: for measurements) once the projected gradient is at most `exact_below` (inf: from
        a warm start on)."""
        t0 = time.perf_counter()
        n = self.n
        P, x, lo, hi, free, start_ok = self._start(setup, init)
        # the objective is 1 (plus smoothness) at the start: its scale is the start's trace (by
        # `fz`: no derivatives)
        P[CAMERA_PARAMETERS] = trace_ref = _scale(float(self.fz(x, P)[2][0]))
        status, it, shift = (Status.MAXIMUM_ITERATIONS_EXCEEDED if start_ok
                             else Status.INFEASIBLE_START), 0, 0.0
        exact_steps, secant_steps, history = 0, 0, []
        secant, previous = None, None  # the end-game's correction; the last point and its gradient
        while start_ok and it <= max_iter:
            _, f_val, G, HB, depth = self.step(x, P)
            f_val = float(f_val[0])
            history.append(f_val)
            if (len(history) > STALL_WINDOW
                and history[-STALL_WINDOW - 1] - f_val <= STALL_DECREASE * abs(f_val)):
                # not converged, and not getting there: the caller's fallback, not the cap
                status = Status.STALLED
                break
            g = np.bincount(self.g_index, weights=G, minlength=n)
            # the secant pair of the last step, against the surrogate at the new point
            if secant is not None:
                s = x - previous[0]
                secant.update(s, g - previous[1]
                              - np.bincount(self.h_rows, weights=HB * s[self.h_cols], minlength=n))
            held = ((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0))
            idx = np.flatnonzero(free & ~held)
            if np.max(np.abs(g[idx]), initial=0.0) <= tol:
                status = Status.SOLVE_SUCCEEDED
                break
            if it == max_iter:
                break
            pg = np.max(np.abs(g[idx]), initial=0.0)
            if pg <= DEPTH_CHECK_BELOW and float(depth[0]) < setup.ocp.min_depth:
                status = Status.DEPTH_BOUND_VIOLATED
                break
            d = (self._exact_step(x, P, HB, g, idx) if pg <= exact_below and self.curv is not None
                 else None)
            exact_steps += d is not None
            kind = "exact" if d is not None else "surrogate"
            if d is None:
                if use_secant and secant is None and pg <= exact_below and self.curv is None:
                    # the end-game starts: pairs from the next step on
                    secant = _SecantCorrection(n)
                step = self._surrogate_step(HB, g, idx, shift, secant)
                if step is None:
                    status = Status.SINGULAR_HESSIAN
                    break
                d, shift, corrected = step
                secant_steps += corrected
                kind = "secant" if corrected else kind
                if secant is not None and not corrected and secant.w.size:
                    # H + A was not positive definite: start the correction afresh
                    secant = _SecantCorrection(n)
            if verbose:
                print(f"newton {it:4d}  f {f_val:.10e}  |pg| {pg:.2e}  free {idx.size:4d}  {kind}",
                      flush=True)
            previous = (x, g)
            def projected(alpha, x=x, d=d, g=g, f_val=f_val):  # Armijo along the projected path
                trial = np.clip(x + alpha * d, lo, hi)
                return (trial if float(self.f(trial, P)[0][0]) <= f_val + 1e-4 * g @ (trial - x)
                        else None)

            trial = _backtrack(1.0, projected)
            if trial is None:
                status = Status.LINE_SEARCH_FAILED
                break
            x, it = trial, it + 1
        return self._end(setup, x, P, trace_ref, status, it, exact_steps, t0, secant_steps)

    def _exact_step(self, x, P, HB, g, idx) -> np.ndarray | None:
        """Newton's step with the exact Hessian (the surrogate's plus S's own curvature C^T d2S/dc2
        C) on the free variables, or None where it is not positive definite there."""
        n = self.n
        Hs, CJ = self.curv(x, P)
        C = np.zeros(self.nc * n)
        C[self.c_index] = CJ
        C = C.reshape(self.nc, n)
        H = np.bincount(self.h_full, weights=HB, minlength=n * n).reshape(n, n)
        H += C.T @ Hs.reshape(self.nc, self.nc, order="F") @ C
        try:
            factor = scipy.linalg.cho_factor(H[np.ix_(idx, idx)], check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return None
        d = np.zeros(n)
        d[idx] = scipy.linalg.cho_solve(factor, -g[idx], check_finite=False)
        return d if np.all(np.isfinite(d)) else None

    def _surrogate_step(self, HB, g, idx, shift, secant: _SecantCorrection | None = None,
                        band_extra=None):
        """The step with the surrogate Hessian (banded; plus `band_extra` in the same band storage,
        the barrier's), shifted until positive definite, and with the secant correction where it has
        one and stays positive definite: (d, shift, corrected) or None.

        LAPACK's banded Cholesky (dpbtrf / dpbtrs) is called directly: scipy's solveh_banded wrapper
        cost more than the factorisation at these sizes."""
        n = self.n
        ab = np.bincount(self.h_index, weights=HB[self.h_lower],
                         minlength=self.band * n).reshape(self.band, n)
        if band_extra is not None:
            ab += band_extra
        fixed = np.ones(n + 1, bool)
        fixed[idx] = False
        # rows and columns of the held variables out,
        ab[fixed[:n][None, :] | fixed[self.band_partner]] = 0.0
        fixed = fixed[:n]
        ab[0, fixed] = 1.0  # identity in
        rhs = np.where(fixed, 0.0, -g)
        shift = shift / 4 if shift > 1e-14 else 0.0
        free_diag = ab[0, ~fixed]
        scale = max(float(np.max(np.abs(free_diag))) if free_diag.size else 0.0, 1e-12)
        # a diagonal shift until positive definite (IPOPT's inertia correction)
        while shift <= 1e12 * scale:
            shifted = ab.copy()
            shifted[0, ~fixed] += shift
            factor, info = dpbtrf(shifted, lower=1, overwrite_ab=1)
            if info == 0:
                d = dpbtrs(factor, rhs[:, None], lower=1)[0][:, 0]
                if np.all(np.isfinite(d)):
                    corrected = secant.step(factor, fixed, d) if secant is not None else None
                    return (d, shift, False) if corrected is None else (corrected, shift, True)
            shift = max(1e-8 * scale, 10 * shift)  # not positive definite (or not finite)
        return None

    def _end(self, setup, x, P, trace_ref, status, it, exact_steps, t0,
             secant_steps=0) -> NewtonRun:
        """The run's result at `x` (its trace and objective by `fz`: no derivatives)."""
        T, nq = self.T, self.robot.nq
        q = x.reshape(T + 1, nq)
        mu = setup.means_of(q)  # means (p, Q), evaluated in place
        terminal = float(np.max(np.abs(mu[T] - setup.m_goal)))
        depth = float(max(0.0, setup.ocp.min_depth - mu[:, 2].min()))
        if status == Status.SOLVE_SUCCEEDED and (depth > 0 or terminal > 1e-9):
            status = Status.DEPTH_BOUND_VIOLATED if depth > 0 else Status.TERMINAL_POSE_NOT_MET
        solve_s = time.perf_counter() - t0
        f_y, _, s_y = self.fz(x, P)
        trace, f_val = float(s_y[0]), float(f_y[0])
        return NewtonRun(q, np_poses(mu), status, it, exact_steps, f_val * trace_ref,
                         trace * trace_ref, trace_ref, max(terminal, depth), solve_s, secant_steps)

    def solution(self, setup, method, init, r: NewtonRun, sigma: np.ndarray | None = None
                 ) -> Solution:
        """The Solution of a run: its plan evaluated by the exact EKF
        (`output.solution.evaluate`; `sigma`: its covariances when the caller has them)."""
        return evaluate(
            setup, method, r.poses, list(r.q), sigma=sigma,
            success=r.success, status=r.status, solve_time_s=r.solve_time_s,
            iterations=r.iterations, objective=r.objective,
            run=SolveRecord(solver="newton", init=init.source, covariance_form="condensed",
                            build_time_s=self.build_time_s, compiled=self.codegen,
                            codegen_note=self.codegen_note or None,
                            initial_trace=r.initial_trace, ocp_trace_final=r.trace,
                            constraint_violation=r.violation),
            # its end-game's exact-Hessian and secant-corrected steps
            extras={"exact_steps": r.exact_steps, "secant_steps": r.secant_steps},
        )
