"""The paper's gradient-descent variant: L-BFGS over waypoint differences, clipping action, pose loss.

As published (SURESTEP, section 5 of the method page):

- decision variables: the differences d_0..d_{T-1} between consecutive pose-space
  waypoints, x_{t+1} = x_t + d_t from x_0 = x_start (the orientation part is added
  in axis-angle coordinates, as the paper does);
- clipping action: the last waypoint x_T is overwritten by the goal x^G, so
  E[x_T] = x^G by construction (d_{T-1} then no longer enters the loss: its gradient
  is zero and it stays at its initial value; the last step x_{T-1} -> x^G can be large);
- loss: Tr(Sigma_T) + w (||p_T - p_{T-1}|| + angle(r_{T-1}, r_T)), w the pose-loss
  weight (paper: 1); "no pose loss" drops the bracket;
- L-BFGS for a fixed number of iterations (paper: 50), tolerances off.

The loss is NOT rescaled (the paper did not): Tr(Sigma_T) is ~1e-5..1e-3 while the
pose loss is ~1e-3..1e-1, so the pose loss can dominate. The loss terms at start and
end and a `barely_moved` flag are put in the solution's extras so that is visible.
The waypoints carry no reachability guarantee: each is checked by IK afterwards.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import scipy.optimize

from .baseline import reachability, straight_line
from .belief import NX, trace_vech
from .lie import angle_sq, np_angle, so3_exp
from .setup import Setup
from .solution import Solution, evaluate

# Smooth guards of the two norms in the pose loss: sqrt(a^2 + eps^2) - eps equals |a|
# up to eps/2 relative near 0 and differs from it by < eps everywhere; it is exactly 0 at 0
# and infinitely differentiable, with curvature 1/eps at 0.
EPS_POS = 1e-6  # [m]
EPS_ANG = 1e-6  # [rad]
BARELY_MOVED_M = 1e-3  # [m]  max waypoint position change vs the baseline
BARELY_MOVED_RAD = 1e-2  # [rad] max waypoint orientation change vs the baseline


def _smooth_norm(sq, eps: float):
    return ca.sqrt(sq + eps**2) - eps


def build_loss(setup: Setup, model, pose_loss: bool, weight: float) -> tuple[ca.Function, ca.Function]:
    """The loss of the stacked differences d (6T) as CasADi Functions.

    Returns:
        (terms, loss_grad): `terms(d) -> (loss, trace, step_m, step_rad)` where step_m and
        step_rad are the smoothed final step sizes (the pose-loss terms before weighting),
        and `loss_grad(d) -> (loss, dloss/dd)`.
    """
    T = setup.problem.horizon
    d = ca.SX.sym("d", NX * T)
    x = ca.DM(setup.x_start)
    s = ca.DM(model.sigma0_vech())
    xs = [x]
    for t in range(T):
        x = x + d[NX * t:NX * (t + 1)]
        xs.append(x)
    xs[T] = ca.DM(setup.x_goal)  # the clipping action
    for t in range(T - 1):
        s = model.step(xs[t], xs[t + 1], s)
    if model.noise.objective == "predicted":  # Sigma_T|T-1: before the last observation
        s = model.predict(xs[T - 1], xs[T], s)
    else:
        s = model.step(xs[T - 1], xs[T], s)
    trace = trace_vech(s)
    dp = xs[T][:3] - xs[T - 1][:3]
    step_m = _smooth_norm(ca.dot(dp, dp), EPS_POS)
    step_rad = _smooth_norm(angle_sq(so3_exp(xs[T - 1][3:]), so3_exp(xs[T][3:])), EPS_ANG)
    loss = trace + weight * (step_m + step_rad) if pose_loss else trace
    terms = ca.Function("gradient_loss_terms", [d], [loss, trace, step_m, step_rad],
                        ["d"], ["loss", "trace", "step_m", "step_rad"])
    loss_grad = ca.Function("gradient_loss_grad", [d], [loss, ca.gradient(loss, d)], ["d"], ["loss", "grad"])
    return terms, loss_grad


def poses_of(setup: Setup, d: np.ndarray) -> np.ndarray:
    """(T+1, 6) waypoints of the differences `d` (T, 6) with the clipping action applied."""
    d = np.asarray(d, float).reshape(-1, NX)
    poses = setup.x_start + np.vstack([np.zeros(NX), np.cumsum(d, axis=0)])
    poses[-1] = setup.x_goal
    return poses


def _terms_dict(terms: ca.Function, d: np.ndarray) -> dict:
    loss, tr, sm, sr = (float(v) for v in terms(d))
    return {"loss": loss, "trace": tr, "step_m": sm, "step_rad": sr}


def solve_gradient(
    setup: Setup,
    pose_loss: bool = True,
    components: tuple[str, ...] | None = None,
    init_poses: np.ndarray | None = None,
) -> Solution:
    """The paper's gradient-descent variant (L-BFGS-B, fixed number of iterations).

    Args:
        setup: the problem; `setup.problem.gradient` gives iterations, memory and the
            pose-loss weight.
        pose_loss: include w (||p_T - p_{T-1}|| + angle(r_{T-1}, r_T)) in the loss.
        components: observation components used in optimisation (default
            `setup.model.components`); evaluation always uses all of them.
        init_poses: (T+1, 6) initial waypoints (its first row is replaced by x_start);
            default the straight-line baseline.

    Returns:
        The evaluated Solution, method "gradient" or "gradient-no-pose-loss".
    """
    prob = setup.problem
    spec = prob.gradient
    T = prob.horizon
    components = tuple(setup.model.components if components is None else components)
    model = setup.model if components == tuple(setup.model.components) else setup.model.with_components(components)

    base = straight_line(setup.x_start, setup.x_goal, T)
    init = base if init_poses is None else np.array(init_poses, dtype=float)
    if init.shape != (T + 1, NX):
        raise ValueError(f"init_poses must have shape ({T + 1}, {NX}), got {init.shape}")
    init[0] = setup.x_start
    d0 = np.diff(init, axis=0).ravel()

    t_build = time.perf_counter()
    terms, loss_grad = build_loss(setup, model, pose_loss, spec.pose_loss_weight)
    build_s = time.perf_counter() - t_build

    def fun(z):
        f, g = loss_grad(z)
        return float(f), np.asarray(g, dtype=float).ravel()

    t0 = time.perf_counter()
    error = None
    try:
        res = scipy.optimize.minimize(
            fun, d0, jac=True, method="L-BFGS-B",
            options={"maxiter": spec.iterations, "maxcor": spec.memory, "gtol": 0.0, "ftol": 0.0},
        )
        d_opt, nit, message, status_code = res.x, int(res.nit), str(res.message), int(res.status)
    except (RuntimeError, ValueError, FloatingPointError) as exc:  # NaN from CasADi, etc.
        error = f"{type(exc).__name__}: {exc}"
        d_opt, nit, message, status_code = d0, 0, error, -1
    solve_s = time.perf_counter() - t0

    start, end = _terms_dict(terms, d0), _terms_dict(terms, d_opt)
    poses = poses_of(setup, d_opt)
    # scipy's status: 0 converged, 1 iteration/evaluation limit (the normal stop here),
    # 2 stopped otherwise (e.g. ABNORMAL line search: no further decrease found).
    finite = bool(np.isfinite(end["loss"]) and np.all(np.isfinite(poses)))
    success = finite and error is None and status_code in (0, 1, 2) and end["loss"] <= start["loss"]
    if status_code == 1 and nit >= spec.iterations:
        status = f"completed {nit} iterations"
    else:
        status = f"stopped after {nit} of {spec.iterations} iterations: {message}"

    dpos = float(np.max(np.linalg.norm(poses[:, :3] - base[:, :3], axis=1)))
    dang = float(max(np_angle(a, b) for a, b in zip(poses[:, 3:], base[:, 3:])))
    t_ik = time.perf_counter()
    qs, info = reachability(setup, poses)
    ik_s = time.perf_counter() - t_ik
    method = "gradient" if pose_loss else "gradient-no-pose-loss"
    extras = {
        "optimiser": "scipy L-BFGS-B",
        "scipy_message": message,
        "scipy_status": status_code,
        "iterations_requested": spec.iterations,
        "memory": spec.memory,
        "function_evaluations": int(res.nfev) if error is None else 0,
        "pose_loss": bool(pose_loss),
        "pose_loss_weight": float(spec.pose_loss_weight),
        "components": list(components),
        "init": "straight-line baseline" if init_poses is None else "init_poses",
        "loss_start": start,
        "loss_end": end,
        "final_step_m": float(np.linalg.norm(poses[T, :3] - poses[T - 1, :3])),
        "final_step_rad": np_angle(poses[T - 1, 3:], poses[T, 3:]),
        "max_change_vs_baseline_m": dpos,
        "max_change_vs_baseline_rad": dang,
        "barely_moved": bool(dpos < BARELY_MOVED_M and dang < BARELY_MOVED_RAD),
        "build_time_s": build_s,
        "ik_time_s": ik_s,
        "reachability": info,
    }
    return evaluate(
        setup, method, poses, qs,
        success=success, status=status, solve_time_s=solve_s, iterations=nit,
        objective=end["loss"], components=components, extras=extras,
    )
