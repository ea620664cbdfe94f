"""Noisy closed-loop rollouts of a planned trajectory (method page, section 7).

A plan is its waypoints `x_0..x_T` (camera frame, `x = (p, r)`, axis-angle `r`).
N rollouts of one plan run together as arrays (a loop over time steps only).
Per step t -> t+1, for every rollout:

1. command: the step from the current estimate `mu_t` to the waypoint `x_t+1`,
   `dp = p_t+1 - p_mu`, `D = R_mu^T R_t+1` (a body-frame rotation step);
2. motion: `p_true += dp + w_p`, `R_true <- exp(w_r) R_true D`, with
   `w ~ N(0, W(mu_t, x_t+1))` (W of the commanded step);
3. observation: `p_z = p_true + v_p`, `R_z = exp(v_r) R_true`, all components always,
   with `v ~ N(0, V(mu_t+1|t))` in mode `model` or `v ~ N(0, V(x_true))` in mode `true`;
   with a `Detection` (the evaluation's default), only when the true pose is detectable:
   in front of the lens beyond `min_depth` and projecting inside the image with
   `margin` to spare, optionally with a probability falling linearly from 1 to 0 over
   the `falloff` band next to that border; an undetected step is a prediction only
   (`mu = mu^-`, `Sigma = P`), in both modes;
4. EKF (its own model, F = Q = H = R = I): predicted mean `mu^- = mu_t (+) command`
   (which is the waypoint itself), `P = Sigma + W`, `S = P + V(mu^-)`,
   innovation `y = (p_z - p^-, log(R_z R^-^T))`, `mu+ = (p^- + K y_p, exp(K y_r) R^-)`,
   `Sigma+ = sym(P S^-1 V)` (`= P - P S^-1 P` without its cancellation; as `BeliefModel.step`).

Pose arithmetic: positions add; rotations compose, and the orientation part of every
error (noise, innovation, estimate error) is the axis-angle vector of a *left*
(camera-frame) perturbation, `R_a = exp(e) R_b`. In those error coordinates the
commanded step leaves the error unchanged and noises add to first order, so the
EKF's identity maps are exact for positions and first-order exact for orientations
(the noises here are milliradians). `final_error` uses the same coordinates,
`(p_true - p_mu, log(R_true R_mu^T))`, so its covariance is comparable with Sigma_T.

The noise models are the belief model's own CasADi Functions (`motion_noise`,
`observation_noise`) evaluated on all rollouts at once with `Function.map(N)`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import SurestepError
from ..model.belief import _TRIL, NM, NX, BeliefModel
from ..model.detection import Detection  # noqa: F401 (re-exported: its home before)
from .grasp_rule import GraspRule, Grasping
from ..model.lie import np_means

MODES = ("model", "true")
METRICS = ("pos_err_mean", "pos_err_std", "ori_err_mean", "ori_err_std", "trace_noisy", "trace_ml",
           "entropy_noisy", "entropy_ml")
_ENTROPY_CONST = 0.5 * NX * (1 + np.log(2 * np.pi))


@dataclass
class Rollouts:
    """N noisy rollouts of one plan; arrays are indexed by rollout first."""

    mode: str
    goal: np.ndarray  # (6,) the goal x^G
    final_true: np.ndarray  # (N, 6) true pose at T, (p, axis-angle)
    final_estimate: np.ndarray  # (N, 6) EKF mean at T
    final_error: np.ndarray  # (N, 6) (p_true - p_mu, log(R_true R_mu^T)) at T
    sigma_final: np.ndarray  # (N, 6, 6) EKF posterior covariance at T
    pos_err: np.ndarray  # (N,) ||p_T^true - p^G|| [m]
    ori_err: np.ndarray  # (N,) angle(R_T^true, R^G) [rad], geodesic
    true_path: np.ndarray | None = None  # (N, T+1, 6) when kept
    estimate_path: np.ndarray | None = None  # (N, T+1, 6) when kept
    detected: np.ndarray | None = None  # (N, T) whether step t -> t+1 had an observation
    # with a grasp rule (`grasp_rule.py`): the steps each rollout ran until it grasped, its
    # predicted success then, and whether the cap made it grasp
    grasp_step: np.ndarray | None = None
    predicted: np.ndarray | None = None
    capped: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.pos_err)

    @property
    def trace(self) -> np.ndarray:
        """(N,) Tr(Sigma_T) of each rollout's EKF."""
        return np.trace(self.sigma_final, axis1=1, axis2=2)

    @property
    def entropy(self) -> np.ndarray:
        """(N,) Gaussian entropy [nats] of each rollout's Sigma_T (-inf if not positive
        definite)."""
        sign, logdet = np.linalg.slogdet(self.sigma_final)
        return np.where(sign > 0, _ENTROPY_CONST + 0.5 * logdet, -np.inf)

    def summary(self) -> dict[str, float]:
        """Mean and sample standard deviation (ddof=1) of the final errors; mean Tr(Sigma_T) and
        entropy."""
        ddof = 1 if self.n > 1 else 0
        return {
            "pos_err_mean": float(np.mean(self.pos_err)),
            "pos_err_std": float(np.std(self.pos_err, ddof=ddof)),
            "ori_err_mean": float(np.mean(self.ori_err)),
            "ori_err_std": float(np.std(self.ori_err, ddof=ddof)),
            "trace_noisy": float(np.mean(self.trace)),
            "entropy_noisy": float(np.mean(self.entropy)),
        }


