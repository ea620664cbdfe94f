"""The curve played at a plan's pace (a quintic Hermite through the waypoints) and the linear rows
that bound its velocity, acceleration and, between the waypoints, position (the OCP's limit rows,
`CURVE_ROWS = "curve"`).

`surestep export` plays it (`evaluate_curve`); the OCP's transcription bounds it
(`curve_control_rows`, `curve_point_weights`); docs/motion_limits_and_export.md, "The curve and its
rows", derives and measures it.
"""

from __future__ import annotations

import functools
import math

import numpy as np

# The curve `surestep export` plays at the planned times when it is within the limits, and the one
# whose limits the OCP's rows bound (with `limits.CURVE_ROWS = "curve"`): between waypoints t and
# t+1 the quintic Hermite polynomial with the waypoints' positions and their finite-difference
# velocities and accelerations at both ends,
#   v_t = (q_t+1 - q_t-1) / (2 dt),  a_t = (q_t+1 - 2 q_t + q_t-1) / dt^2   (interior waypoints),
#   v_0 = v_T = 0,  a_0 = (q_1 - q_0) / dt^2,  a_T = (q_T-1 - q_T) / dt^2
#                                                         (from and to rest, as plan_report),
# so it is twice continuously differentiable, passes every waypoint at its planned time, and its
# knot accelerations are exactly the finite-difference accelerations `plan_report` checks. Each
# piece depends on four waypoints (t-1 .. t+2), so every row is local. Velocity (a quartic) and
# acceleration (a cubic) are linear in the waypoints, so their Bernstein control points are too, and
# a polynomial lies between its smallest and largest control point: bounding the control points
# bounds the curve everywhere (a sufficient linear condition). The tool's speed is nonlinear:
# bounded at TOOL_POINTS of every piece (the export checks it densely and says so).

# parts of a step for the control-point bounds (tighter with more)
CURVE_PIECES = {"velocity": 1, "acceleration": 3}
# fractions of a step where the tool-speed rows bound the curve
TOOL_POINTS = (0.0, 0.25, 0.5, 0.75)
TOOL_MARGIN = 0.02  # the rows bound the tool's speeds at those points to (1 - this) of their limits
CURVE_NAME = ("quintic Hermite through the waypoints, finite-difference velocities and "
              "accelerations at them")


def _quintic_basis() -> np.ndarray:
    """(6, 6): power coefficients c_0..c_5 of p(s), s in [0, 1], from (p0, p0', p0'', p1, p1', p1'')
    (d/ds)."""
    M = np.zeros((6, 6))
    for row, (s, d) in enumerate(((0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2))):
        for k in range(6):
            if k >= d:
                M[row, k] = math.perm(k, d) * (s ** (k - d) if k > d else 1.0)
    return np.linalg.inv(M)


_QUINTIC = _quintic_basis()


