"""The condensed, gain-lifted and diagonal transcriptions of the belief-space OCP (IPOPT).

Direct multiple shooting over joints and belief mean. Per node t = 0..T: joints `q_t` and mean
`mu_t` (camera-frame position and unit quaternion, 7 numbers: rotation-valued, no axis-angle chart),
tied by `mu_t = pose_in_camera(FK(q_t))` (`Robot.camera_pose`: the FK quaternion); joint limits, a
minimum depth, `q_0`, `mu_0`, `Sigma_0` fixed and `mu_T = x^G` (hard; the goal's quaternion on the
goal joints' sheet). Objective: `Tr(Sigma_T)` divided by the initial guess's value, plus an optional
joint-step smoothness term. The covariance forms (`solver.covariance`):

* `condensed`: no covariance variables; the EKF recursion is written out in the objective (six
  scalar Kalman updates for a scalar model, the 6x6 recursion otherwise). With the surrogate or
  Gauss-Newton Hessian the derivatives are built stage-wise (`staged_derivatives.py`,
  `stages.py`) and compiled.
* `full` with the exact Hessian: `vech(Sigma_t)` per node and a free gain `K_t` per interval, the
  step in Joseph form, which is smallest at the Kalman gain (no symbolic inverse; any F, Q, H, R).
  The lifted form with the structured Hessian is `lifted.py`.
* `diagonal`: six scalar covariances per node with free scalar gains.

The NLP is parametric in the camera pose (the robot base in the camera frame), the scales and
Sigma_0, so one built solver serves every start, goal and camera pose of a given structure and
horizon (`nlp_cache.transcription` caches it). Measurements: docs/method.md and
docs/hessian_and_newton.md.

With `limits` (a problem's `limits.enforce: true`, `limits.py`) the NLP also carries the motion
limits, each row normalised by its limit (so every bound is 1; `transcription_limits.py`). By
default (`limits.CURVE_ROWS = "curve"`) they bound the curve `surestep export` plays at the
planned times: linear rows on its velocity and acceleration control points, the tool's speeds at
points inside every step. With "steps" (before, kept for measurements): joint velocities
`(q_t+1 - q_t) / (dt v_max)` and accelerations `(q_t+1 - 2 q_t + q_t-1) / (dt^2 a_max)` of the
moving joints, linear, with the plan at rest before q_0 and after q_T (q_-1 = q_0, q_T+1 = q_T: a
plan is a motion from rest to rest, as `limits.py` reports it and `surestep export` runs it); per
interval the tool's squared translation `|p(q_t+1) - p(q_t)|^2 / (v_tool dt)^2` and its rotation
`(3 - tr(R_t^T R_t+1)) / (2 - 2 cos(w_tool dt))` (the angle between the two orientations is at most
`w_tool dt` exactly when this is at most 1), with the frame's FK (no needle offset); and the RCM
distance as a lower bound on the PSM's insertion joint (`limits.rcm_insertion_bound`).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from ..model.belief import DIAG, NM, NV, NX, BeliefModel, unvech, vech
from ..model.joint_noise import joint_noise_function
from ..model.limits import MotionLimits
from ..model.robot import CAMERA_PARAMETERS, Robot
from ..output.solution import Solution
from .plan_evaluation import evaluate
from ..output.solution_records import SolveRecord
from ..problem.setup import Setup
from ..problem.solver_config import HESSIANS
from .codegen import compiled_or_interpreted
from .iterate import InitialGuess, PrimalDual
from .staged_derivatives import staged_derivatives
from .surrogate import pose_function, scalar_trace
from .transcription_limits import add_limit_rows
from ..status import Status


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
        return np.concatenate([np.asarray(values[name], float).ravel()
                               for name, _, _ in self.blocks])


class Transcription:
    """The multiple-shooting NLP of one structure (robot, belief model, horizon, form), built
    once."""

    def __init__(self, robot: Robot, model: BeliefModel, horizon: int, form: str, smoothness: float,
                 options: dict, hessian: str = "exact", codegen: bool = False,
                 codegen_required: bool = False, limits: tuple[float, MotionLimits] | None = None):
        self.robot, self.model, self.T, self.form = robot, model, horizon, form
        self.limits = limits  # (step_s, MotionLimits) enforced as constraints, or None
        self.scalar = form == "condensed" and model.scalar
        T = horizon
        ns = NX if form == "diagonal" else NV
        self.ns = ns
        L = self.layout = _Layout()
        qs, mus, ss, Ks = self._variables()
        # Parameters: robot base in the camera frame (3x4), covariance scales, trace reference.
        Tcb = ca.SX.sym("camera", CAMERA_PARAMETERS)
        scale = ca.SX.sym("scale", T + 1)
        trace_ref = ca.SX.sym("trace_ref")
        sigma0 = ca.SX.sym("sigma0", NV)
        self.p = ca.vertcat(ca.vec(Tcb), scale, trace_ref, sigma0)

        pose = pose_function(robot)
        self.joint_fn = (joint_noise_function(robot, model.noise.joint_sigma) if model.joint_noise
                         else None)
        # W_q, vech
        wq = [self.joint_fn(qs[t], qs[t + 1], Tcb) if self.joint_fn else None for t in range(T)]

        g = [mus[t] - pose(qs[t], Tcb) for t in range(T + 1)]
        if form == "condensed":  # the covariance is shot through the EKF steps inside the objective
            trace_T = self._condensed_trace(mus, sigma0, wq)
        else:
            for t in range(T):
                g.append(self._step(mus[t], mus[t + 1], scale[t] * ss[t], Ks[t], wq[t])
                         / scale[t + 1]
                         - ss[t + 1])
            trace_T = scale[T] * (ca.sum1(ss[T]) if form == "diagonal"
                                  else sum(ss[T][i] for i in DIAG))
        self.poses = pose.map(T + 1)  # (q columns, T_cam_base) -> mean columns, for initial points
        # Tr(Sigma_T) the planner minimises
        self.trace = ca.Function("trace", [L.vector(), self.p], [trace_T])
        f = trace_T / trace_ref
        if smoothness > 0:
            f += smoothness * sum(ca.sumsqr(qs[t + 1] - qs[t]) for t in range(T))
        self.ng_eq = ca.vertcat(*g).shape[0]  # the equality rows; the limit rows (if any) follow
        add_limit_rows(self, L.vector(), qs, g)
        self.ng = ca.vertcat(*g).shape[0]
        self.hessian, self.hess_lag = hessian, None
        # solver_config.resolve rejects these for users: a caller's bug
        if hessian not in HESSIANS or (
                hessian != "exact" and (form != "condensed" or not model.structured)) or (
                hessian == "exact" and codegen):
            raise ValueError(f"no {hessian} Hessian (codegen {codegen}) for the {form} form "
                             "of this model")
        self.codegen, self.codegen_note = codegen, None
        t0 = time.perf_counter()
        if hessian != "exact":
            staged = staged_derivatives(self, pose, sigma0, trace_ref, smoothness)
            # compiled: the derivatives' time per solve several times lower (docs/solve_speed.md)
            if codegen:
                staged, self.codegen_note = compiled_or_interpreted(staged, codegen_required)
                self.codegen = self.codegen_note is None
            self.hess_lag = staged["hess_lag"]
            options = {**options, **staged}
        self.solver = ca.nlpsol("surestep_ocp", "ipopt",
                                {"x": L.vector(), "f": f, "g": ca.vertcat(*g), "p": self.p},
                                options)
        self.build_time_s = time.perf_counter() - t0

    def _variables(self) -> tuple[list, list, list, list]:
        """The decision vector's blocks, node by node: (joints, means, scaled covariances, gains);
        the condensed form has joints and means only."""
        L, T, nq, form = self.layout, self.T, self.robot.nq, self.form
        qs, mus, ss, Ks = [], [], [], []
        for t in range(T + 1):
            qs.append(L.add(f"q{t}", nq))
            mus.append(L.add(f"mu{t}", NM))
            if form == "condensed":
                continue
            ss.append(L.add(f"s{t}", self.ns))
            if t < T:
                Ks.append(L.add(f"K{t}", NX * NX if form == "full" else NX))
        return qs, mus, ss, Ks

    def _condensed_trace(self, mus: list, sigma0: ca.SX, wq: list) -> ca.SX:
        """Tr(Sigma_T) of the condensed form: the EKF recursion written out along the means (six
        scalar Kalman recursions for a scalar model, in Sigma_0's eigenbasis when isotropic)."""
        model, T = self.model, self.T
        # needs the condensed form (solver_config.resolve)
        predicted = model.noise.objective == "predicted"
        if self.scalar:
            return scalar_trace(
                sigma0, [ca.diag(model.motion_noise(mus[t], mus[t + 1])) for t in range(T)],
                [lambda p, t=t: ca.diag(model.planning_noise(mus[t + 1], vech(ca.diag(p))))
                 for t in range(T)],
                predicted)
        s_t = sigma0
        for t in range(T - 1):
            s_t = model.step_expr(mus[t], mus[t + 1], s_t, wq[t])
        last = model.predict_expr if predicted else model.step_expr
        s_t = last(mus[T - 1], mus[T], s_t, wq[T - 1])
        return sum(s_t[i] for i in DIAG)

    def g_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """lbg, ubg: the equalities at 0, every normalised limit row at most 1 (the linear ones at
        least -1)."""
        off = self.A_offset if self.n_lin else np.zeros(0)
        lo = np.concatenate([np.zeros(self.ng_eq), -1.0 - off, np.full(self.n_tool, -np.inf)])
        hi = np.concatenate([np.zeros(self.ng_eq), 1.0 - off, np.ones(self.n_tool)])
        return lo, hi

    def _violation(self, g: np.ndarray) -> float:
        """Largest violation of the constraint rows (the equalities' |g|, the limit rows' excess
        over 1)."""
        lo, hi = self.g_bounds()
        return float(np.max(np.maximum(lo - g, 0) + np.maximum(g - hi, 0))) if len(g) else 0.0

    def _step(self, x0, x1, s, K, w=None):
        m = self.model
        if self.form == "diagonal":
            p = s + ca.diag(m.motion_noise(x0, x1))
            v = ca.diag(m.planning_noise(x1, vech(ca.diag(p))))
            return (1 - K) ** 2 * p + K**2 * v  # scalar Joseph form, gains free (as in `full`)
        p = m.predict_expr(x0, x1, s, w)
        S, H = m.innovation_expr(x0, x1, p)
        P = unvech(p)
        K = ca.reshape(K, NX, NX)
        IKH = ca.DM.eye(NX) - K @ H
        post = IKH @ P @ IKH.T + K @ (S - H @ P @ H.T) @ K.T  # Joseph form; S - H P H^T = R V R^T
        return vech(0.5 * (post + post.T))

    # ------------------------------------------------------------------ one solve
    def guess(self, setup: Setup, q: np.ndarray) -> tuple[dict, np.ndarray]:
        """Consistent primal point (mean, covariance, gains) from a joint trajectory; and the
        scales."""
        model, T = setup.model, self.T  # this setup's Sigma_0 (the cached model may hold another)
        mu = setup.means_of(q)
        sig, pred = model.propagate_means(mu, joint=setup.joint_noises(q))
        out = {}
        for t in range(T + 1):
            out[f"q{t}"], out[f"mu{t}"] = q[t], mu[t]
            out[f"s{t}"] = np.diag(sig[t]) if self.form == "diagonal" else vech(sig[t])
            if t < T and self.form == "diagonal":
                v = np.diag(np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))))
                out[f"K{t}"] = np.diag(pred[t]) / (np.diag(pred[t]) + v)
            elif t < T:
                _, _, H, Rm = (np.asarray(M) for M in model.jacobians(mu[t], mu[t + 1]))
                S = (H @ pred[t] @ H.T + Rm
                     @ np.asarray(model.planning_noise(mu[t + 1], vech(pred[t]))) @ Rm.T)
                out[f"K{t}"] = np.linalg.solve(S, H @ pred[t]).T.ravel(order="F")
        scale = np.array([max(np.trace(s) / NX, 1e-14) for s in sig])
        return out, scale

    def bounds(self, setup: Setup, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prob, T, nq = setup.ocp, self.T, self.robot.nq
        movable = set(self.robot.supporting_joints())
        s0 = np.asarray(prob.noise.Sigma0, float)
        lo, hi = {}, {}
        for t in range(T + 1):
            ql, qh = self.robot.lower.copy(), self.robot.upper.copy()
            for j in range(nq):
                if t == 0 or j not in movable:
                    ql[j] = qh[j] = setup.q_start[j]
                elif self.rcm_bound is not None and j == self.rcm_bound[0]:
                    # the RCM distance (limits)
                    ql[j] = min(max(ql[j], self.rcm_bound[1]), qh[j])
            lo[f"q{t}"], hi[f"q{t}"] = ql, qh
            ml, mh = np.full(NM, -np.inf), np.full(NM, np.inf)
            ml[2] = prob.min_depth
            if t == 0:
                ml = mh = setup.m_start
            if t == T:
                ml = mh = setup.m_goal
            lo[f"mu{t}"], hi[f"mu{t}"] = ml, mh
            if t == 0:
                lo["s0"] = hi["s0"] = (np.diag(s0) if self.form == "diagonal"
                                       else vech(s0)) / scale[0]
            else:
                lo[f"s{t}"], hi[f"s{t}"] = np.full(self.ns, -np.inf), np.full(self.ns, np.inf)
                lo[f"s{t}"][slice(None) if self.form == "diagonal" else DIAG] = 0.0
            if t < T:
                nk = NX * NX if self.form == "full" else NX
                lo[f"K{t}"], hi[f"K{t}"] = np.full(nk, -np.inf), np.full(nk, np.inf)
        return self.layout.join(lo), self.layout.join(hi)

    def _parameters(self, setup: Setup, scale: np.ndarray, trace_ref: float) -> np.ndarray:
        sigma0 = np.asarray(setup.ocp.sigma0, float)
        # the scalar recursions start from their channel variances (the trace is the same)
        s0 = setup.model.recursion_sigma0(sigma0) if self.form == "condensed" else vech(sigma0)
        return np.concatenate([setup.camera_parameter(), scale, [trace_ref], s0])

    def _condensed_start(self, setup: Setup,
                         init: InitialGuess) -> tuple[np.ndarray, np.ndarray, float]:
        """Initial point of the condensed form (joints, and their means by FK), scales, and its
        trace."""
        T, q = self.T, np.asarray(init.q, float)
        mu = np.asarray(self.poses(q.T, setup.camera_parameter())).T
        x0 = self.layout.join({**{f"q{t}": q[t] for t in range(T + 1)},
                               **{f"mu{t}": mu[t] for t in range(T + 1)}})
        scale = np.ones(T + 1)  # unused by this form
        return x0, scale, float(self.trace(x0, self._parameters(setup, scale, 1.0)))

    def start_solution(self, setup: Setup, init: InitialGuess,
                       method: str = "ocp") -> Solution | None:
        """The initial guess itself as a plan, if it is feasible (every bound to 1e-9; the kinematic
        constraints hold by construction in the condensed form); None otherwise."""
        if self.form != "condensed":
            return None
        x0, scale, trace_ref = self._condensed_start(setup, init)
        lbx, ubx = self.bounds(setup, scale)
        violation = float(np.max(np.maximum(lbx - x0, 0) + np.maximum(x0 - ubx, 0)))
        # the motion limits too (the kinematic rows hold by construction)
        if self.limit_g is not None:
            violation = max(violation, self._violation(np.concatenate(
                [np.zeros(self.ng_eq), np.asarray(self.limit_g(x0)).ravel()])))
        if violation > 1e-9:
            return None
        q = np.asarray(init.q, float)
        return evaluate(setup, method, setup.poses_of(q), list(q), success=True,
                        status=Status.INITIAL_GUESS_KEPT, solve_time_s=0.0, iterations=0,
                        objective=trace_ref,
                        run=SolveRecord(solver="ipopt", init=init.source,
                                        covariance_form=self.form,
                                        build_time_s=self.build_time_s, compiled=self.codegen,
                                        initial_trace=trace_ref, ocp_trace_final=trace_ref,
                                        constraint_violation=violation))

    def solve(self, setup: Setup, init: InitialGuess, method: str = "ocp",
              warm: PrimalDual | None = None) -> tuple[Solution, PrimalDual]:
        T = self.T
        # the solve time counts the set-up of the call (initial point, scales, bounds)
        t0 = time.perf_counter()
        # no covariance variables: means and the trace only
        if warm is None and self.form == "condensed":
            x0, scale, trace_ref = self._condensed_start(setup, init)
        elif warm is None:
            x0, scale = self.guess(setup, np.asarray(init.q, float))
            trace_ref = float(np.sum(np.asarray(x0[f"s{T}"])[slice(None) if self.form == "diagonal"
                                                             else DIAG]))
            for t in range(T + 1):
                x0[f"s{t}"] = x0[f"s{t}"] / scale[t]
            x0 = self.layout.join(x0)
        else:
            x0, scale, trace_ref = warm.x, warm.scale, warm.trace_ref
        lbx, ubx = self.bounds(setup, scale)
        p = self._parameters(setup, scale, trace_ref)
        lbg, ubg = self.g_bounds()
        args = dict(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg, p=p)
        if warm is not None:
            args.update(lam_x0=warm.lam_x, lam_g0=warm.lam_g)
        res = self.solver(**args)
        solve_s = time.perf_counter() - t0
        vals = self.layout.split(np.asarray(res["x"]).ravel())
        q = np.array([vals[f"q{t}"] for t in range(T + 1)])
        if self.form == "condensed":
            ocp_trace = float(res["f"]) * trace_ref
        else:
            sT = vals[f"s{T}"] * scale[T]
            ocp_trace = float(np.sum(sT) if self.form == "diagonal" else np.trace(unvech(sT)))
        return ipopt_solution(self, setup, method, init, warm, q, res, solve_s, scale, trace_ref,
                              ocp_trace, self._violation(np.asarray(res["g"]).ravel()), self.form)


def ipopt_solution(tr, setup: Setup, method: str, init, warm, q: np.ndarray, res: dict,
                   solve_s: float, scale: np.ndarray, trace_ref: float, ocp_trace: float,
                   violation: float,
                   form: str) -> tuple[Solution, PrimalDual]:
    """The Solution of one IPOPT solve of transcription `tr` (the exact EKF re-evaluates the plan
    from the Pinocchio FK of its joints), and its primal-dual point as a warm start."""
    stats = tr.solver.stats()
    poses = setup.poses_of(q)
    sol = evaluate(
        setup, method, poses, list(q),
        success=bool(stats["success"]), status=Status.of(stats["return_status"]),
        solve_time_s=solve_s,
        iterations=int(stats["iter_count"]), objective=float(res["f"]) * trace_ref,
        run=SolveRecord(
            solver="ipopt",
            init=init.source if warm is None else f"warm start ({init.source})",
            covariance_form=form,
            build_time_s=tr.build_time_s,
            compiled=tr.codegen,  # derivatives compiled to C (solver.codegen)
            codegen_note=tr.codegen_note or None,
            initial_trace=trace_ref,  # the planner's objective at the (cold) initial guess
            ocp_trace_final=ocp_trace,
            constraint_violation=violation,
        ),
    )
    return sol, PrimalDual(np.asarray(res["x"]).ravel(), np.asarray(res["lam_x"]).ravel(),
                          np.asarray(res["lam_g"]).ravel(), scale, trace_ref)
