"""The motion-limit rows of the multiple-shooting transcription (IPOPT), and their stages.

With a problem's `limits.enforce: true` the NLP carries the motion limits, each row normalised by
its limit (so every bound is 1): linear rows `A x` (A constant) on the joints, then the tool's
rates at points of the played curve, each a function of a window of waypoints (`tool_point`).
`add_limit_rows` adds them to a `Transcription` (its module docstring says what they bound);
`limit_stages` gives their blocks of the stage-wise derivatives (`staged_derivatives.py`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..errors import SurestepError
from ..model import limits as lm
from .stages import entries


def add_limit_rows(tr, x: ca.SX, qs: list, g: list) -> None:
    """Append the motion-limit rows of the transcription `tr` to `g`: the linear ones `A x`
    (A constant), then the tool's normalised translation and rotation (`tr.tool_point`, of a
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
    tr.n_lin = tr.n_tool = 0
    tr.A, tr.tool_point, tr.rcm_bound, tr.limit_g = None, None, None, None
    # the curve's tool rows as a function of (q(s), q'(s)) (`tool_stages`)
    tr.tool_rate = None
    if tr.limits is None:
        return
    dt, lim = tr.limits
    tr.curve = lm.CURVE_ROWS
    if tr.curve not in ("curve", "steps"):
        raise SurestepError(f"limits.CURVE_ROWS must be 'curve' or 'steps', got {tr.curve!r}")
    tr.A, tr.A_offset = _linear_rows(tr, dt, lim, x.shape[0])
    tr.n_lin = len(tr.A)
    out, w, c, tr.tool_rate, windows, weights = _tool_rows(tr.robot, tr.curve, tr.T, dt, lim)
    tr.tool_point = ca.Function("tool_point", [w, c], [out])
    tr.tool_windows = windows  # per point: the waypoints (node indices) it depends on
    tr.tool_weights = ca.DM(np.array(weights).T)  # (2 win, points)
    tr.tool_k = out.shape[0]
    tr.n_tool = tr.tool_k * len(windows)
    lin = ca.mtimes(ca.sparsify(ca.DM(tr.A)), x)
    W = ca.horzcat(*[ca.vertcat(*[qs[m] for m in nodes]) for nodes in windows])
    tool = ca.vec(tr.tool_point.map(len(windows))(W, tr.tool_weights))
    g += [lin, tool]
    tr.limit_g = ca.Function("limit_g", [x], [ca.vertcat(lin, tool)])
    tr.rcm_bound = lm.rcm_insertion_bound(tr.robot, lim.rcm_min_distance)


def _q_index(tr) -> list[np.ndarray]:
    """The joints' positions in the decision vector, per node."""
    offsets = dict(zip((name for name, _, _ in tr.layout.blocks),
                       np.cumsum([0] + [size for _, size, _ in tr.layout.blocks])))
    return [np.arange(offsets[f"q{t}"], offsets[f"q{t}"] + tr.robot.nq)
            for t in range(tr.T + 1)]