def knot_derivatives(T: int, dt: float, moving: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(T+1, m) maps of one joint's waypoints to its knot velocities and accelerations (see above).

    `moving`: the curve starts in motion (a re-plan from the executed curve's state): the first
    knot's velocity and acceleration are given, as two more entries after the waypoints (m = T + 3:
    the waypoints, then v_0, then a_0); else m = T + 1 and the curve starts at rest."""
    m = T + 3 if moving else T + 1
    Dv, Da = np.zeros((T + 1, m)), np.zeros((T + 1, m))
    for i in range(1, T):
        Dv[i, i + 1], Dv[i, i - 1] = 1 / (2 * dt), -1 / (2 * dt)
        Da[i, i - 1], Da[i, i], Da[i, i + 1] = 1 / dt**2, -2 / dt**2, 1 / dt**2
    if moving:
        Dv[0, T + 1], Da[0, T + 2] = 1.0, 1.0
    else:
        Da[0, 0], Da[0, 1] = -1 / dt**2, 1 / dt**2
    Da[T, T], Da[T, T - 1] = -1 / dt**2, 1 / dt**2
    return Dv, Da


@functools.lru_cache(maxsize=256)
def curve_coefficients(T: int, dt: float, moving: bool = False) -> np.ndarray:
    """(T, 6, m): for piece t, the power coefficients in s = (time - t dt) / dt of the curve, as a
    linear map of one joint's waypoints, then (`moving`) its start velocity and acceleration (the
    same for every joint; `knot_derivatives`). Cached (a re-plan evaluates its curve at every
    frame), hence read-only."""
    Dv, Da = knot_derivatives(T, dt, moving)
    E = np.eye(T + 1, Dv.shape[1])
    out = np.zeros((T, 6, Dv.shape[1]))
    for t in range(T):
        data = np.vstack([E[t], dt * Dv[t], dt**2 * Da[t],
                          E[t + 1], dt * Dv[t + 1], dt**2 * Da[t + 1]])
        out[t] = _QUINTIC @ data
    out[np.abs(out) < 1e-12 * np.abs(out).max()] = 0.0  # rounding of exact zeros
    out.flags.writeable = False
    return out


def _to_bernstein(n: int) -> np.ndarray:
    """(n+1, n+1): Bernstein control points of a degree-n polynomial on [0, 1] from its power
    coefficients."""
    B = np.zeros((n + 1, n + 1))
    for j in range(n + 1):
        for k in range(j + 1):
            B[j, k] = math.comb(j, k) / math.comb(n, k)
    return B


def derivative_power(order: int, dt: float) -> np.ndarray:
    """(6 - order, 6): power coefficients of the order-th time derivative of a quintic in s = time /
    dt."""
    D = np.zeros((6 - order, 6))
    for k in range(order, 6):
        D[k - order, k] = math.perm(k, order) / dt**order
    return D


def _reparametrise(n: int, lo: float, hi: float) -> np.ndarray:
    """(n+1, n+1): power coefficients in sigma of p(lo + (hi - lo) sigma) from those of p(s)."""
    R = np.zeros((n + 1, n + 1))
    for j in range(n + 1):
        for k in range(j, n + 1):
            R[j, k] = math.comb(k, j) * lo ** (k - j) * (hi - lo) ** j
    return R


def curve_control_rows(T: int, dt: float, pieces: dict | None = None,
                       moving: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Rows (linear maps of one joint's waypoints) whose absolute values bound the curve's
    |velocity| and |acceleration| everywhere: the knot values once, and the interior Bernstein
    control points of each step split in `pieces[kind]` equal parts (default CURVE_PIECES; more
    parts, tighter bounds: the control points converge to the curve's values, measured in
    docs/motion_limits_and_export.md)."""
    pieces = {**CURVE_PIECES, **(pieces or {})}
    C = curve_coefficients(T, dt, moving)
    out = []
    for order, kind in ((1, "velocity"), (2, "acceleration")):
        m = int(pieces[kind])
        n = 5 - order
        D = derivative_power(order, dt)
        B = _to_bernstein(n)
        rows = [(B @ D)[0] @ C[0]]
        for t in range(T):
            for k in range(m):
                ctrl = B @ _reparametrise(n, k / m, (k + 1) / m) @ D @ C[t]  # (n+1, T+1)
                rows += list(ctrl[1:])  # its first is the last one of the part before
        out.append(np.array(rows))
    return out[0], out[1]