class BatchedNoise:
    """The model's noise Functions mapped over N poses at once (CasADi `Function.map`), taking poses
    `(p, r)` (converted to the model's means, `lie.np_means`)."""

    def __init__(self, model: BeliefModel, n: int):
        self.n, self.model = n, model
        self._W = model.motion_noise.map(n)
        self._V = model.observation_noise.map(n)
        self._V_expected = None

    def _unstack(self, out) -> np.ndarray:
        # map() concatenates the N 6x6 outputs horizontally: (6, 6N) -> (N, 6, 6)
        return np.asarray(out).reshape(NX, self.n, NX).transpose(1, 0, 2)

    def motion(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """(N, 6, 6) W of the steps x0[k] -> x1[k] ((N, 6) each)."""
        return self._unstack(self._W(np_means(x0).T, np_means(x1).T))

    def observation(self, x: np.ndarray) -> np.ndarray:
        """(N, 6, 6) V at the poses x ((N, 6))."""
        return self._unstack(self._V(np_means(x).T))

    def expected_observation(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(N, 6, 6) V expected under the beliefs N(x, P) ((N, 6), (N, 6, 6)): the model's
        `expected` form, V(x) + tr(J P J^T) per term (surestep_method.md, section 8), the noise
        of the observation given what the tracker knows of the pose."""
        if self._V_expected is None:
            form = replace(self.model.noise, observation_noise="expected")
            self._V_expected = BeliefModel(form, self.model.camera,
                                           self.model.components).planning_noise.map(self.n)
        rows, cols = np.array(_TRIL).T
        return self._unstack(self._V_expected(np_means(x).T, np.asarray(P)[:, rows, cols].T))


def sample_gaussian(cov: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Samples of N(0, cov[k]) from standard normals z (N, 6); cov may be singular (PSD)."""
    lam, U = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    L = U * np.sqrt(np.clip(lam, 0.0, None))[:, None, :]
    return np.einsum("nij,nj->ni", L, z)


def has_identity_maps(model: BeliefModel) -> bool:
    """Whether the model's F, Q, H, R are the constant identity (checked symbolically).

    (`BeliefModel.identity_maps` is False for models made by `with_components`, which
    pass the identity Jacobian Function on explicitly.)
    """
    if model.identity_maps:
        return True
    x0, x1 = ca.SX.sym("x0", NM), ca.SX.sym("x1", NM)
    mats = model.jacobians(x0, x1)
    return all(M.is_constant() and np.array_equal(np.asarray(ca.DM(M)), np.eye(NX)) for M in mats)


def _pose(p: np.ndarray, R: Rotation) -> np.ndarray:
    return np.hstack([p, R.as_rotvec()])


def _gain(P: np.ndarray, S: np.ndarray) -> np.ndarray:
    """K^T = S^-1 P for a stack; pseudo-inverse where S is singular (e.g. all noise constants 0)."""
    try:
        return np.linalg.solve(S, P)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(S, hermitian=True) @ P


def _update(P, V, y, seen) -> tuple[np.ndarray, np.ndarray]:
    """(K^T, K y) of the update with observation noise V (stacks); no observation: no update."""
    KT = _gain(P, P + V)  # K^T = S^-1 P (S, P symmetric); K = P S^-1
    KT[~seen] = 0.0  # no observation: the EKF only predicts
    return KT, np.einsum("nji,nj->ni", KT, y)  # K y


# the iterated tracker's re-linearisations of V per update
ITERATIONS = 2
TRACKER_NOISES = ("mean", "expected", "iterated", "auto")


def rollout(
    model: BeliefModel,
    poses: np.ndarray,
    goal: np.ndarray | None = None,
    n: int = 50,
    rng: np.random.Generator | int | None = 0,
    mode: str = "model",
    sample_initial: bool = False,
    keep_paths: bool = False,
    detection: Detection | None = None,
    changes: list | None = None,
    replan=None,
    policy=None,
    grasp: GraspRule | None = None,
    tracker_noise: str = "mean",
) -> Rollouts:
    """Execute a plan `n` times in closed loop with sampled motion and observation noise.

    Args:
        model: the belief model of the EKF and of the noise (use all components:
            `Setup.eval_model`); only identity motion/observation maps are supported.
        poses: (T+1, 6) planned waypoints, camera frame; `poses[0]` is the start.
        goal: (6,) goal pose for the errors (default: the last waypoint), in the last step's camera
            frame.
        n: number of rollouts.
        rng: a NumPy Generator or a seed. Per step the draws are, in this order,
            `n x 6` normals for w and `n x 6` for v (after `n x 6` for the initial
            error if `sample_initial`), so plans of the same horizon given the same seed
            see the same normal draws (common random numbers across methods).
        mode: `model` (v ~ N(0, V(mu_t|t-1))) or `true` (v ~ N(0, V(x_true))).
        sample_initial: draw the true start from N(poses[0], Sigma0) (left perturbation
            for the orientation); by default the true start is the planned start and
            Sigma0 is only the EKF's prior.
        keep_paths: also return the (N, T+1, 6) true and estimated paths.
        detection: when the true pose gives an observation (see `Detection`); None: always.
            With `falloff > 0`, the n uniforms per step that decide detection come from a child
            generator (`rng.spawn(1)`), not from `rng`: the normal draws are those of the same
            plan with `falloff` 0 (common random numbers across falloffs).
        changes: camera moves (Types 3 and 4; `Setup.camera_changes()`): entry t (4x4 or None)
            maps camera-t to camera-(t+1) coordinates and applies before the step t -> t+1;
            `poses` are then each in their own step's camera frame (`Setup.in_step_frames`).
            At a move, true pose and estimate are re-expressed in the new frame, the EKF adds
            the camera's own motion noise `|t|^2 camera_W_p0 + angle^2 camera_W_o0` to Sigma
            (rotated with it), and the true pose is perturbed by a draw of that noise (n x 6
            normals, drawn before the step's own). A plan longer than `changes` (a baseline
            lengthened to keep within the limits) runs its last steps with the camera held.
        replan: with `changes`, re-planning per rollout after each camera move (Type 4): called as
            `replan(t, mean, cov, waypoints)` right after the move at entry t, with every rollout's
            EKF mean (N, 6) and covariance (N, 6, 6) in the new camera frame and the waypoints each
            rollout follows (N, T+1, 6, step frames; a copy); it returns the (N, T+1, 6) waypoints
            to follow from step t+1 on (rows up to t are not used). It draws nothing from `rng`,
            so the normal draws are those of the same plan without re-planning.
        policy: a closed-loop controller (`closed_loop.ClosedLoop`), called at every step t after
            any camera move as `policy(t, mean, cov)` with every rollout's EKF mean (N, 6) and
            covariance (N, 6, 6); it returns the (N, 6) targets of the step t -> t+1 and an (N,)
            mask of the rollouts still moving. A rollout whose plan has ended holds still (nothing
            moves, nothing is observed: its final values are those at its end). The rollouts run
            `policy.steps` steps; `poses[0]` is the start. It draws nothing from `rng`. A policy
            may say which rollouts' step t -> t+1 ends their plan (`policy.arriving`, (N,)).
        grasp: when each rollout grasps (`grasp_rule.GraspRule`): with a confidence, at the first
            step onto the goal whose predicted success reaches it, dwelling at the goal (under
            observation) until then, or at the rule's cap; the rollouts' `grasp_step`,
            `predicted` and `capped` say when and how sure. None: at the plan's end.
        tracker_noise: the observation noise of the tracker's update: `mean` (V at the predicted
            mean), `expected` (V expected under the predicted belief, `BatchedNoise`) or
            `iterated` (V expected under the updated belief, the update repeated ITERATIONS times
            from the prediction: the noise where the measurement says the tool is); `auto`: each
            mode's world's own (`mean` in `model` mode, whose noise is V at the predicted mean;
            `expected` in `true` mode, whose noise is V at the unknown true pose).
    """
    if tracker_noise not in TRACKER_NOISES:
        raise ValueError(f"unknown tracker_noise '{tracker_noise}'; allowed: "
                         f"{', '.join(TRACKER_NOISES)}")
    if mode not in MODES:
        raise ValueError(f"unknown rollout mode '{mode}'; allowed: {', '.join(MODES)}")
    if tracker_noise == "auto":
        tracker_noise = "mean" if mode == "model" else "expected"
    if not has_identity_maps(model):
        raise ValueError("rollouts support belief models with identity motion and observation "
                         "maps only")
    # the rollouts sample pose-space noise from the waypoints alone: the term would be lost
    if model.joint_noise:
        raise SurestepError("noise.joint_motion_sigma: the rollouts (surestep evaluate) sample "
                            "pose-space motion noise from the waypoints only; evaluate without the "
                            "joint-space term")
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != NX or len(poses) < 2:
        raise ValueError(f"poses must have shape (T+1, {NX}) with T >= 1, got {poses.shape}")
    goal = poses[-1] if goal is None else np.asarray(goal, dtype=float)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    noise = BatchedNoise(model, n)
    waypoints = Rotation.from_rotvec(poses[:, 3:])

    mu_p = np.tile(poses[0, :3], (n, 1))
    mu_R = Rotation.from_rotvec(np.tile(poses[0, 3:], (n, 1)))
    sigma0 = np.asarray(model.noise.Sigma0, dtype=float)
    if sample_initial:
        e0 = sample_gaussian(np.broadcast_to(sigma0, (n, NX, NX)), rng.standard_normal((n, NX)))
        true_p, true_R = mu_p + e0[:, :3], Rotation.from_rotvec(e0[:, 3:]) * mu_R
    else:
        true_p, true_R = mu_p.copy(), mu_R
    sigma = np.tile(sigma0, (n, 1, 1))
    paths_true, paths_est = (([_pose(true_p, true_R)], [_pose(mu_p, mu_R)]) if keep_paths
                             else (None, None))

    steps = len(poses) - 1 if policy is None else int(policy.steps)
    grasping = Grasping(grasp or GraspRule(), n, steps)
    steps = grasping.cap
    last = len(poses) - 1  # the plan's goal waypoint (a dwell targets it)
    detected = np.ones((n, steps), dtype=bool)
    # leaves rng's stream
    u_rng = rng.spawn(1)[0] if detection is not None and detection.falloff > 0 else None
    own = None  # (N, T+1, 6) each rollout's waypoints, once `replan` has been called
    for t in range(steps):
        if changes is not None and t < len(changes) and changes[t] is not None:  # then it holds
            Dc = np.asarray(changes[t], float)
            R_D, t_D = Rotation.from_matrix(Dc[:3, :3]), Dc[:3, 3]
            Wc = (t_D @ t_D) * np.asarray(model.noise.camera_W_p0, float) + \
                R_D.magnitude() ** 2 * np.asarray(model.noise.camera_W_o0, float)
            wc = sample_gaussian(np.broadcast_to(Wc, (n, NX, NX)), rng.standard_normal((n, NX)))
            true_p = R_D.apply(true_p) + t_D + wc[:, :3]
            true_R = Rotation.from_rotvec(wc[:, 3:]) * R_D * true_R
            mu_p, mu_R = R_D.apply(mu_p) + t_D, R_D * mu_R
            F = np.zeros((NX, NX))
            F[:3, :3] = F[3:, 3:] = Dc[:3, :3]  # left-perturbation errors rotate with the frame
            sigma = F @ sigma @ F.T + Wc
            if replan is not None:
                current = np.array(np.broadcast_to(poses, (n, *poses.shape)) if own is None
                                   else own)
                own = np.asarray(replan(t, _pose(mu_p, mu_R), sigma.copy(), current), dtype=float)
                if own.shape != current.shape or not np.all(np.isfinite(own[:, t + 1:])):
                    raise ValueError(f"replan at step {t} returned waypoints of shape {own.shape} "
                                     f"(expected {current.shape}, finite)")
        still = grasping.done.copy()  # grasped: they hold still
        k = min(t + 1, last)
        arriving = np.full(n, t + 1 >= last)
        if policy is not None:
            target, moving = policy(t, _pose(mu_p, mu_R), sigma.copy())
            target, moving = np.asarray(target, float), np.asarray(moving, bool)
            if target.shape != (n, NX) or moving.shape != (n,) or \
                    not np.all(np.isfinite(target[moving])):
                raise ValueError(f"policy at step {t} returned targets of shape {target.shape} "
                                 f"and a mask of shape {moving.shape} (expected ({n}, {NX}), "
                                 f"finite, and ({n},))")
            dwell = ~moving & ~still
            if grasping.rule.confidence is None:  # at its plan's end a rollout holds still
                still |= dwell
            target[dwell] = goal
            arriving = dwell | np.asarray(getattr(policy, "arriving", np.zeros(n, bool)), bool)
        elif own is None:
            target = np.tile(poses[k], (n, 1))
        else:
            target = own[:, k].copy()
        held = (true_p, true_R.as_quat(), mu_p, mu_R.as_quat(), sigma)
        z_w, z_v = rng.standard_normal((n, NX)), rng.standard_normal((n, NX))
        u_det = None if u_rng is None else u_rng.random(n)
        # command: from the estimate to the next waypoint; W of that step
        W = noise.motion(_pose(mu_p, mu_R), target)
        dp = target[:, :3] - mu_p
        D = mu_R.inv() * (waypoints[k] if own is None and policy is None
                          else Rotation.from_rotvec(target[:, 3:]))
        w = sample_gaussian(W, z_w)
        true_p = true_p + dp + w[:, :3]
        true_R = Rotation.from_rotvec(w[:, 3:]) * true_R * D
        # EKF predict (identity maps): the predicted mean is the commanded waypoint
        pred_p, pred_R = mu_p + dp, mu_R * D
        pred = _pose(pred_p, pred_R)
        P = sigma + W
        grasping.decide(t, arriving & ~still, P)
        if detection is not None:
            prob = detection.probability(model.camera, true_p)
            seen = prob >= 1.0 if u_det is None else u_det < prob
            detected[:, t] = seen
        else:
            seen = detected[:, t]
        V_pred = noise.observation(pred)
        V_ekf = V_pred if tracker_noise == "mean" else noise.expected_observation(pred, P)
        if mode == "model":
            V_real = V_pred
        else:  # V at an undetected true pose (e.g. behind the lens) is not used; keep it finite
            V_real = noise.observation(np.where(seen[:, None], _pose(true_p, true_R), pred))
        v = sample_gaussian(V_real, z_v)
        z_p, z_R = true_p + v[:, :3], Rotation.from_rotvec(v[:, 3:]) * true_R
        # gating: a reported position outside the detectable region is no detection
        if detection is not None:
            seen = seen & (detection.probability(model.camera, z_p) > 0)
            detected[:, t] = seen
        y = np.hstack([z_p - pred_p, (z_R * pred_R.inv()).as_rotvec()])
        KT, dx = _update(P, V_ekf, y, seen)
        for _ in range(ITERATIONS if tracker_noise == "iterated" else 0):
            # V expected under the updated belief, then the update again from the prediction
            # P - P S^-1 P without its cancellation (unseen: P)
            upd = np.where(seen[:, None, None], np.swapaxes(KT, 1, 2) @ V_ekf, P)
            V_ekf = noise.expected_observation(
                _pose(pred_p + dx[:, :3], Rotation.from_rotvec(dx[:, 3:]) * pred_R),
                0.5 * (upd + np.swapaxes(upd, 1, 2)))
            KT, dx = _update(P, V_ekf, y, seen)
        mu_p, mu_R = pred_p + dx[:, :3], Rotation.from_rotvec(dx[:, 3:]) * pred_R
        # P - P S^-1 P as P S^-1 V: equal, without the cancellation that loses definiteness
        post = np.where(seen[:, None, None], np.swapaxes(KT, 1, 2) @ V_ekf, P)
        sigma = 0.5 * (post + np.swapaxes(post, 1, 2))
        if still.any():  # the rollouts that grasped (or ended their plan) hold still
            detected[still, t] = False
            true_p, mu_p = np.where(still[:, None], held[0], true_p), np.where(still[:, None],
                                                                             held[2], mu_p)
            true_R = Rotation.from_quat(np.where(still[:, None], held[1], true_R.as_quat()))
            mu_R = Rotation.from_quat(np.where(still[:, None], held[3], mu_R.as_quat()))
            sigma = np.where(still[:, None, None], held[4], sigma)
        if keep_paths:
            paths_true.append(_pose(true_p, true_R))
            paths_est.append(_pose(mu_p, mu_R))
        if grasping.rule.confidence is not None and grasping.done.all() and t + 1 < steps:
            # every rollout has grasped: the paths end here
            detected = detected[:, :t + 1]
            break

    goal_R = Rotation.from_rotvec(goal[3:])
    return Rollouts(
        mode=mode,
        goal=goal,
        final_true=_pose(true_p, true_R),
        final_estimate=_pose(mu_p, mu_R),
        final_error=np.hstack([true_p - mu_p, (true_R * mu_R.inv()).as_rotvec()]),
        sigma_final=sigma,
        pos_err=np.linalg.norm(true_p - goal[:3], axis=1),
        ori_err=(goal_R.inv() * true_R).magnitude(),
        true_path=None if paths_true is None else np.stack(paths_true, axis=1),
        estimate_path=None if paths_est is None else np.stack(paths_est, axis=1),
        detected=detected,
        grasp_step=grasping.step,
        predicted=grasping.predicted,
        capped=grasping.capped,
    )


def plan_metrics(model: BeliefModel, poses: np.ndarray, goal: np.ndarray, n: int, rng, mode: str,
                 sigma_ml: np.ndarray | None = None, detection: Detection | None = None,
                 policy=None) -> tuple[dict[str, float], Rollouts]:
    """The eight evaluation metrics (`METRICS`) of one plan in one rollout mode (with `policy`, of
    a closed-loop method whose first plan is `poses`: `rollout`'s).

    `trace_ml` and `entropy_ml` are of the plan's own maximum-likelihood Sigma_T
    (`sigma_ml`, e.g. `Solution.sigma_final`; computed with `model.propagate` if omitted).
    """
    ro = rollout(model, poses, goal, n, rng, mode, detection=detection, policy=policy)
    if sigma_ml is None:
        sigma_ml = model.propagate(np.asarray(poses, float))[0][-1]
    sigma_ml = np.asarray(sigma_ml, dtype=float)
    out = ro.summary()
    sign, logdet = np.linalg.slogdet(sigma_ml)
    out["trace_ml"] = float(np.trace(sigma_ml))
    out["entropy_ml"] = float(_ENTROPY_CONST + 0.5 * logdet) if sign > 0 else float("-inf")
    return {k: out[k] for k in METRICS}, ro
