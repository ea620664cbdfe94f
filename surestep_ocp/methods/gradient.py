"""The paper's gradient-descent variant: L-BFGS over waypoint differences, clipping action, pose
loss.

As published (SURESTEP, section 5 of the method page):

- decision variables: the differences d_0..d_{T-1} between consecutive pose-space
  waypoints, x_{t+1} = x_t + d_t from x_0 = x_start (the orientation part is added
  in axis-angle coordinates, as the paper does);
- clipping action: the last waypoint x_T is overwritten by the goal x^G, so
  E[x_T] = x^G by construction (d_{T-1} then no longer enters the loss: its gradient
  is zero and it stays at its initial value; the last step x_{T-1} -> x^G can be large);
- loss: Tr(Sigma_T) + w (||p_T - p_{T-1}|| + angle(r_{T-1}, r_T)), w the pose-loss
  weight (paper: 1); "no pose loss" drops the bracket;
- L-BFGS for a fixed number of iterations (paper: 50), tolerances off
  (`gradient.optimizer: scipy`, the default: scipy's L-BFGS-B with `iterations`), or with
  PyTorch's semantics (`gradient.optimizer: torch`, `lbfgs.py`): `steps` outer `step()`
  calls of up to `max_iter` inner iterations each, torch's tolerances, strong Wolfe line
  search; `gradient.preset: paper` is the reading that reproduces the paper's Table I
  (50 `step()` calls, `trace_scale` 1e3; docs/evaluation.md, "Table I").

By default the loss is NOT rescaled (the paper does not say it was): Tr(Sigma_T) is
~1e-5..1e-3 while the pose loss is ~1e-3..1e-1, so the pose loss can dominate;
`gradient.trace_scale` multiplies the trace. The loss terms at start and
end and a `barely_moved` flag are put in the solution's extras so that is visible.
The waypoints carry no reachability guarantee: each is checked by IK afterwards.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import scipy.optimize

from .baseline import reachability
from ..ocp.straight_line import straight_line
from ..solvers.lbfgs import LBFGS
from ..model.belief import NX, trace_vech
from ..model.lie import angle_sq, np_angle, pose_mean, so3_exp
from ..errors import SurestepError
from ..problem.setup import Setup
from ..output.solution import Solution
from ..ocp.plan_evaluation import evaluate
from ..output.solution_records import SolveRecord

# Smooth guards of the two norms in the pose loss: sqrt(a^2 + eps^2) - eps equals |a|
# up to eps/2 relative near 0 and differs from it by < eps everywhere; it is exactly 0 at 0
# and infinitely differentiable, with curvature 1/eps at 0.
EPS_POS = 1e-6  # [m]
EPS_ANG = 1e-6  # [rad]
BARELY_MOVED_M = 1e-3  # [m]  max waypoint position change vs the baseline
BARELY_MOVED_RAD = 1e-2  # [rad] max waypoint orientation change vs the baseline
# the paper's variant optimises pose-space waypoints: it has no joints to take the joint-space
# term's Jacobian at
JOINT_NOISE_UNSUPPORTED = ("noise.joint_motion_sigma: the gradient variant plans waypoints in pose "
                           "space, without the joints the joint-space motion noise needs; run the "
                           "OCP and the baseline (--methods ocp baseline)")
FAR_M = 10.0  # [m] waypoints this far from the camera are not checked by IK (a diverged optimiser)


def _smooth_norm(sq, eps: float):
    return ca.sqrt(sq + eps**2) - eps


def build_loss(setup: Setup, model, pose_loss: bool, weight: float,
               trace_scale: float = 1.0) -> tuple[ca.Function, ca.Function]:
    """The loss `trace_scale Tr(Sigma_T) [+ weight pose loss]` of the stacked differences d (6T),
    CasADi Functions.

    Returns:
        (terms, loss_grad): `terms(d) -> (loss, trace, step_m, step_rad)` where step_m and
        step_rad are the smoothed final step sizes (the pose-loss terms before weighting),
        and `loss_grad(d) -> (loss, dloss/dd)`.
    """
    T = setup.ocp.horizon
    d = ca.SX.sym("d", NX * T)
    x = ca.DM(setup.x_start)
    s = ca.DM(model.sigma0_vech())
    xs = [x]
    for t in range(T):
        x = x + d[NX * t:NX * (t + 1)]
        xs.append(x)
    xs[T] = ca.DM(setup.x_goal)  # the clipping action
    # the belief's means of the pose-space waypoints (the paper's decision space)
    ms = [pose_mean(x) for x in xs]
    for t in range(T - 1):
        s = model.step(ms[t], ms[t + 1], s)
    if model.noise.objective == "predicted":  # Sigma_T|T-1: before the last observation
        s = model.predict(ms[T - 1], ms[T], s)
    else:
        s = model.step(ms[T - 1], ms[T], s)
    trace = trace_vech(s)
    dp = xs[T][:3] - xs[T - 1][:3]
    step_m = _smooth_norm(ca.dot(dp, dp), EPS_POS)
    step_rad = _smooth_norm(angle_sq(so3_exp(xs[T - 1][3:]), so3_exp(xs[T][3:])), EPS_ANG)
    loss = trace_scale * trace + weight * (step_m + step_rad) if pose_loss else trace_scale * trace
    terms = ca.Function("gradient_loss_terms", [d], [loss, trace, step_m, step_rad],
                        ["d"], ["loss", "trace", "step_m", "step_rad"])
    loss_grad = ca.Function("gradient_loss_grad", [d], [loss, ca.gradient(loss, d)], ["d"],
                            ["loss", "grad"])
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
        setup: the problem; `setup.ocp.gradient` gives iterations, memory and the
            pose-loss weight.
        pose_loss: include w (||p_T - p_{T-1}|| + angle(r_{T-1}, r_T)) in the loss.
        components: observation components used in optimisation (default
            `setup.model.components`); evaluation always uses all of them.
        init_poses: (T+1, 6) initial waypoints (its first row is replaced by x_start);
            default the straight-line baseline.

    Returns:
        The evaluated Solution, method "gradient" or "gradient-no-pose-loss".
    """
    prob = setup.ocp
    if setup.model.joint_noise:
        raise SurestepError(JOINT_NOISE_UNSUPPORTED)
    spec = prob.gradient
    T = prob.horizon
    components = tuple(setup.model.components if components is None else components)
    model = (setup.model if components == tuple(setup.model.components)
             else setup.model.with_components(components))
    base, d0 = _start(setup, init_poses)

    t_build = time.perf_counter()
    terms, loss_grad = build_loss(setup, model, pose_loss, spec.pose_loss_weight, spec.trace_scale)
    build_s = time.perf_counter() - t_build

    def fun(z):
        f, g = loss_grad(z)
        return float(f), np.asarray(g, dtype=float).ravel()

    t0 = time.perf_counter()
    if spec.optimizer == "torch":
        run = _run_torch(fun, d0, spec)
    else:
        run = _run_scipy(fun, d0, spec)
    solve_s = time.perf_counter() - t0
    d_opt, nit = run["x"], run["iterations"]

    start, end = _terms_dict(terms, d0), _terms_dict(terms, d_opt)
    poses = poses_of(setup, d_opt)
    finite, success, status = _verdict(run, start, end, poses)

    dpos, dang = _change_vs_baseline(poses, base)
    t_ik = time.perf_counter()
    qs, info = _reachability(setup, poses, finite)
    ik_s = time.perf_counter() - t_ik
    method = "gradient" if pose_loss else "gradient-no-pose-loss"
    extras = {
        **run["extras"],
        "function_evaluations": run["evaluations"],
        "pose_loss": bool(pose_loss),
        "pose_loss_weight": float(spec.pose_loss_weight),
        "trace_scale": float(spec.trace_scale),
        "preset": spec.preset or None,
        "components": list(components),
        "loss_start": start,
        "loss_end": end,
        "final_step_m": float(np.linalg.norm(poses[T, :3] - poses[T - 1, :3])),
        "final_step_rad": np_angle(poses[T - 1, 3:], poses[T, 3:]),
        "max_change_vs_baseline_m": dpos,
        "max_change_vs_baseline_rad": dang,
        "barely_moved": bool(dpos < BARELY_MOVED_M and dang < BARELY_MOVED_RAD),
        "ik_time_s": ik_s,
        "reachability": info,
    }
    return evaluate(
        setup, method, poses, qs,
        success=success, status=status, solve_time_s=solve_s, iterations=nit,
        objective=end["loss"], components=components, extras=extras,
        run=SolveRecord(init="straight-line baseline" if init_poses is None else "init_poses",
                        build_time_s=build_s),
    )


