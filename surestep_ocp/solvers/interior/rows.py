"""The limit rows of one structure: the linear rows (velocity and acceleration control points,
joint bounds between the waypoints), the tool's speeds at points of each piece (compiled CasADi
functions of their windows of waypoints) and the means' depths; their values at a point and a run's
start point."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ...buffered import Buffered
from ...model import limits as lm
from ...ocp.codegen import SX_OPTIONS, compiled_or_interpreted
from ..newton import BOUND_PUSH, parameters
from .jacobian import _csr_dot
from .options import RELAX_TO, WINDOW


@dataclass
class RunRows:
    """One run's rows: the parameters, the linear rows' constant part, the tool points' offsets,
    the depth bound and the kept fraction of the limits (`reserve`), and their sizes."""

    P: np.ndarray
    lin_c: np.ndarray
    offsets: np.ndarray
    min_depth: float
    keep: float
    tool_scale: np.ndarray  # the tool rows' scale over the kept limits
    idx: np.ndarray  # the free variables
    nb: int  # free variables (bound rows: 2 nb)
    nl: int  # linear rows (2 nl)
    nd: int  # the direct rows (bounds, linear) come first, then the curved ones

    def values(self, ip, x) -> tuple[float, np.ndarray]:
        """(objective, rows) at x (`constraints`)."""
        return ip.constraints(x, self.P, self.lin_c, self.offsets, self.min_depth, self.keep)


class RowsPart:
    """`InteriorNewton`'s rows: built once per structure, evaluated at each trial point."""

    def _build_linear_rows(self, newton, robot, step_s, limits, moving) -> None:
        """The structure's sizes and the linear rows per joint, their sparse form on the variables
        (`lin_*`)."""
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
        # the linear rows as a sparse matrix
        self.lin_map = sp.csr_matrix((self.lin_coef.ravel(),
                                      (np.repeat(np.arange(self.n_lin), width),
                                       self.lin_idx.ravel())), shape=(self.n_lin, self.n))
        self.lin_map.eliminate_zeros()

    def _build_tool_points(self, robot, lim):
        """The tool points' windows and weights and the tool rows' expressions: (qa, qd, pv, Rd,
        out, lam, y, Mq) for `_build_tool_functions`."""
        T, nq, dt, moving = self.T, self.nq, self.dt, self.moving
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
        return qa, qd, pv, Rd, out, lam, y, Mq

    def _build_tool_functions(self, qa, qd, pv, Rd, out, lam, y, Mq, codegen, codegen_required
                              ) -> None:
        """The tool rows, their Jacobians and the end-game's curvature as (compiled) functions of
        the joints and the points' offsets."""
        nq, npts, n = self.nq, self.n_pts, self.n
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