def curve_limit_rows(T: int, dt: float, limits, joints, moving: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(rows, the joint of each row): the OCP's linear limit rows on one joint's extended vector
    (its T+1 waypoints, then v_0 and a_0 when `moving`), each normalised by its limit, so that
    |row . x_j| <= 1 keeps it; the one builder of the transcription's and the interior point's rows.

    The knot velocities within v_max - a_max dt / 2 when that is positive for every joint in
    `joints` (sufficient given the acceleration rows: |a| <= a_max everywhere and a knot is dt / 2
    away at most; fewer rows), else the velocity quartic's control points; then the acceleration
    cubic's control points (`curve_control_rows`). Rows ordered by kind, row, then joint."""
    Rv, Ra = curve_control_rows(T, dt, moving=moving)
    v_scale = limits.velocity
    slack = limits.velocity - limits.acceleration * dt / 2
    if np.all(slack[joints] > 0):
        Rv = knot_derivatives(T, dt, moving)[0][1:T]
        v_scale = slack
    rows, which = [], []
    for R, scale in ((Rv, v_scale), (Ra, limits.acceleration)):
        for row in R:
            for j in joints:
                rows.append(row / scale[j])
                which.append(j)
    return np.array(rows), np.array(which)


def curve_position_rows(T: int, dt: float, lower, upper, joints, moving: bool = False
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, the joint of each row, offsets): the joint bounds on the played curve between the
    waypoints, as linear rows on one joint's extended vector (as `curve_limit_rows`): the interior
    Bernstein control points b1..b4 of each step's quintic (b0, b5 are the waypoints), centred and
    normalised, so that |row . x_j + offset| <= 1 keeps lower[j] <= b <= upper[j], and the curve
    within the bounds everywhere (a polynomial lies between its smallest and largest control point).

    With p' = dt v and p'' = dt^2 a at the knots: b1 = q_t + dt v_t / 5,
    b2 = q_t + 2 dt v_t / 5 + dt^2 a_t / 20, and symmetrically b3, b4 from q_t+1."""
    Dv, Da = knot_derivatives(T, dt, moving)
    eye = np.eye(T + 1, Dv.shape[1])  # the waypoints in the extended vector
    ctrl = []
    for t in range(T):
        q0, v0, a0 = eye[t], Dv[t] * dt, Da[t] * dt**2
        q1, v1, a1 = eye[t + 1], Dv[t + 1] * dt, Da[t + 1] * dt**2
        ctrl += [q0 + v0 / 5, q0 + 2 * v0 / 5 + a0 / 20, q1 - 2 * v1 / 5 + a1 / 20, q1 - v1 / 5]
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    centre, half = (upper + lower) / 2, (upper - lower) / 2
    rows, which, offsets = [], [], []
    for b in ctrl:
        for j in joints:
            rows.append(b / half[j])
            which.append(j)
            offsets.append(-centre[j] / half[j])
    return np.array(rows), np.array(which), np.array(offsets)


def curve_point_weights(T: int, dt: float, t: int, s: float,
                        moving: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(m,) weights of one joint's waypoints (and start derivatives, `moving`) giving the curve's
    position and velocity in piece t at fraction s."""
    C = curve_coefficients(T, dt, moving)[t]
    powers = np.array([s**k for k in range(6)])
    dpow = np.array([k * s ** (k - 1) if k else 0.0 for k in range(6)]) / dt
    return powers @ C, dpow @ C


def tool_point_windows(T: int, dt: float, moving: bool = False
                       ) -> tuple[list[list[int]], np.ndarray, np.ndarray]:
    """The points where the OCP bounds the tool's speeds (TOOL_POINTS of every piece but the first
    piece's start, which is at rest or the executed curve's own state): per point the four waypoints
    its piece depends on (t-1 .. t+2, clipped at the ends), its weights (8: the curve's position
    from the four, then its velocity; a repeated end node weighted in its first slot only), and,
    `moving`, the weights of the start's velocity and acceleration (4: in the position, then in the
    velocity; zeros at rest)."""
    windows, weights, consts = [], [], []
    for t in range(T):
        nodes = [min(max(m, 0), T) for m in (t - 1, t, t + 1, t + 2)]
        for frac in TOOL_POINTS:
            if t == 0 and frac == 0.0:
                continue
            wq, wv = curve_point_weights(T, dt, t, frac, moving)
            cw = np.zeros(8)
            for slot, m in enumerate(nodes):
                if m not in nodes[:slot]:
                    cw[slot], cw[4 + slot] = wq[m], wv[m]
            windows.append(nodes)
            weights.append(cw)
            consts.append(np.concatenate([wq[T + 1:], wv[T + 1:]]) if moving else np.zeros(4))
    return windows, np.array(weights), np.array(consts)


def evaluate_curve(q: np.ndarray, dt: float, times: np.ndarray,
                   start: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The curve through the waypoints `q` ((T+1, n)) at the planned pace: positions, velocities and
    accelerations at `times` ([0, T dt]), each (len(times), n). `start`: the first knot's velocity
    and acceleration ((n,) each) when the curve starts in motion (a re-plan); default at rest."""
    q = np.asarray(q, float)
    T = len(q) - 1
    if start is not None:
        q = np.vstack([q, np.asarray(start[0], float)[None], np.asarray(start[1], float)[None]])
    x = np.asarray(times, float) / dt
    piece = np.clip(np.floor(x).astype(int), 0, T - 1)
    s = x - piece
    # the pieces the times fall in, each's coefficients once
    used, which = np.unique(piece, return_inverse=True)
    coef = np.einsum("tkm,mj->tkj", curve_coefficients(T, dt, start is not None)[used], q)
    out = []
    for order in range(3):
        D = derivative_power(order, dt) if order else np.eye(6)
        c = np.einsum("ik,tkj->tij", D, coef)[which.ravel()]  # (N, 6 - order, n)
        p = np.stack([s**k for k in range(6 - order)], axis=1)  # (N, 6 - order)
        out.append(np.einsum("nk,nkj->nj", p, c))
    return out[0], out[1], out[2]
