"""What a structure fixes for the certificate: the free joints and their bounds (`_Layout`) and the
enforced motion-limit rows (`_Rows`), built once per process.

The limit rows are NumPy arrays over all rows at once: the played curve's linear rows
(`model/limits/curve.py`) and the tool's rates at its points, by a mapped CasADi Function compiled
like the certificate's (`certificate_function._Function`). A re-plan from a moving start keeps its
horizon's rows with the start state as values (`_Rows.at`); its tool rates' map is padded to a
multiple of `PAD_POINTS`, shared by a re-planning loop's horizons.
"""

from __future__ import annotations

import time
from copy import copy

import casadi as ca
import numpy as np
from scipy.sparse import csr_matrix

from ..buffered import thread_buffered
from ..model import limits as lm
from ..model.limits import problem_limits
from ..output.solution import Solution
from ..problem.setup import Setup
from .certificate_function import _Function

PAD_POINTS = 64  # ... and its tool rates' map of points (rounded up to a multiple of this)


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
