"""A primal-dual interior-point Newton method for the OCP within the motion limits, built for its
stage structure.

The problem is `newton.py`'s joint-space one (the condensed scalar recursion with the surrogate
Hessian, q_0 and q_T fixed, the interior joints free) plus the rows the IPOPT transcription carries
with `limits.enforce: true`, all local in time: the joint bounds (the RCM distance as the
insertion's lower bound), the means' minimum depth, the played curve's velocity and acceleration
control points (linear in a window of four waypoints of one joint, `model/limits/curve.py`) and the
tool's speeds at points of each step (nonlinear in a window of four waypoints).

Each iteration solves the primal-dual Newton system reduced to the joints, `(H + sum_i (z_i / c_i)
grad c_i grad c_i^T + sum_i z_i Hess(-c_i)) dx = -grad f + sum_i (mu / c_i) grad c_i`, whose matrix
is banded (half-bandwidth four waypoints): a banded Cholesky, linear in T. Barrier parameter:
Mehrotra's probe, re-centred after a short step; direction: with Mehrotra's corrector (the affine
step's second-order complementarity term); steps: fraction to the boundary for the rows (with
second-order corrections for the curved ones) and the multipliers, Armijo on the barrier function
against the decrease the model predicts (the barrier exact on the linearised rows).
It needs a start strictly within every row (the backend tries the straight line at several time
laws, `backends/interior_point.py`). A re-plan may start in motion: the curve's first knot then has
the executed curve's velocity and acceleration (`curve.knot_derivatives(moving=True)`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpbtrf, dpbtrs
from scipy.sparse import _sparsetools

from ..model import limits as lm
from ..model.limits import MotionLimits
from ..model.robot import CAMERA_PARAMETERS, Robot
from ..buffered import Buffered
from .codegen import SX_OPTIONS, compiled_or_interpreted
from .newton import (BOUND_PUSH, TAU_MIN, NewtonRun, NewtonSolver, _backtrack, _SecantCorrection,
                     parameters)

MU_INIT = 0.1  # IPOPT's mu_init (the objective is 1 at the start)
# The last barrier parameter (IPOPT's mu_min): the barrier's optimum is above the problem's by up to
# (rows) x mu, and the problem has thousands of rows (docs/realtime.md)
MU_FINAL = 1e-11
# Converged at the acceptable level when the objective changed by at most this (relative) over
# ACCEPTABLE_ITER iterations with the complementarity at MU_FINAL: the surrogate Hessian converges
# linearly near the optimum (IPOPT's acceptable_obj_change_tol on the enforced NLP,
# nlp_cache.ENFORCED_OPTIONS)
ACCEPTABLE_CHANGE, ACCEPTABLE_ITER = 1e-9, 3
# `feasible_ok`: a run that reaches max_iter with every row kept (not relaxed) ends with this
# status, a success: its plan keeps every limit and reaches the goal, not yet optimal (a re-planning
# loop's iteration budget)
FEASIBLE = "Feasible_Point_Found"
# with `feasible_ok`, the steps that shrink a relaxation do not count against max_iter, up to this
# many
RELAXED_MAX = 30
# the secant end-game (newton.py's SR1 correction of the surrogate Hessian, the tool rows' exact
# curvature) starts once the average complementarity is this small and no row is relaxed (tuned on
# benchmarks/realtime.py's 101 problems: docs/realtime.md)
SECANT_GAP = 3e-8
# each correction must bring the rows nearer the boundary fraction by this factor (IPOPT's
# kappa_soc), else the step is shortened
KAPPA_SOC = 0.99
MAX_SOC = 4  # second-order corrections per iteration (IPOPT's max_soc), over all its step lengths
# `relax`: a start's rows below this (of their limit) get it as slack, the relaxation then shrinks
RELAX_TO = 1e-2
# relaxed rows: STUCK_ITER steps in a row shorter than STUCK_STEP end the run as (locally)
# infeasible
STUCK_STEP, STUCK_ITER = 1e-3, 3
# a step cut below this fraction: the next barrier parameter re-centres (no Mehrotra decrease)
SHORT_STEP = 0.2
# while the dual error is above the tolerance, the barrier parameter falls no lower than this times
# it, nor than its last value: a complementarity far below the dual error leaves rows with tiny
# slacks and multipliers that the Newton direction ignores and then runs into, 1 % of a step at a
# time (tuned on benchmarks/realtime.py's 101 problems). In a re-plan's few iterations
# (`feasible_ok`) only while rows are relaxed: after that it kept the plans off the optimum and cost
# the closed loop grasps; while relaxed, without it, the slacks fell to ~1e-10 and the relaxation
# (which only a full step removes) then shrank by about half a step for 17 steps (docs/realtime.md).
# Once no row is relaxed the floor is lower (MU_PER_DUAL): fewer iterations, on held-out problems
# too (docs/realtime.md, "The barrier parameter's floor")
MU_PER_DUAL_RELAXED = 1e-5
MU_PER_DUAL = 3e-6
WINDOW = 4  # waypoints each curve piece depends on (t-1 .. t+2)


@dataclass
class InteriorRun(NewtonRun):
    """Where an interior-point run ended, with its constraint multipliers (a warm start for the next
    run)."""

    multipliers: np.ndarray | None = None
    relaxed_iterations: int = 0  # iterations with relaxed rows (a start outside them, `relax`)

    @property
    def success(self) -> bool:
        return self.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level", FEASIBLE)


class InteriorNewton:
    """The limit rows of one structure (robot, horizon, step time, limits, start at rest or in
    motion) around a projected Newton solver of the same structure, built once; `run` solves from a
    strictly feasible start."""

    def __init__(self, newton: NewtonSolver, robot: Robot, step_s: float, limits: MotionLimits,
                 moving: bool, codegen: bool, codegen_required: bool = False):
        t0 = time.perf_counter()
        self.newton, self.robot, self.dt, self.limits, self.moving = (newton, robot, step_s, limits,
                                                                       moving)
        T, nq = newton.T, robot.nq
        self.T, self.nq, self.n = T, nq, newton.n
        mov = robot.supporting_joints()
        self.mov = mov
        # linear rows on the extended vector of one joint (waypoints, then v_0, a_0 when moving), as
        # transcription.py
        dt, lim = step_s, limits
        R, joints = lm.curve_limit_rows(T, dt, lim, mov, moving)
        # the joint bounds on the curve between the waypoints (the insertion's lower one from the
        # RCM distance, as `bounds`): centred rows, a constant each, no reserve
        self.joint_lower, self.joint_upper = lm.joint_bounds(robot, lim.rcm_min_distance)
        Rp, jp, off = lm.curve_position_rows(T, dt, self.joint_lower, self.joint_upper, mov,
                                             moving)
        R, joints = np.vstack([R, Rp]), np.concatenate([joints, jp])
        off = np.concatenate([np.zeros(len(R) - len(Rp)), off])
        position = np.arange(len(R)) >= len(R) - len(Rp)
        # per row: coefficients on the waypoints, the (v0, a0) part
        W = R[:, :T + 1].copy()
        E = R[:, T + 1:].copy() if moving else np.zeros((len(R), 2))
        big = np.abs(np.hstack([W, E])).max(axis=1, keepdims=True)
        W[np.abs(W) < 1e-12 * big] = 0.0
        E[np.abs(E) < 1e-12 * big] = 0.0
        # rows that are 0 by construction (velocities at rest) or constant
        keep = np.any(W != 0, axis=1)
        self.lin_w, self.lin_ext, self.lin_joint = W[keep], E[keep], np.array(joints)[keep]
        self.lin_off, self.lin_position = off[keep], position[keep]
        # per row: its (<= WINDOW) nonzero waypoints as variable indices and their coefficients
        nz = [np.flatnonzero(w) for w in self.lin_w]
        width = max(len(z) for z in nz)
        self.lin_idx = np.zeros((len(nz), width), int)
        self.lin_coef = np.zeros((len(nz), width))
        for i, z in enumerate(nz):
            self.lin_idx[i, :len(z)] = z * nq + self.lin_joint[i]
            self.lin_coef[i, :len(z)] = self.lin_w[i, z]
        self.n_lin = len(nz)
        # the tool's speeds at TOOL_POINTS of each piece, each a function of its window of waypoints
        # (plus the start derivatives' part when moving)
        qa, qd = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
        Ta = robot.fk_expr(qa, robot.frame)
        pv, Rd = ca.jtimes(Ta[:3, 3], qa, qd), ca.jtimes(ca.vec(Ta[:3, :3]), qa, qd)
        k = 1 - lm.TOOL_MARGIN
        # the tool's squared speeds at a point of the curve, (q(s), q'(s)), over their limits
        # over tool_scale's squared limits in `constraints`
        out = ca.vertcat(ca.sumsqr(pv), 0.5 * ca.sumsqr(Rd))
        # (numbers, not in the compiled code: structures that differ in their limits share their
        # libraries)
        self.tool_scale = np.array([1 / (k * lim.tool_speed) ** 2,
                                    1 / (k * lim.tool_rotation) ** 2])
        self.tool_k = out.shape[0]
        lam, y = ca.SX.sym("lam", self.tool_k), ca.vertcat(qa, qd)
        windows, weights, consts = lm.tool_point_windows(T, dt, moving)
        self.n_pts = len(windows)
        self.tool_nodes = np.array(windows)
        self.tool_weights = weights.T  # (2 WINDOW, points)
        self.tool_consts = consts  # (points, 4): position (v0, a0) weights, then velocity's
        npts, n = self.n_pts, self.n
        # the linear rows as a sparse matrix
        self.lin_map = sp.csr_matrix((self.lin_coef.ravel(),
                                      (np.repeat(np.arange(self.n_lin), width),
                                       self.lin_idx.ravel())), shape=(self.n_lin, n))
        self.lin_map.eliminate_zeros()
        # variable indices of each point's window (node-major)
        self.tool_var = (self.tool_nodes[:, :, None] * nq
                         + np.arange(nq)[None, None, :]).reshape(npts, -1)
        # (points, 2, W): each point's weights of its window's nodes in q(s), then in q'(s)
        self.point_cw = self.tool_weights.T.reshape(npts, 2, WINDOW)
        # each point's (q(s), q'(s)) from the joints, point-major (in the compiled functions)
        pr = np.arange(npts * nq).reshape(npts, 1, nq).repeat(WINDOW, 1)
        pc = self.tool_var.reshape(npts, WINDOW, nq)
        point_map = sp.coo_matrix(
            (np.concatenate([(self.point_cw[:, 0, :, None] * np.ones(nq)).ravel(),
                             (self.point_cw[:, 1, :, None] * np.ones(nq)).ravel()]),
             (np.concatenate([pr.ravel(), pr.ravel() + npts * nq]),
              np.concatenate([pc.ravel(), pc.ravel()]))), shape=(2 * npts * nq, n)).tocsc()
        point_map.eliminate_zeros()
        point_map.sort_indices()
        Mq = ca.DM(ca.Sparsity(2 * npts * nq, n, point_map.indptr.tolist(),
                               point_map.indices.tolist()), point_map.data)
        # inputs: the joints, the points' offsets from the start's derivatives (2 nq, points)
        Xm, Om, Lm = (ca.MX.sym("x", n), ca.MX.sym("off", 2 * nq, npts),
                      ca.MX.sym("L", self.tool_k, npts))
        Y = ca.mtimes(Mq, Xm)
        Qm = ca.reshape(Y[:npts * nq], nq, npts) + Om[:nq, :]
        Dm = ca.reshape(Y[npts * nq:], nq, npts) + Om[nq:, :]
        f_val = ca.Function("tool", [qa, qd], [out], SX_OPTIONS)
        # the velocities (pv, vec(R)') with their Jacobian in (q, q') for the Gauss-Newton
        # curvature; the end-game adds the rest of the exact curvature, the Hessian of c . (pv,
        # vec(R)') with c = (2 lam_0 pv, lam_1 vec(R)') held (their operation counts:
        # docs/realtime.md, "The method")
        vel = ca.vertcat(pv, Rd)
        jac_vel = ca.densify(ca.jacobian(vel, y))
        # and the rows' own gradients (unscaled, (k, 2 nq)) from the same Jacobian's expressions
        grad = ca.vertcat(2 * pv.T @ jac_vel[:3, :], Rd.T @ jac_vel[3:, :])
        f_jac = ca.Function("tool_jac", [qa, qd], [jac_vel, grad], SX_OPTIONS)
        c_vel = ca.SX.sym("c", vel.shape[0])
        h_res = ca.substitute(ca.jacobian(jac_vel.T @ c_vel, y), c_vel,
                              ca.vertcat(2 * lam[0] * pv, lam[1] * Rd))
        f_res = ca.Function("tool_res", [qa, qd, lam], [jac_vel, grad, ca.densify(h_res)],
                            SX_OPTIONS)
        L = self.lin_map.tocsc()
        L.sort_indices()
        lin_dm = ca.DM(ca.Sparsity(L.shape[0], n, L.indptr.tolist(), L.indices.tolist()), L.data)
        # the tool rows and the linear rows (without their constant part)
        fns = {"tool_rows": ca.Function("tool_rows", [Xm, Om], [f_val.map(npts)(Qm, Dm),
                                                                 ca.mtimes(lin_dm, Xm)]),
               "tool_jacs": ca.Function("tool_jacs", [Xm, Om], f_jac.map(npts)(Qm, Dm)),
               "tool_res": ca.Function("tool_res", [Xm, Om, Lm], f_res.map(npts)(Qm, Dm, Lm))}
        self.codegen_note = None
        if codegen:
            fns, self.codegen_note = compiled_or_interpreted(fns, codegen_required,
                                                             fast=("tool_rows", "tool_jacs"),
                                                             vectorised=("tool_res",))
        self.tool_rows, self.tool_jacs = Buffered(fns["tool_rows"]), Buffered(fns["tool_jacs"])
        self.tool_res = Buffered(fns["tool_res"])
        # the band layout (lower storage, half-bandwidth WINDOW nodes)
        self.bw = WINDOW * nq
        r, cc = np.meshgrid(np.arange(WINDOW * nq), np.arange(WINDOW * nq), indexing="ij")
        # the points of one piece share its window: their blocks are summed per window, then
        # scattered
        windows_u, self.point_window = np.unique(self.tool_nodes, axis=0, return_inverse=True)
        self.point_window = self.point_window.ravel()
        slot = np.zeros(npts, int)
        for p in range(1, npts):
            slot[p] = slot[p - 1] + 1 if self.point_window[p] == self.point_window[p - 1] else 0
        self.point_slot, self.n_windows, self.window_points = (slot, len(windows_u),
                                                               int(slot.max()) + 1)
        # (points, 2 nq, W nq): each point's (q(s), q'(s)) from its window's waypoints
        cw, eye = self.point_cw, np.eye(nq)
        self.tool_map = np.concatenate([np.concatenate([cw[:, a, m, None, None] * eye
                                                        for m in range(WINDOW)], axis=2)
                                        for a in range(2)], axis=1)
        # (windows, W W, points x (a, b)): C_pa[m] C_pb[n] of each window's points (zero-padded)
        self.point_flat = self.point_window * self.window_points + slot
        U = np.zeros((self.n_windows * self.window_points, 4, WINDOW * WINDOW))
        U[self.point_flat] = np.einsum("pam,pbn->pabmn", cw, cw).reshape(npts, 4, -1)
        self.window_weights = (U.reshape(self.n_windows, -1, WINDOW * WINDOW)
                               .transpose(0, 2, 1).copy())
        if np.any(np.diff(self.point_window) < 0):
            raise ValueError("tool points are not ordered by window")
        wvar = (windows_u[:, :, None] * nq
                + np.arange(nq)[None, None, :]).reshape(len(windows_u), -1)
        vr, vc = wvar[:, r.ravel()], wvar[:, cc.ravel()]  # (windows, (W nq)^2)
        self.tool_low = vr >= vc
        self.tool_band = ((vr - vc) * n + vc)[self.tool_low]
        li = self.lin_idx
        lr, lc = li[:, :, None].repeat(width, 2), li[:, None, :].repeat(width, 1)
        self.lin_low = ((lr >= lc) & (self.lin_coef[:, :, None] != 0)
                        & (self.lin_coef[:, None, :] != 0))
        self.lin_band = ((lr - lc) * n + lc)[self.lin_low]
        self.lin_pair = (self.lin_coef[:, :, None] * self.lin_coef[:, None, :])[self.lin_low]
        self.lin_pair_row = np.broadcast_to(np.arange(self.n_lin)[:, None, None],
                                            lr.shape)[self.lin_low]
        hr, hc = newton.h_rows, newton.h_cols
        self.h_low = hr >= hc
        self.h_band = ((hr - hc) * n + hc)[self.h_low]
        a, b = newton.node_pairs
        self.node_band = np.concatenate([(a - b) * n + t * nq + b for t in range(T + 1)])
        self.band_partner = np.minimum(np.arange(n)[None, :] + np.arange(self.bw)[:, None], n)
        self._set_bounds()
        self._jac_pattern(self.free_idx)
        self._held = None  # (free indices, held mask, band entries outside the free block)
        # every band entry as one sparse product with (the surrogate's blocks, the linear rows'
        # weights, the nodes' depth blocks, the windows' blocks): sums over a fixed pattern
        nbw = self.bw * n
        nodes = (np.arange(T + 1)[:, None] * nq * nq + a * nq + b).ravel()
        # the windows' entries in `_window_terms`' order: each one's place in the (windows, W nq,
        # W nq) blocks
        nw_ = self.n_windows
        place = (np.arange(self.tool_low.size).reshape(nw_, WINDOW, nq, WINDOW, nq)
                 .transpose(0, 1, 3, 2, 4).ravel())
        order = np.argsort(place)  # block entry -> its position in the terms
        tool_cols = order[np.flatnonzero(self.tool_low)]
        # the windows' part alone too: the end-game adds the tool rows' exact curvature with it
        self.tool_scatter = sp.csr_matrix(
            (np.ones(len(tool_cols)), (self.tool_band, tool_cols)), shape=(nbw, self.tool_low.size))
        parts = [(self.h_band, np.flatnonzero(self.h_low), np.ones(self.h_low.sum()),
                  len(self.h_low)),
                 (self.lin_band, self.lin_pair_row, self.lin_pair, self.n_lin),
                 (self.node_band, nodes, np.ones(len(nodes)), (T + 1) * nq * nq)]
        # one matrix per part, their products summed into the band in turn: each entry's sum runs
        # in the order of one product with them side by side (without concatenating the parts)
        self.band_scatter = [sp.csr_matrix((v, (r, c_)), shape=(nbw, size))
                             for r, c_, v, size in parts] + [self.tool_scatter]
        # the entries outside the free block (a held joint's row or column) are left out: the
        # factorisation sees the held joints as identity rows (`_factor`), so the band holds
        # zeros there without clearing them at every iteration
        inside = np.ones(nbw)
        inside[self._held_entries(self.free_idx)[1]] = 0.0
        keep = sp.diags(inside, format="csr")
        self.band_scatter = [keep @ S for S in self.band_scatter]
        for S in self.band_scatter:
            S.eliminate_zeros()
            S.sort_indices()
        self.tool_scatter = self.band_scatter[-1]
        self.build_time_s = time.perf_counter() - t0

    def _jac_pattern(self, idx: np.ndarray) -> None:
        """The curved rows' Jacobian (depths of the interior nodes, then tool rows) as CSR for the
        free variables `idx`: the slots `_RowJacobian` fills at each iterate. The direct rows' (the
        bounds' +-e_i, the linear rows' +-a_i) are the constant `lin_map` and `idx` themselves."""
        T, nq = self.T, self.nq
        depth = sp.csr_matrix((np.ones((T - 1) * nq), (np.repeat(np.arange(T - 1), nq),
                                                        np.arange(nq, T * nq))),
                              shape=(T - 1, self.n))
        tool = (self.tool_var[:, None, :].repeat(self.tool_k, 1)
                .reshape(self.n_pts * self.tool_k, -1))
        indptr = np.concatenate([depth.indptr, depth.nnz + tool.shape[1] * np.arange(
            1, tool.shape[0] + 1)])
        self.jac_idx = idx
        self.jac_curved = sp.csr_matrix((np.zeros(depth.nnz + tool.size),
                                         np.concatenate([depth.indices, tool.ravel()]), indptr),
                                        shape=(len(indptr) - 1, self.n))
        self.jac_depth = slice(0, depth.nnz)
        self.jac_tool = slice(depth.nnz, self.jac_curved.nnz)

    # ---------------------------------------------------------------------------- constraint values
    def _lin_const(self, v0: np.ndarray | None, a0: np.ndarray | None) -> np.ndarray:
        """The linear rows' constant part: from the start's velocity and acceleration (none at
        rest), and the position rows' centring."""
        if not self.moving:
            return self.lin_off.copy()
        return (self.lin_ext[:, 0] * v0[self.lin_joint] + self.lin_ext[:, 1] * a0[self.lin_joint]
                + self.lin_off)

    def _tool_offsets(self, v0, a0) -> np.ndarray:
        """(2 nq, points): each tool point's position and velocity offsets from the start's
        derivatives."""
        if not self.moving:
            return np.zeros((2 * self.nq, self.n_pts))
        C = self.tool_consts
        return np.vstack([np.outer(v0, C[:, 0]) + np.outer(a0, C[:, 1]),
                          np.outer(v0, C[:, 2]) + np.outer(a0, C[:, 3])])

    def bounds(self, q_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lower, upper, free mask) of the node-major joints: the interior moving joints free
        within the joint limits (the insertion above the RCM bound), the others held: the same
        read-only arrays for every start (the first node is held at the start a run is given)."""
        return self._bounds

    def _set_bounds(self) -> None:
        """`bounds`' arrays and the free joints' indices, once (read-only: every run shares them,
        and the row Jacobian's pattern and the factor's held mask are kept while they are the
        same object)."""
        T, nq = self.T, self.nq
        lo, hi = np.tile(self.joint_lower, T + 1), np.tile(self.joint_upper, T + 1)
        free = np.zeros((T + 1, nq), bool)
        free[1:T, self.mov] = True
        self._bounds = (lo, hi, free.ravel())
        self.free_idx = np.flatnonzero(free.ravel())
        self._free_bounds = (lo[self.free_idx], hi[self.free_idx])
        # the box a start's free joints are pushed into (`_pushed`)
        self._push_box = (lo + BOUND_PUSH * np.minimum(np.maximum(1.0, np.abs(lo)), hi - lo),
                          hi - BOUND_PUSH * np.minimum(np.maximum(1.0, np.abs(hi)), hi - lo))
        for a in (*self._bounds, self.free_idx, *self._free_bounds, *self._push_box):
            a.flags.writeable = False

    def constraints(self, x, P, lin_c, offsets, min_depth, keep: float = 1.0
                    ) -> tuple[float, np.ndarray]:
        """(objective, row values c >= 0) in the rows' order: the direct ones (joint bounds lower
        and upper, linear rows lower and upper: exact under linearisation), then the nonlinear ones
        (depths of the interior nodes, tool rows), which the method gives slacks."""
        f_y, z_y, _ = self.newton.fz(x, P)
        raw, lin = self.tool_rows(x, offsets)
        lin = lin + lin_c
        # the reserve tightens the velocity and acceleration rows, not the joint bounds
        keep_lin = np.where(self.lin_position, 1.0, keep) if keep != 1.0 else 1.0
        # written in place, part by part (fewer temporaries: evaluated at every trial point)
        nb, nl, T = len(self.free_idx), self.n_lin, self.T
        c = np.empty(2 * nb + 2 * nl + T - 1 + raw.size)
        xi = x[self.free_idx]
        lo_i, hi_i = self._free_bounds
        np.subtract(xi, lo_i, out=c[:nb])
        np.subtract(hi_i, xi, out=c[nb:2 * nb])
        np.add(keep_lin, lin, out=c[2 * nb:2 * nb + nl])
        np.subtract(keep_lin, lin, out=c[2 * nb + nl:2 * nb + 2 * nl])
        np.subtract(z_y[1:T], min_depth, out=c[2 * nb + 2 * nl:2 * nb + 2 * nl + T - 1])
        # the tool rows, point-major (k per point), over their squared limits
        tool = c[2 * nb + 2 * nl + T - 1:].reshape(self.n_pts, self.tool_k)
        np.multiply(self.tool_scale / keep**2, raw.reshape(self.n_pts, self.tool_k), out=tool)
        np.subtract(1.0, tool, out=tool)
        self._fixed_slacks(c, nb)
        return float(f_y[0]), c

    def rows(self, x, P, v0, a0, min_depth) -> np.ndarray:
        """The row values (>= 0 within every limit) at `x` from a start moving at `v0`, `a0`
        (None: at rest), as `constraints` orders them."""
        return self.constraints(x, P, self._lin_const(v0, a0), self._tool_offsets(v0, a0),
                                min_depth)[1]

    def _fixed_slacks(self, c: np.ndarray, nb: int) -> None:
        """Linear rows that no free joint moves (the curve at the start: constant in a run) and
        that hold with equality, to rounding (a start joint exactly at its limit), given the
        fixed slack RELAX_TO in `c`: no step can open a slack of 0, so the relaxation shrank
        towards it forever and its multiplier overflowed (RuntimeWarnings from w / s, 1 / s)."""
        cached = getattr(self, "_constant_rows", None)
        if cached is None or cached[0] is not self.free_idx:
            moved = self.lin_map[:, self.free_idx].getnnz(axis=1)
            cached = self._constant_rows = (self.free_idx, np.flatnonzero(moved == 0))
        for rows in (2 * nb + cached[1], 2 * nb + self.n_lin + cached[1]):
            c[rows[np.abs(c[rows]) <= 1e-12]] = RELAX_TO

    def _start_point(self, x, P, lin_c, offsets, min_depth, keep, relax
                     ) -> tuple[np.ndarray, float, np.ndarray]:
        """(point, objective, rows) a run starts from: `x` with its free joints pushed off their
        bounds (IPOPT's bound_push) if that keeps every row, else `x` itself if that does, else
        (`relax`) the pushed one."""
        inside = self._pushed(x)
        f_val, c = self.constraints(inside, P, lin_c, offsets, min_depth, keep)
        if np.all(c > 0):
            return inside, f_val, c
        # the pushed start breaks a row: the start itself if that is inside
        f_in, c_in = self.constraints(x, P, lin_c, offsets, min_depth, keep)
        if np.all(c_in > 0) or not relax:
            return x, f_in, c_in
        return inside, f_val, c

    def _pushed(self, x: np.ndarray) -> np.ndarray:
        """`x` with its free joints pushed off their bounds (IPOPT's bound_push)."""
        return np.where(self._bounds[2], np.clip(x, *self._push_box), x)

    def starts_inside(self, setup, init) -> bool:
        """Whether `run` (without `relax`, at rest) can start from `init`: its start point
        strictly within every row. The linear rows are looked at first, alone (a start at a
        constant pace breaks the accelerations at its ends: no need for the rest)."""
        x = np.asarray(init.q, float).ravel()
        if not np.allclose(x[:self.nq], setup.q_start, atol=1e-12):
            return False
        lin_c = self._lin_const(None, None)
        if all(np.any(np.abs(_csr_dot(self.lin_map, z) + lin_c) >= 1.0)
               for z in (self._pushed(x), x)):
            return False  # (the rows keep_lin -+ lin > 0 with keep_lin = 1, `constraints`)
        c = self._start_point(x, parameters(setup), lin_c, self._tool_offsets(None, None),
                              setup.ocp.min_depth, 1.0, False)[2]
        return bool(np.all(np.isfinite(c)) and np.all(c > 0))

    def start_margin(self, setup, init, v0=None, a0=None) -> float:
        """The smallest row value at `init` (positive: strictly within every row)."""
        c = self.constraints(np.asarray(init.q, float).ravel(), parameters(setup),
                             self._lin_const(v0, a0), self._tool_offsets(v0, a0),
                             setup.ocp.min_depth)[1]
        return float(c.min())

    def _tool_gradients(self, A: np.ndarray, G: np.ndarray, tool_scale: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """The compiled velocities' Jacobian and the rows' gradients (flat) -> (points, 12, 2 nq)
        Jacobian and (points, k, 2 nq) scaled gradients of the tool rows' g in each point's (q(s),
        q'(s))."""
        nq, k = self.nq, self.tool_k
        A = A.reshape(-1, 2 * nq, self.n_pts, order="F").transpose(2, 0, 1)
        G = G.reshape(k, 2 * nq, self.n_pts, order="F").transpose(2, 0, 1)
        return A, G * tool_scale[None, :, None]

    @staticmethod
    def _tool_blocks(A: np.ndarray, gy: np.ndarray, wk: np.ndarray, st: np.ndarray
                     ) -> np.ndarray:
        """Each tool point's block of the reduced matrix in its (q(s), q'(s)), (points, 2 nq,
        2 nq): Gauss-Newton's curvature of wk . g (the velocities' Jacobian A weighted by 2 wk_0,
        wk_1) plus sum_k st_k gy_k gy_k^T (st: the rows' w / c)."""
        wv = np.empty(A.shape[:2])
        wv[:, :3], wv[:, 3:] = 2 * wk[0][:, None], wk[1][:, None]
        return ((A * wv[:, :, None]).transpose(0, 2, 1) @ A
                + (gy * st[:, :, None]).transpose(0, 2, 1) @ gy)

    def _band(self, HB: np.ndarray, wl: np.ndarray, blocks: np.ndarray, JW: np.ndarray
              ) -> np.ndarray:
        """The reduced matrix in LAPACK's lower band storage (bw, n) from its parts: the
        surrogate's interval blocks, the linear rows' weights, the depths' node blocks (flat) and
        the tool windows' terms (`_window_terms`), each part's sparse product added in turn."""
        ab = np.zeros(self.bw * self.n)
        for S, part in zip(self.band_scatter, (HB, wl, blocks, JW)):
            _csr_dot(S, part, ab)
        return ab.reshape(self.bw, self.n)

    def _to_window(self, Y: np.ndarray) -> np.ndarray:
        """(points, r, 2 nq) derivatives in each point's (q(s), q'(s)) -> (points, r, W nq) in
        its window's waypoints."""
        return Y @ self.tool_map

    def _window_terms(self, H: np.ndarray) -> np.ndarray:
        """(points, 2 nq, 2 nq) Hessians in each point's (q(s), q'(s)) -> the windows' blocks
        summed over each window's points, sum_p K_p^T H_p K_p with K_p = C_p kron I, i.e. sum_p,a,b
        (C_pa C_pb^T) kron H_p,ab: one product per window, flat in its (window, m, n, i, j) order
        (node m's joint i, node n's joint j), the order `tool_scatter` takes."""
        nq, nw, npts = self.nq, self.n_windows, self.n_pts
        V = np.zeros((nw * self.window_points, 4, nq * nq))
        V[self.point_flat] = (H.reshape(npts, 2, nq, 2, nq).transpose(0, 1, 3, 2, 4)
                              .reshape(npts, 4, nq * nq))
        return (self.window_weights @ V.reshape(nw, -1, nq * nq)).ravel()

    # ---------------------------------------------------------------------------------------- solve
    def run(self, setup, init, v0=None, a0=None, tol: float = 1e-6, max_iter: int = 300,
            verbose: bool = False, warm: np.ndarray | None = None, mu0: float | None = None,
            relax: bool = False, reserve: float = 0.0,
            feasible_ok: bool = False, acceptable_change: float = ACCEPTABLE_CHANGE,
            use_secant: bool = True, relaxed_max: int = RELAXED_MAX) -> InteriorRun:
        """From `init`, which must be strictly within every row (else status `Infeasible_Start`: the
        caller starts elsewhere or hands over to IPOPT), with the start's velocity and acceleration
        `v0`, `a0` when the structure starts in motion; `warm`: multipliers of a previous run of the
        same structure (with `mu0`, the barrier parameter to start from).

        Steps keep every row within the fraction to the boundary: exactly for the bounds and linear
        rows (linear in the step), and for the curved ones (depths, tool speeds) by up to MAX_SOC
        second-order corrections before the step is shortened (IPOPT's), re-solving with what the
        linearisation missed. The barrier parameter follows Mehrotra's probe (the affine step's
        complementarity, cubed), and re-centres after a step cut short; the direction adds
        Mehrotra's corrector unless it then does not descend the barrier function. Relaxed rows
        (`relax`) lose their relaxation once every row holds with the boundary fraction of its
        slack; with nothing free (one step) the start is the plan or the problem is infeasible."""
        t0 = time.perf_counter()
        nw, T, nq, n = self.newton, self.T, self.nq, self.n
        P = parameters(setup)
        x = np.array(init.q, float).ravel()
        idx = self.free_idx
        min_depth = setup.ocp.min_depth
        lin_c = self._lin_const(v0, a0)
        offsets = self._tool_offsets(v0, a0)
        # the fraction of the velocity, acceleration and tool-speed limits the plan may use
        keep = 1.0 - reserve
        tool_scale = self.tool_scale / keep**2
        # the objective's scale: the start's trace (by the rows' function: no derivatives)
        P[CAMERA_PARAMETERS] = trace_ref = float(nw.fz(x, P)[2][0])
        m = MU_INIT if mu0 is None else mu0
        m_last = m  # the last iteration's barrier parameter
        nb, nl = len(idx), self.n_lin
        nd_ = 2 * nb + 2 * nl  # the direct rows (bounds, linear) come first, then the curved ones
        x, f_val, c = self._start_point(x, P, lin_c, offsets, min_depth, keep, relax)
        # rows outside (or within RELAX_TO of) their boundary at the start are relaxed by rho, which
        # every step of length a shrinks by (1 - a): the Newton step aims at rho = 0 (an
        # infeasible-start interior point)
        rho = np.maximum(RELAX_TO - c, 0.0) if relax and not np.all(c > 0) else np.zeros(len(c))
        start_ok = bool(np.all(np.isfinite(c)) and np.all(c + rho > 0)
                        and np.allclose(x[:nq], setup.q_start, atol=1e-12))
        nc = len(c)
        s = c + rho  # the rows' slacks
        # the multipliers
        w = (np.asarray(warm, float).copy() if warm is not None and len(warm) == nc else m / s)
        if warm is not None and len(warm) == nc:
            r = m / s
            w = np.minimum(np.maximum(w, r * 1e-10), r * 1e10)
        status = "Maximum_Iterations_Exceeded" if start_ok else "Infeasible_Start"
        if start_ok and nb == 0:
            # nothing free (a one-step plan): the start is the plan, within every row or not (else
            # the relaxation shrinks towards a slack of 0, and w / s overflows)
            status = "Solve_Succeeded" if np.all(c > 0) else "Infeasible_Problem_Detected"
            start_ok = False
        it, shift, f_hist, last_step, stuck, relaxed_its = 0, 0.0, [], 1.0, 0, 0
        # the end-game's secant correction of the surrogate; the last point
        secant, previous = None, None
        last_az, last_socs = 1.0, 0
        end_game = False  # the tool rows' exact curvature from then on (else Gauss-Newton's)
        while start_ok:
            _, f_val, G, HB, _ = nw.step(x, P)
            f_val = float(f_val[0])
            Z, DZ, D2Z = nw.depth(x, P)
            DZ, D2Z = DZ.reshape(T + 1, nq), D2Z.reshape(T + 1, nq, nq)
            wt = w[nd_ + T - 1:]
            wk = wt.reshape(self.n_pts, self.tool_k).T * tool_scale[:, None]  # (k, points)
            if end_game:  # the exact curvature beyond Gauss-Newton's: Hess of w . g - GN's
                A, GT, hy = self.tool_res(x, offsets, wk)
                hy = hy.reshape(2 * nq, 2 * nq, self.n_pts, order="F").transpose(2, 0, 1)
            else:
                A, GT = self.tool_jacs(x, offsets)
            A, gy = self._tool_gradients(A, GT, tool_scale)
            # (points, k, W nq): the rows' gradients in the window
            tj = self._to_window(gy)
            g = np.bincount(nw.g_index, weights=G, minlength=n)  # grad f
            if secant is not None:
                # the last step's secant pair, against the surrogate at this point
                step_x = x - previous[0]
                secant.update(step_x, g - previous[1]
                              - np.bincount(nw.h_rows, weights=HB * step_x[nw.h_cols], minlength=n))
            jac = _RowJacobian(self, idx, DZ, tj)
            err_d = float(np.max(np.abs((g - jac.T(w))[idx]))) if nb else 0.0
            gap = float(w @ s) / nc  # the average complementarity
            f_hist.append(f_val)
            stalled = (len(f_hist) > ACCEPTABLE_ITER and abs(f_hist[-1 - ACCEPTABLE_ITER] - f_val)
                       <= acceptable_change * max(abs(f_val), 1e-12))
            if verbose:
                print(f"interior {it:4d}  f {f_val:.10e}  mu {m:.1e}  dual {err_d:.2e}  "
                      f"gap {gap:.2e}  relaxed {rho.max(initial=0):.1e}  step {last_step:.2e}  "
                      f"dual step {last_az:.2e}  corrections {last_socs}",
                      flush=True)
            if gap <= MU_FINAL and (err_d <= tol or stalled) and not rho.any():
                status = "Solve_Succeeded" if err_d <= tol else "Solved_To_Acceptable_Level"
                break
            if (it - (relaxed_its if feasible_ok else 0) == max_iter
                    or (feasible_ok and relaxed_its >= relaxed_max)):
                if feasible_ok and not rho.any() and np.all(c > 0):
                    status = FEASIBLE
                break
            # the reduced matrix in band storage: the surrogate, then sum (w / c) grad c grad c^T +
            # w Hess(-c)
            sig = w / s
            wl = sig[2 * nb:2 * nb + nl] + sig[2 * nb + nl:nd_]
            wd, zdn = np.zeros(T + 1), np.zeros(T + 1)
            wd[1:T], zdn[1:T] = sig[nd_:nd_ + T - 1], w[nd_:nd_ + T - 1]
            blocks = wd[:, None, None] * DZ[:, :, None] * DZ[:, None, :] - zdn[:, None, None] * D2Z
            # the tool rows per point in (q(s), q'(s)): sum_k (w / c) grad g grad g^T and
            # Gauss-Newton's w Hess g (the end-game adds the rest of it); then per window
            st = sig[nd_ + T - 1:].reshape(self.n_pts, self.tool_k)  # (points, k)
            JW = self._window_terms(self._tool_blocks(A, gy, wk, st))
            ab = self._band(HB, wl, blocks.ravel(), JW)
            ab[0, idx] += sig[:nb] + sig[nb:2 * nb]
            factor = None
            if end_game:
                # the tool rows' exact curvature where the matrix with it is positive definite as
                # it is, else Gauss-Newton's: shifted, the exact one gave short, gradient-like steps
                exact = ab + _csr_dot(self.tool_scatter, self._window_terms(hy)
                                      ).reshape(self.bw, n)
                factor = self._factor(exact, idx, 0.0, may_shift=False)
            if factor is None:
                factor = self._factor(ab, idx, shift)
            if factor is None:
                status = "Singular_Hessian"
                break
            solve, shift, band_factor, fixed = factor
            # the tool rows' exact curvature from the end-game on (Gauss-Newton's can stall there)
            end_game = end_game or (not rho.any() and gap <= SECANT_GAP)
            if secant is None and use_secant and gap <= SECANT_GAP and not rho.any():
                secant = _SecantCorrection(n)  # the end-game: pairs from the next step on
            previous = (x, g)

            relaxed = bool(rho.any())

            def direction(mu_t):
                # (dx, dc, dw) for the barrier parameter mu_t; dc the rows' linearised change
                if relaxed:
                    dx = solve(jac.T(mu_t / s + sig * rho) - g)
                else:  # (the affine probe's: -g alone)
                    dx = solve(jac.T(mu_t / s) - g if np.any(mu_t) else -g)
                if secant is not None and secant.w.size:
                    # the surrogate's missing curvature, learnt
                    corrected = secant.step(band_factor, fixed, dx)
                    dx = dx if corrected is None else corrected
                # the slacks' change: the rows' linearised change, the relaxation gone
                dc = jac.dot(dx) - rho
                return dx, dc, mu_t / s - w - sig * dc

            # Mehrotra's probe: the affine step (mu = 0) says how far the complementarity can fall
            _, dca, dwa = direction(0.0)
            ap, ad = _to_boundary(s, dca, 1.0), _to_boundary(w, dwa, 1.0)
            gap_aff = float((s + ap * dca) @ (w + ad * dwa)) / nc
            if last_step >= SHORT_STEP:
                # sigma = (gap_aff / gap)^3; the barrier parameter is never raised here
                m = max(MU_FINAL / 10, min(m, gap * min(1.0, (gap_aff / max(gap, 1e-300)) ** 3)))
            else:
                # the last step was cut short (the iterate off the central path): re-centre at the
                # current gap
                m = max(MU_FINAL / 10, gap)
            if err_d > tol and not stalled and (not feasible_ok or rho.any()):
                m = max(m, min(m_last, (MU_PER_DUAL_RELAXED if rho.any() else MU_PER_DUAL)
                                * err_d))
            m_last = m
            # Mehrotra's corrector: the affine step's second-order complementarity term, unless the
            # direction then does not descend the barrier function (slope g.dx - (mu / s).(J dx))
            dx, dc, dw = direction(m - dca * dwa)
            if float(g @ dx) - m * float((dc + rho) @ (1.0 / s)) >= 0.0:
                dx, dc, dw = direction(m)
            tau = max(TAU_MIN, 1.0 - m)
            a_max, az = _to_boundary(s, dc, tau), _to_boundary(w, dw, tau)
            value = f_val - m * float(np.sum(np.log(s)))
            g_dx = float(g @ dx)

            def accept(a, x=x, dx=dx, dc=dc, m=m, value=value, g_dx=g_dx, c=c, s=s, rho=rho,
                       tau=tau, sig=sig):
                """(point, rows, step) at step a if within the boundary fraction and Armijo's
                decrease (while rows are relaxed: the boundary fraction alone, the relaxation
                shrinking with a), else None."""
                d = a * dx
                # the step, then its second-order corrections (at any length: a row with a tiny
                # slack breaks under the linearisation's error at any length; MAX_SOC in all, each
                # while it brings the rows nearer the boundary fraction by KAPPA_SOC)
                short = np.inf
                while True:
                    f_t, c_t = self.constraints(x + d, P, lin_c, offsets, min_depth, keep)
                    s_t = c_t + (1.0 - a) * rho
                    below = (1 - tau) - float(np.min(s_t / s))  # <= 0: within the fraction
                    if below <= 0.0:
                        if rho.any():
                            return x + d, c_t, a
                        # Armijo against the decrease the model predicts: the objective linear,
                        # the barrier exact on the linearised slacks (its slope alone, for a row
                        # leaving a tiny slack, asks a decrease the log never gives: steps of 1e-4)
                        v_t = f_t - m * float(np.sum(np.log(s_t)))
                        pred = a * g_dx - m * float(np.sum(np.log1p(a * dc / s)))
                        return (x + d, c_t, a) if pred <= 0 and v_t <= value + 1e-4 * pred else None
                    if (socs[0] == MAX_SOC or below > KAPPA_SOC * short
                            or not np.all(s_t[:nd_] > 0)):
                        return None
                    short = below
                    socs[0] += 1
                    # what the linearisation of the curved rows missed
                    e = c_t[nd_:] - (c[nd_:] + jac.curved_dot(d))
                    d = d + solve(-jac.curved_T(sig[nd_:] * e))

            socs = [0]  # this iteration's second-order corrections
            found = _backtrack(a_max, accept)
            if found is None:
                status = "Infeasible_Problem_Detected" if rho.any() else "Line_Search_Failed"
                break
            last_step = float(np.max(np.abs(found[0] - x)) / max(float(np.max(np.abs(dx))), 1e-300))
            stuck = stuck + 1 if rho.any() and found[2] < STUCK_STEP else 0
            if stuck == STUCK_ITER:
                # the relaxation no longer shrinks: no point within every row near here
                status = "Infeasible_Problem_Detected"
                break
            x, c = found[0], found[1]
            rho = (1.0 - found[2]) * rho if found[2] < 1.0 else np.zeros(nc)
            if rho.any() and np.all(c >= (1.0 - TAU_MIN) * (c + rho)):
                # every row holds, each with at least the boundary fraction of its slack: the
                # relaxation is done (else it would end only with a full step, after many short ones
                # that shrink it geometrically); a row barely inside would leave a slack near 0
                rho = np.zeros(nc)
            s = c + rho
            w = w + min(1.0, az) * dw
            last_az, last_socs = az, socs[0]
            # IPOPT's safeguard keeps w s within a band around mu
            r = m / s
            w = np.minimum(np.maximum(w, r * 1e-10), r * 1e10)
            it += 1
            relaxed_its += bool(rho.any())
        run = nw._end(setup, x, P, trace_ref, status, it, 0, t0)
        return InteriorRun(**{k: getattr(run, k) for k in NewtonRun.__dataclass_fields__},
                           multipliers=w, relaxed_iterations=relaxed_its)

    def _factor(self, ab: np.ndarray, idx: np.ndarray, shift: float, may_shift: bool = True):
        """The banded matrix on the free variables (held ones: identity) factorised, shifted until
        positive definite (with `may_shift` false: only as it is): (solve(rhs), shift, its banded
        factor, the held mask) or None."""
        n = self.n
        if self._held is None or self._held[0] is not idx:
            self._held = (idx, *self._held_entries(idx))
        _, fixed, outside = self._held
        if idx is not self.free_idx:
            np.put(ab, outside, 0.0)  # (the band's parts leave out the held entries of free_idx)
        ab[0, fixed] = 1.0
        shift = shift / 4 if shift > 1e-14 else 0.0

        def diagonal_scale() -> float:  # bounds the shift: computed only once one is applied
            return max(float(np.max(np.abs(ab[0, idx]))) if len(idx) else 0.0, 1e-12)

        scale = diagonal_scale() if shift else None
        while scale is None or shift <= 1e12 * scale:
            shifted = ab.copy()
            if shift:
                shifted[0, idx] += shift
            factor, info = dpbtrf(shifted, lower=1, overwrite_ab=1)
            if info == 0:
                def solve(rhs, factor=factor):
                    d = dpbtrs(factor, np.where(fixed, 0.0, rhs)[:, None], lower=1)[0][:, 0]
                    return d if np.all(np.isfinite(d)) else np.zeros(n)
                return solve, shift, factor, fixed
            if not may_shift:
                return None
            scale = diagonal_scale() if scale is None else scale
            shift = max(1e-8 * scale, 10 * shift)
        return None

    def _held_entries(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(held mask, flat band entries in a held joint's row or column) for free indices idx."""
        fixed = np.ones(self.n + 1, bool)
        fixed[idx] = False
        return fixed[:self.n], np.flatnonzero(fixed[:self.n][None, :] | fixed[self.band_partner])


class _RowJacobian:
    """The rows' Jacobian at one iterate, in the order of `InteriorNewton.constraints` (bounds
    +-e_i, linear rows +-a_i, depths grad z, tool rows -grad g): products with it and with its
    transpose, each pair of direct rows by one product. The curved rows' entries are written into
    the solver's CSR matrix in place (valid until the next iterate's)."""

    def __init__(self, ip: InteriorNewton, idx: np.ndarray, DZ: np.ndarray, tj: np.ndarray):
        if ip.jac_idx is not idx and not np.array_equal(ip.jac_idx, idx):
            ip._jac_pattern(idx)
        self.idx, self.n, self.L, self.C = idx, ip.n, ip.lin_map, ip.jac_curved
        self.nb, self.nl = len(idx), ip.n_lin
        self.C.data[ip.jac_depth] = DZ[1:ip.T].ravel()
        self.C.data[ip.jac_tool] = -tj.ravel()  # (points, k, W nq)

    def T(self, v: np.ndarray) -> np.ndarray:
        """sum_i v_i grad c_i"""
        nb, nl = self.nb, self.nl
        out = _csr_tdot(self.C, v[2 * nb + 2 * nl:], self.n)
        _csr_tdot(self.L, v[2 * nb:2 * nb + nl] - v[2 * nb + nl:2 * nb + 2 * nl], self.n, out)
        out[self.idx] += v[:nb] - v[nb:2 * nb]
        return out

    def dot(self, dx: np.ndarray) -> np.ndarray:
        """grad c_i . dx for every row"""
        nb, nl = self.nb, self.nl
        out = np.zeros(2 * nb + 2 * nl + self.C.shape[0])
        np.take(dx, self.idx, out=out[:nb])
        np.negative(out[:nb], out=out[nb:2 * nb])
        lin = _csr_dot(self.L, dx, out[2 * nb:2 * nb + nl])
        np.negative(lin, out=out[2 * nb + nl:2 * nb + 2 * nl])
        _csr_dot(self.C, dx, out[2 * nb + 2 * nl:])
        return out

    def curved_dot(self, dx: np.ndarray) -> np.ndarray:
        """grad c_i . dx for the curved rows alone (depths, tool rows)"""
        return _csr_dot(self.C, dx)

    def curved_T(self, v: np.ndarray) -> np.ndarray:
        """sum_i v_i grad c_i over the curved rows alone"""
        return _csr_tdot(self.C, v, self.n)


def _to_boundary(v: np.ndarray, dv: np.ndarray, tau: float) -> float:
    """The largest step a <= 1 with v + a dv >= (1 - tau) v for positive v: tau over the largest
    relative decrease."""
    fall = float(np.min(dv / v))
    return 1.0 if fall >= 0.0 else min(1.0, -tau / fall)


def _csr_dot(A: sp.csr_matrix, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """A @ x (added to `out` if given) by SciPy's kernel without its dispatch, which costs twice
    the product at these sizes (tens of microseconds, several times an iteration)."""
    y = np.zeros(A.shape[0]) if out is None else out
    _sparsetools.csr_matvec(A.shape[0], A.shape[1], A.indptr, A.indices, A.data, x, y)
    return y


def _csr_tdot(A: sp.csr_matrix, v: np.ndarray, n: int, out: np.ndarray | None = None
              ) -> np.ndarray:
    """A^T @ v (added to `out` if given), A's CSR arrays read as its transpose's CSC."""
    y = np.zeros(n) if out is None else out
    _sparsetools.csc_matvec(n, A.shape[0], A.indptr, A.indices, A.data, v, y)
    return y