def _start(setup: Setup, init_poses: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(the straight-line baseline, the initial waypoint differences d0): from `init_poses` (its
    first row replaced by x_start), else from the baseline."""
    T = setup.ocp.horizon
    base = straight_line(setup.x_start, setup.x_goal, T)
    init = base if init_poses is None else np.array(init_poses, dtype=float)
    if init.shape != (T + 1, NX):
        raise ValueError(f"init_poses must have shape ({T + 1}, {NX}), got {init.shape}")
    init[0] = setup.x_start
    return base, np.diff(init, axis=0).ravel()


def _change_vs_baseline(poses: np.ndarray, base: np.ndarray) -> tuple[float, float]:
    """The waypoints' largest change from the straight-line baseline: position [m], angle [rad]."""
    dpos = float(np.max(np.linalg.norm(poses[:, :3] - base[:, :3], axis=1)))
    dang = float(max(np_angle(a, b) for a, b in zip(poses[:, 3:], base[:, 3:])))
    return dpos, dang


def _verdict(run: dict, start: dict, end: dict, poses: np.ndarray) -> tuple[bool, bool, str]:
    """(finite, success, status) of an optimiser's run from its loss terms at start and end and
    its waypoints."""
    # scipy's status: 0 converged, 1 iteration/evaluation limit (the normal stop here),
    # 2 stopped otherwise (e.g. ABNORMAL line search: no further decrease found).
    finite = bool(np.isfinite(end["loss"]) and np.all(np.isfinite(poses)))
    success = finite and run["error"] is None and run["ok"] and end["loss"] <= start["loss"]
    status = (run["status"] if finite
              else f"{run['status']}; diverged (non-finite loss or waypoints)")
    if finite and end["loss"] > start["loss"]:
        status += f"; the loss rose from {start['loss']:.3g} to {end['loss']:.3g}"
    return finite, success, status


def _reachability(setup: Setup, poses: np.ndarray, finite: bool) -> tuple[list, dict]:
    """(joints of each waypoint or None, the reachability record): the waypoints checked by IK,
    unless the run diverged."""
    if finite and np.max(np.abs(poses[:, :3])) < FAR_M:
        return reachability(setup, poses)
    # a diverged run (e.g. torch's fixed step without line search): no IK on absurd waypoints
    far = ~np.all(np.isfinite(poses), axis=1) | (np.max(np.abs(poses[:, :3]), axis=1) >= FAR_M)
    qs = [None] * len(poses)
    info = {"reachable": 0, "unreachable": len(poses), "ik_residual_m": [],
            "ik_residual_rad": [],
            "note": f"not checked: {int(far.sum())} waypoints non-finite or beyond {FAR_M:g} m"}
    return qs, info


def _run_scipy(fun, d0: np.ndarray, spec) -> dict:
    """scipy's L-BFGS-B for `spec.iterations` iterations, tolerances off."""
    try:
        res = scipy.optimize.minimize(
            fun, d0, jac=True, method="L-BFGS-B",
            options={"maxiter": spec.iterations, "maxcor": spec.memory, "gtol": 0.0, "ftol": 0.0},
        )
    except (RuntimeError, ValueError, FloatingPointError) as exc:  # NaN from CasADi, etc.
        error = f"{type(exc).__name__}: {exc}"
        return {"x": d0, "iterations": 0, "evaluations": 0, "error": error, "ok": False,
                "status": error,
                "extras": {"optimiser": "scipy L-BFGS-B", "scipy_message": error,
                           "scipy_status": -1, "iterations_requested": spec.iterations,
                           "memory": spec.memory}}
    nit, code = int(res.nit), int(res.status)
    # scipy's status: 0 converged, 1 iteration/evaluation limit (the normal stop here),
    # 2 stopped otherwise (e.g. ABNORMAL line search: no further decrease found): not a success,
    # whatever the loss (it said success with the iterations left undone before issue 48)
    if code == 1 and nit >= spec.iterations:
        status = f"completed {nit} iterations"
    else:
        status = f"stopped after {nit} of {spec.iterations} iterations: {res.message}"
    return {"x": res.x, "iterations": nit, "evaluations": int(res.nfev), "error": None,
            "ok": code in (0, 1), "status": status,
            "extras": {"optimiser": "scipy L-BFGS-B", "scipy_message": str(res.message),
                       "scipy_status": code, "iterations_requested": spec.iterations,
                       "memory": spec.memory}}


def _run_torch(fun, d0: np.ndarray, spec) -> dict:
    """`spec.steps` step() calls of torch.optim.LBFGS's algorithm (`lbfgs.LBFGS`); stops early on a
    non-finite loss."""
    opt = LBFGS(d0, lr=spec.lr, max_iter=spec.max_iter, max_eval=spec.max_eval,
                tolerance_grad=spec.tolerance_grad, tolerance_change=spec.tolerance_change,
                history_size=spec.history_size,
                line_search=spec.line_search)
    error = None
    done = 0
    with np.errstate(all="ignore"):
        try:
            for _ in range(spec.steps):
                opt.step(fun)
                done += 1
                if not np.all(np.isfinite(opt.x)) or not np.isfinite(opt.steps[-1].loss_after):
                    error = f"non-finite loss after step() {done}"
                    break
        except (RuntimeError, ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            error = f"{type(exc).__name__}: {exc}"
    stops: dict[str, int] = {}
    for st in opt.steps:
        stops[st.stop] = stops.get(st.stop, 0) + 1
    if error is None:
        status = f"completed {done} steps ({opt.n_iter} inner iterations)"
    else:
        status = (f"stopped after {done} of {spec.steps} steps ({opt.n_iter} inner "
                  f"iterations): {error}")
    return {"x": opt.x, "iterations": opt.n_iter, "evaluations": opt.func_evals, "error": error,
            "ok": error is None, "status": status,
            "extras": {"optimiser": "torch-semantics L-BFGS (lbfgs.py, line search "
                                    f"{spec.line_search})",
                       "steps_requested": spec.steps, "steps_done": done, "max_iter": spec.max_iter,
                       "max_eval": opt.max_eval, "history_size": spec.history_size, "lr": spec.lr,
                       "tolerance_grad": spec.tolerance_grad,
                       "tolerance_change": spec.tolerance_change, "inner_iterations": opt.n_iter,
                       "step_stops": stops}}