def _linear_rows(tr, dt: float, lim, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(A, its offsets): the linear rows `|A x + offset| <= 1` over the decision vector (n
    entries), the rows that are zero by construction left out."""
    T = tr.T
    idx = _q_index(tr)
    mov = tr.robot.supporting_joints()
    if tr.curve == "curve":
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
    Rp, jp, off = lm.curve_position_rows(T, dt, *lm.joint_bounds(tr.robot,
                                                                  lim.rcm_min_distance), mov)
    offsets = np.concatenate([np.zeros(len(rows)), off])
    blocks = []
    for row, j in zip([*rows, *Rp], [*joints, *jp]):
        B = np.zeros(n)
        B[[idx[m][j] for m in range(T + 1)]] = row
        blocks.append(B)
    A = np.array(blocks)
    # exact zeros, rounded
    A[np.abs(A) < 1e-12 * np.abs(A).max(axis=1, keepdims=True)] = 0.0
    # rows that are 0 by construction (the velocities at rest)
    nonzero = np.any(A != 0, axis=1)
    return A[nonzero], offsets[nonzero]


def _tool_rows(robot, curve: str, T: int, dt: float, lim) -> tuple:
    """One tool point's rows over its window of waypoints: (the rows, the window's symbol `w`,
    the point's weights' symbol `c`, the rate Function of (q(s), q'(s)) or None, the points'
    windows, their weights)."""
    nq = robot.nq
    qa, qd = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
    Ta = robot.fk_expr(qa, robot.frame)
    if curve == "curve":
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
        windows, weights, _ = lm.tool_point_windows(T, dt)
        return out, w, c, rate, windows, weights
    win = 2
    # c unused: the chord of (q_t, q_t+1)
    w, c = ca.SX.sym("w", win * nq), ca.SX.sym("c", 2 * win)
    Tb = robot.fk_expr(w[nq:], robot.frame)
    Tw = robot.fk_expr(w[:nq], robot.frame)
    rows = [ca.sumsqr(Tb[:3, 3] - Tw[:3, 3]) / (lim.tool_speed * dt) ** 2]
    if lim.tool_rotation * dt < np.pi:  # else any rotation is within the limit
        rows.append((3 - ca.sum1(ca.sum2(Tw[:3, :3] * Tb[:3, :3])))
                    / (2 - 2 * np.cos(lim.tool_rotation * dt)))
    out = ca.vertcat(*rows)
    windows, weights = [[t, t + 1] for t in range(T)], [np.zeros(2 * win)] * T
    return out, w, c, None, windows, weights


def limit_stages(tr, X: ca.MX, lam_g: ca.MX, q_idx: list, n: int) -> tuple:
    """The limit rows' part of the stage-wise derivatives: (their Jacobian entries, their Hessian
    entries, the linear rows' constant Jacobian, the tool rows' mapped Jacobians and curvatures,
    the rows' values `[A x, tool rows]`), at the decision vector X with the multipliers lam_g."""
    k, npts = tr.tool_k, len(tr.tool_windows)
    tool_jac, tool_hess = tool_stages(tr)
    win_idx = [np.concatenate([q_idx[m] for m in nodes]) for nodes in tr.tool_windows]
    t_idx = [tr.ng_eq + tr.n_lin + np.arange(k * p, k * (p + 1)) for p in range(npts)]
    jac_part = entries(list(zip(t_idx, win_idx)))
    hess_part = entries([(i, i) for i in win_idx])
    lin_const = np.zeros((tr.ng, n))
    lin_const[tr.ng_eq:tr.ng_eq + tr.n_lin] = tr.A
    W_x = ca.reshape(X[np.concatenate(win_idx).tolist()], tool_jac.size1_in(0), npts)
    Jt = tool_jac.map(npts)(W_x, tr.tool_weights)
    Ht = tool_hess.map(npts)(W_x, tr.tool_weights,
                             ca.reshape(lam_g[tr.ng_eq + tr.n_lin:], k, npts))
    A_sp = ca.sparsify(ca.DM(tr.A))
    g_lim = [ca.mtimes(A_sp, X), ca.vec(tr.tool_point.map(npts)(W_x, tr.tool_weights))]
    return jac_part, hess_part, lin_const, Jt, Ht, g_lim


def tool_stages(tr) -> tuple[ca.Function, ca.Function]:
    """One tool point's Jacobian `(w, c) -> d rows / d w` and curvature
    `(w, c, lam) -> Hess_w (lam . rows)` over its window `w` of waypoints (`tool_point`).

    On the played curve a point's joints and joint velocities are linear in the window,
    `z = (q(s), q'(s)) = M w` with `M = [c_q^T kron I; c_v^T kron I]`, so the derivatives are
    the rate's in z (2 nq variables) mapped by M:
    `J = J_z M`, `H = M^T H_z M`, the same matrices as differentiating the composed rows over w
    (4 nq variables) in fewer instructions (docs/motion_limits_and_export.md, "The enforced
    solve's speed"). The finite-difference rows ("steps") are differentiated directly."""
    w_in, c_in = tr.tool_point.sx_in()
    lam_k = ca.SX.sym("lam_k", tr.tool_k)
    if tr.tool_rate is None:
        rows_w = tr.tool_point(w_in, c_in)
        return (ca.Function("tool_jac", [w_in, c_in], [ca.densify(ca.jacobian(rows_w, w_in))]),
                ca.Function("tool_hess", [w_in, c_in, lam_k],
                            [ca.densify(ca.hessian(ca.dot(lam_k, rows_w), w_in)[0])]))
    nq = tr.robot.nq
    win = c_in.shape[0] // 2
    z_a, z_d = ca.SX.sym("qa", nq), ca.SX.sym("qd", nq)
    z = ca.vertcat(z_a, z_d)
    rows_z = tr.tool_rate(z_a, z_d)
    jz = ca.Function("tool_jac_z", [z], [ca.densify(ca.jacobian(rows_z, z))])
    hz = ca.Function("tool_hess_z", [z, lam_k],
                     [ca.cse(ca.densify(ca.hessian(ca.dot(lam_k, rows_z), z)[0]))])
    ws = ca.reshape(w_in, nq, win)
    z_w = ca.vertcat(ws @ c_in[:win], ws @ c_in[win:])
    M = ca.vertcat(ca.kron(c_in[:win].T, ca.SX.eye(nq)), ca.kron(c_in[win:].T, ca.SX.eye(nq)))
    return (ca.Function("tool_jac", [w_in, c_in], [ca.densify(jz(z_w) @ M)]),
            ca.Function("tool_hess", [w_in, c_in, lam_k],
                        [ca.densify(M.T @ hz(z_w, lam_k) @ M)]))
