"""The camera registered to the tracker's estimate, and the goal's joints as that camera sees it.

A re-plan within the limits starts where the tracker says the tool is: the camera pose is corrected
so that the kinematics at the executed joints q0 show the tool at the tracker's mean M (the
correction takes the tool's offset from its kinematics for a camera error). The goal, a pose in the
camera frame, then has joints by IK. Near a joint limit a mean a few millimetres off can put those
joints beyond it: the goal is then out of reach under the tracker's registration.

The goal is within reach by the task's own terms (the needle is held where the arm can grasp it), so
the estimate to register is the most probable one under the tracker's belief N(M, Sigma) that keeps
it within reach: Kalman filtering with an inequality constraint by projection of the estimate in
the metric Sigma^-1 (Simon and Simon, IET Control Theory Appl. 2010, "Constrained Kalman filtering
via density function truncation", its projection method). With the goal's joints q_g within the
limits, the estimate that puts the goal there is closed-form, m(q_g) = A B(q_g)^-1 B0 (A the goal,
B(q) the tool's pose at q, B0 at q0, camera frame), so the projection is a bounded least-squares
problem over q_g: minimise |L^-1 e(m(q_g), M)|^2, Sigma = L L^T, e = (p_m - p_M, log(R_m R_M^T))
(the tracker's error coordinates, rollout.py). Its minimum d2 is the squared Mahalanobis distance
the constraint moves the estimate (`Registration.constrained`).

The constrained registration is used whatever d2 is: holding the current plan's registration (what
re-plans did before) is itself one estimate whose goal is within reach, the one the descent starts
from (the current goal's joints), so the projection ends at least as near the tracker's belief. A
d2 beyond GATE (the chi-square 99 % quantile, 6 degrees of freedom) says the belief puts the goal
out of reach: such re-plans are counted apart (`beyond_gate`). The current registration holds
(`Registration.held`) only where no projection is made (a covariance Cholesky cannot factor).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from ..model.lie import pose_to_matrix, so3_log
from ..problem.setup import Setup

# the chi-square distribution's 99 % quantile with 6 degrees of freedom (scipy.stats.chi2.ppf(0.99,
# 6)): a constrained estimate farther than this from the tracker's is one its belief rules out (the
# goal beyond reach by the belief: counted apart)
GATE = 16.811893829770927
# the projection keeps the goal's joints this far inside each limit (a fraction of the joint's
# range: 0.24 mm of the PSM's insertion): the re-plan's interior point keeps its rows strictly
# inside, and a goal nearer the limit made its full re-plans slower (Type 1 easy, 20 rollouts: with
# 1e-4 two of 824 re-plans failed and the slowest constrained one took 45 ms; with 1e-3 none, 37 ms)
MARGIN = 1e-3
# a goal within reach: its IK residual at most these (the Planner's test) [m], [rad]
REACH_M, REACH_RAD = 1e-6, 1e-5


@dataclass(frozen=True)
class Registration:
    """A re-plan's camera registration: `setup` (the problem seen from the registered camera),
    the goal's joints `q_goal` and whether they reach it; `unreached`, the tracker's registration's
    goal IK residual ({"m", "rad"}) when it did not reach; then either `constrained` (the squared
    Mahalanobis distance to the nearest registration that reaches it, used) or `held` (the current
    plan's registration used)."""

    @property
    def beyond_gate(self) -> bool:
        """The constrained estimate is one the tracker's belief rules out (d2 > GATE)."""
        return self.constrained is not None and self.constrained > GATE

    setup: Setup
    q_goal: np.ndarray
    reachable: bool
    unreached: dict | None = None
    constrained: float | None = None
    held: bool = False


def registered_to(base: Setup, q0: np.ndarray, M: np.ndarray) -> Setup:
    """`base` seen from the camera corrected so that the kinematics at q0 show the tool at M (a
    camera-frame pose, 4x4)."""
    world_tool = base.camera_pose @ pose_to_matrix(base.pose_of(q0))
    return replace(base, camera_pose=world_tool @ np.linalg.inv(M))


def register(base: Setup, q0: np.ndarray, mean: np.ndarray, cov: np.ndarray, current: np.ndarray,
             q_previous: np.ndarray) -> Registration:
    """The registration of a re-plan from joints q0 with the tracker's (mean, cov) (module
    docstring). `current` is the current plan's registration (a correction of `base.camera_pose`,
    4x4), `q_previous` its goal joints (where the IK starts: the goal moves little per frame)."""
    M = pose_to_matrix(mean)
    registered = registered_to(base, q0, M)
    q_goal = _newton_goal(registered, np.vstack([q_previous, base.q_goal]))
    if q_goal is not None:
        return Registration(registered, q_goal, True)
    # Newton left the limits: the nearest estimate whose goal is within them (the IK itself, at
    # distance 0, where the goal is within reach after all)
    q_near, m, d2 = nearest_reaching(base, q0, M, cov, q_previous)
    res_m, res_rad = _goal_error(registered, q_near)
    if _reaches(res_m, res_rad):
        return Registration(registered, q_near, True)
    unreached = {"m": res_m, "rad": res_rad}
    if np.isfinite(d2):
        return Registration(registered_to(base, q0, m), q_near, True, unreached, constrained=d2)
    held = replace(base, camera_pose=base.camera_pose @ current)
    for start in (q_previous, base.q_goal):
        q_goal, res_m, res_rad = held.joints_for(base.x_goal, start, raise_on_fail=False,
                                                 restarts=0)
        if _reaches(res_m, res_rad):
            break
    return Registration(held, q_goal, _reaches(res_m, res_rad), unreached, held=True)


def _newton_goal(registered: Setup, starts: np.ndarray) -> np.ndarray | None:
    """The goal's joints by plain Newton steps from the first of `starts` that converges within
    the limits (`Robot.newton_batch`, one start at a time: the first, the current goal's joints,
    converges in a few steps where the goal moved little), or None."""
    target = np.linalg.inv(registered.T_cam_base) @ pose_to_matrix(registered.x_goal)
    for start in starts:
        q, done, _ = registered.robot.newton_batch(target[None], start[None])
        if done[0]:
            return q[0]
    return None


def _goal_error(registered: Setup, q: np.ndarray) -> tuple[float, float]:
    """Distance [m] and angle [rad] from the goal to the tool at joints q, as `registered` sees
    it."""
    x = registered.pose_of(q)
    R = Rotation.from_rotvec(x[3:]) * Rotation.from_rotvec(registered.x_goal[3:]).inv()
    return float(np.linalg.norm(x[:3] - registered.x_goal[:3])), float(R.magnitude())


def _reaches(res_m: float, res_rad: float) -> bool:
    return res_m <= REACH_M and res_rad <= REACH_RAD


def nearest_reaching(base: Setup, q0: np.ndarray, M: np.ndarray, cov: np.ndarray,
                     q_guess: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(goal joints within the limits less MARGIN, the estimate (4x4, camera frame) that puts the
    goal there, its squared Mahalanobis distance from the tracker's mean M (4x4) under `cov`): the
    module docstring's bounded least squares, from `q_guess` pushed inside the limits (the current
    plan's goal joints: the nearest branch)."""
    robot = base.robot
    mov = np.array(robot.supporting_joints())
    lo, hi = robot.lower[mov], robot.upper[mov]
    span = np.where(np.isfinite(hi - lo), hi - lo, 2 * np.pi)
    lo, hi = lo + MARGIN * span, hi - MARGIN * span
    try:
        L_inv = np.linalg.inv(np.linalg.cholesky(0.5 * (cov + cov.T)))
    except np.linalg.LinAlgError:  # positive definite, but too ill-conditioned to factor
        return np.array(q_guess, float), M, np.inf
    # the goal (camera frame) and the tool at q0 (URDF root)
    A = pose_to_matrix(base.x_goal)
    F0 = np.linalg.inv(base.T_cam_base) @ pose_to_matrix(base.pose_of(q0))
    fn = _projection_function(base.robot)
    q = np.array(q_guess, float)

    def full(x):
        out = q.copy()
        out[mov] = x
        return out

    def fun(x):
        r, J, m = fn(full(x), A, F0, M, L_inv)
        return np.asarray(r).ravel(), np.asarray(J)[:, mov], m

    x, r, m = bounded_gauss_newton(fun, np.clip(q[mov], lo, hi), lo, hi)
    return full(x), np.asarray(m), float(r @ r)


def bounded_gauss_newton(fun, x, lo, hi, iterations: int = 50, tol: float = 1e-10):
    """min |r(x)|^2 over the box lo <= x <= hi, `fun(x) -> (r, dr/dx, extra)`: Gauss-Newton steps
    on the variables not held at a bound (at it, the gradient pushing outward), projected onto the
    box, halved until |r|^2 falls (Armijo); ends when a step moves no variable by more than `tol`
    or |r|^2 stops falling. Returns (x, r, extra) at the end (a few variables: the registration's
    six joints; its check against SciPy's trust-region method is in the tests)."""
    r, J, extra = fun(x)
    cost = r @ r
    for _ in range(iterations):
        g = J.T @ r
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        d = np.zeros_like(x)
        d[free] = -np.linalg.lstsq(J[:, free], r, rcond=None)[0]
        step, done = 1.0, True
        while step > 1e-8:
            x_new = np.clip(x + step * d, lo, hi)
            r_new, J_new, extra_new = fun(x_new)
            c_new = r_new @ r_new
            if c_new <= cost + 2e-4 * (g @ (x_new - x)):  # (the gradient of |r|^2 is 2 g)
                done = np.max(np.abs(x_new - x)) <= tol or cost - c_new <= tol * tol * (1 + cost)
                x, r, J, extra, cost = x_new, r_new, J_new, extra_new, c_new
                break
            step *= 0.5
        if done:
            break
    return x, r, extra


def _projection_function(robot) -> ca.Function:
    """`project(q, A, F0, M, L_inv) -> (r, dr/dq, m)`: the estimate m(q) = A F(q)^-1 F0 (4x4) that
    puts the goal A (camera frame) at joints q (F: the tool's pose in the URDF root, F0 = F(q0); the
    module docstring's A B(q)^-1 B0, the camera's transform cancelled), and the
    residual r = L_inv e(m, M) from the tracker's mean M; built once per robot."""
    known = robot.__dict__.setdefault("_registration_fns", {})
    if "project" not in known:
        q = ca.SX.sym("q", robot.nq)
        A, F0, M = ca.SX.sym("A", 4, 4), ca.SX.sym("F0", 4, 4), ca.SX.sym("M", 4, 4)
        L_inv = ca.SX.sym("L_inv", 6, 6)
        F = robot.fk_expr(q)
        R, p = F[:3, :3], F[:3, 3]
        F_inv = ca.vertcat(ca.horzcat(R.T, -R.T @ p), ca.DM([[0, 0, 0, 1]]))
        m = A @ F_inv @ F0
        e = ca.vertcat(m[:3, 3] - M[:3, 3], so3_log(m[:3, :3] @ M[:3, :3].T))
        r = L_inv @ e
        known["project"] = ca.Function("registration_project", [q, A, F0, M, L_inv],
                                       [r, ca.jacobian(r, q), m])
    return known["project"]
