"""The belief-space OCP: direct multiple shooting over joints, belief mean and covariance, solved by IPOPT.

Per node t = 0..T: joints `q_t`, mean `mu_t` (camera-frame pose) and the scaled
`vech(Sigma_t)`; per interval: the gain `K_t` as a free variable. The covariance
step is written in Joseph form,

    Sigma_t+1 = (I - K H) P (I - K H)^T + K R V R^T K^T,

which is positive semidefinite for any K and is minimised, in the matrix (Loewner)
order, by the Kalman gain. Since every later step is monotone in that order,
minimising Tr(Sigma_T) over the gains as well as the path gives exactly the Kalman
gains at the optimum: the NLP has no symbolic inverse, a polynomial Hessian, and
no gain equality whose Jacobian blows up when the observation is much sharper than
the prior (the form `Sigma+ = (I - K H) P` with `K S = P H^T` as a constraint was
measured to fail: IPOPT restoration failures on the default problem). The solution
is re-evaluated by the exact EKF from its poses anyway. Constraints:

    mu_t = pose_in_camera(FK(q_t))                      every node
    Sigma_t+1 = Joseph(Sigma_t, K_t; mu_t, mu_t+1)       every interval
    q_lo <= q_t <= q_hi,  mu_t,z >= min_depth
    q_0 = q_start, mu_0 = x_start, Sigma_0 given, mu_T = x_goal  (hard terminal equality)

Objective: `Tr(Sigma_T)` (divided by the initial guess's value, for scaling)
plus an optional joint-step smoothness term.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .belief import NV, NX, BeliefModel, trace_vech, unvech, vech
from .setup import Setup
from .solution import Solution, evaluate


@dataclass
class InitialGuess:
    """A joint trajectory to start from, and where it came from."""

    q: np.ndarray  # (T+1, nq)
    source: str


_DIAG = [0, 6, 11, 15, 18, 20]  # positions of the diagonal in vech


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
        return np.concatenate([np.asarray(values[name], float).ravel() for name, _, _ in self.blocks])


def guess_from_joints(setup: Setup, model: BeliefModel, q: np.ndarray) -> dict[str, np.ndarray]:
    """A consistent primal point (mean, covariance and gains) from a joint trajectory."""
    T = len(q) - 1
    mu = np.array([setup.pose_of(qi) for qi in q])
    sig, pred = model.propagate(mu)
    out = {}
    for t in range(T + 1):
        out[f"q{t}"], out[f"mu{t}"], out[f"s{t}"] = q[t], mu[t], vech(sig[t])
    for t in range(T):
        F, Q, H, R = (np.asarray(M) for M in model.jacobians(mu[t], mu[t + 1]))
        S = H @ pred[t] @ H.T + R @ np.asarray(model.observation_noise(mu[t + 1])) @ R.T
        out[f"K{t}"] = np.linalg.solve(S, H @ pred[t]).T.ravel(order="F")
    return out


def solve_ocp(setup: Setup, init: InitialGuess, solver_options: dict | None = None,
              method: str = "ocp") -> Solution:
    """Solve the belief-space OCP from the initial joint trajectory `init`.

    Returns a Solution whatever IPOPT's status; check `success` (the CLI turns a
    failure into an error carrying the status).
    """
    prob = setup.problem
    model = setup.model
    T, nq = prob.horizon, setup.robot.nq
    movable = set(setup.robot.supporting_joints())
    x0 = guess_from_joints(setup, model, init.q)

    # Scales from the initial guess: covariance entries span 1e-2..1e-8.
    scale = np.array([max(x0[f"s{t}"][_DIAG].mean(), 1e-14) for t in range(T + 1)])
    trace_ref = float(trace_vech(x0[f"s{T}"]))

    L = _Layout()
    qs, mus, ss, Ks = [], [], [], []
    for t in range(T + 1):
        qs.append(L.add(f"q{t}", nq))
        mus.append(L.add(f"mu{t}", NX))
        ss.append(L.add(f"s{t}", NV))
        if t < T:
            Ks.append(L.add(f"K{t}", NX * NX))
    w = L.vector()

    pose_fn = setup.camera_pose_fn
    g, lbg, ubg = [], [], []
    for t in range(T + 1):
        g.append(mus[t] - pose_fn(qs[t]))
    for t in range(T):
        s_t = scale[t] * ss[t]
        p = model.predict_expr(mus[t], mus[t + 1], s_t)
        S, H = model.innovation_expr(mus[t], mus[t + 1], p)
        P = unvech(p)
        K = ca.reshape(Ks[t], NX, NX)
        IKH = ca.DM.eye(NX) - K @ H
        post = IKH @ P @ IKH.T + K @ (S - H @ P @ H.T) @ K.T  # Joseph form; S - H P H^T = R V R^T
        g.append(ss[t + 1] - vech(0.5 * (post + post.T)) / scale[t + 1])
    g = ca.vertcat(*g)
    lbg = ubg = np.zeros(g.shape[0])

    f = trace_vech(scale[T] * ss[T]) / trace_ref
    if prob.objective.smoothness > 0:
        f += prob.objective.smoothness * sum(ca.sumsqr(qs[t + 1] - qs[t]) for t in range(T))

    lo, hi = {}, {}
    for t in range(T + 1):
        ql, qh = setup.robot.lower.copy(), setup.robot.upper.copy()
        for j in range(nq):
            if j not in movable or t == 0:
                ql[j] = qh[j] = (setup.q_start[j] if t == 0 or j not in movable else ql[j])
        lo[f"q{t}"], hi[f"q{t}"] = ql, qh
        ml, mh = np.full(NX, -np.inf), np.full(NX, np.inf)
        ml[2] = prob.min_depth
        if t == 0:
            ml = mh = setup.x_start
        if t == T:
            ml = mh = setup.x_goal
        lo[f"mu{t}"], hi[f"mu{t}"] = ml, mh
        if t == 0:
            lo["s0"] = hi["s0"] = x0["s0"] / scale[0]
        else:
            lo[f"s{t}"], hi[f"s{t}"] = np.full(NV, -np.inf), np.full(NV, np.inf)
            lo[f"s{t}"][_DIAG] = 0.0
        if t < T:
            lo[f"K{t}"], hi[f"K{t}"] = np.full(NX * NX, -np.inf), np.full(NX * NX, np.inf)
    x0s = dict(x0)
    for t in range(T + 1):
        x0s[f"s{t}"] = x0[f"s{t}"] / scale[t]

    opts = {
        "ipopt.print_level": prob.solver.print_level,
        "print_time": False,
        "ipopt.sb": "yes",
        "ipopt.tol": prob.solver.tol,
        "ipopt.max_iter": prob.solver.max_iter,
        # Measured on the problems in problems/: the adaptive barrier update needs 2-60x fewer
        # iterations than the monotone default and avoided its restoration failures.
        "ipopt.mu_strategy": "adaptive",
    }
    opts.update({f"ipopt.{k}": v for k, v in prob.solver.options.items()})
    opts.update(solver_options or {})
    nlp = {"x": w, "f": f, "g": g}
    t_build = time.perf_counter()
    solver = ca.nlpsol("surestep_ocp", "ipopt", nlp, opts)
    build_s = time.perf_counter() - t_build
    t0 = time.perf_counter()
    res = solver(x0=L.join(x0s), lbx=L.join(lo), ubx=L.join(hi), lbg=lbg, ubg=ubg)
    solve_s = time.perf_counter() - t0
    stats = solver.stats()

    sol = L.split(np.asarray(res["x"]).ravel())
    q = np.array([sol[f"q{t}"] for t in range(T + 1)])
    poses = np.array([setup.pose_of(qi) for qi in q])  # Pinocchio FK of the solution's joints
    sigma_T = unvech(sol[f"s{T}"] * scale[T])
    return evaluate(
        setup, method, poses, list(q),
        success=bool(stats["success"]), status=str(stats["return_status"]), solve_time_s=solve_s,
        iterations=int(stats["iter_count"]), objective=float(res["f"]) * trace_ref,
        extras={
            "init": init.source,
            "solver": "ipopt",
            "build_time_s": build_s,
            "ocp_trace_final": float(np.trace(sigma_T)),
            "constraint_violation": float(np.max(np.abs(np.asarray(res["g"])))) if g.shape[0] else 0.0,
        },
    )
