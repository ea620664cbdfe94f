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

from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import SurestepError
from ..model.belief import NM, NX, BeliefModel
from ..model.detection import Detection  # noqa: F401 (re-exported: its home before)
# BatchedNoise and sample_gaussian: imported from here by tracker.py and the tests
from .batched_ekf import BatchedNoise, ekf_update, pose_rows, sample_gaussian
from .grasp_rule import GraspRule, Grasping

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


# the iterated tracker's re-linearisations of V per update
ITERATIONS = 2
TRACKER_NOISES = ("mean", "expected", "iterated", "auto")


def rollout(model: BeliefModel, poses: np.ndarray, goal: np.ndarray | None = None, n: int = 50,
            rng: np.random.Generator | int | None = 0, mode: str = "model",
            sample_initial: bool = False, keep_paths: bool = False,
            detection: Detection | None = None, changes: list | None = None, replan=None,
            policy=None, grasp: GraspRule | None = None, tracker_noise: str = "mean") -> Rollouts:
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
    tracker_noise, poses = _checked(model, poses, mode, tracker_noise)
    goal = poses[-1] if goal is None else np.asarray(goal, dtype=float)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    run = _Batch(model, poses, goal, n, rng, mode, tracker_noise, sample_initial, keep_paths,
                 detection, changes, replan, policy, grasp)
    for t in range(run.steps):
        if run.step(t):
            break
    return run.result()


def _checked(model: BeliefModel, poses, mode: str, tracker_noise: str) -> tuple[str, np.ndarray]:
    """The rollouts' arguments checked: the tracker noise (`auto` resolved) and the (T+1, 6)
    poses."""
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
    return tracker_noise, poses


class _Batch:
    """The N rollouts of `rollout` as they run, one step t -> t+1 at a time: the world (the true
    poses `true_p`, `true_R`), each rollout's tracker (its EKF's mean `mu_p`, `mu_R` and covariance
    `sigma`), the grasp decisions (`grasping`) and what is recorded (`detected`, the paths)."""

    def __init__(self, model: BeliefModel, poses: np.ndarray, goal: np.ndarray, n: int,
                 rng: np.random.Generator, mode: str, tracker_noise: str, sample_initial: bool,
                 keep_paths: bool, detection: Detection | None, changes, replan, policy,
                 grasp: GraspRule | None):
        self.model, self.poses, self.goal, self.n, self.rng = model, poses, goal, n, rng
        self.mode, self.tracker_noise, self.detection = mode, tracker_noise, detection
        self.changes, self.replan, self.policy = changes, replan, policy
        self.noise = BatchedNoise(model, n)
        self.waypoints = Rotation.from_rotvec(poses[:, 3:])
        self._start(sample_initial)
        self.paths = (([pose_rows(self.true_p, self.true_R)], [pose_rows(self.mu_p, self.mu_R)])
                      if keep_paths else None)
        steps = len(poses) - 1 if policy is None else int(policy.steps)
        self.grasping = Grasping(grasp or GraspRule(), n, steps)
        self.steps = self.grasping.cap
        self.last = len(poses) - 1  # the plan's goal waypoint (a dwell targets it)
        self.detected = np.ones((n, self.steps), dtype=bool)
        # leaves rng's stream
        self.u_rng = rng.spawn(1)[0] if detection is not None and detection.falloff > 0 else None
        self.own = None  # (N, T+1, 6) each rollout's waypoints, once `replan` has been called

    def _start(self, sample_initial: bool) -> None:
        """The start: every estimate at the plan's first waypoint with the prior Sigma0, the true
        poses there too or drawn from N(poses[0], Sigma0)."""
        n, poses = self.n, self.poses
        self.mu_p = np.tile(poses[0, :3], (n, 1))
        self.mu_R = Rotation.from_rotvec(np.tile(poses[0, 3:], (n, 1)))
        sigma0 = np.asarray(self.model.noise.Sigma0, dtype=float)
        if sample_initial:
            e0 = sample_gaussian(np.broadcast_to(sigma0, (n, NX, NX)),
                                 self.rng.standard_normal((n, NX)))
            self.true_p = self.mu_p + e0[:, :3]
            self.true_R = Rotation.from_rotvec(e0[:, 3:]) * self.mu_R
        else:
            self.true_p, self.true_R = self.mu_p.copy(), self.mu_R
        self.sigma = np.tile(sigma0, (n, 1, 1))

    def step(self, t: int) -> bool:
        """The step t -> t+1 of every rollout; True when every rollout has grasped before the
        last step (the paths end here)."""
        changes = self.changes
        if changes is not None and t < len(changes) and changes[t] is not None:  # then it holds
            self._move_camera(np.asarray(changes[t], float))
            if self.replan is not None:
                self._replan(t)
        still = self.grasping.done.copy()  # grasped: they hold still
        k = min(t + 1, self.last)
        if self.policy is not None:
            target, arriving = self._policy_targets(t, still)
        else:
            target = (np.tile(self.poses[k], (self.n, 1)) if self.own is None
                      else self.own[:, k].copy())
            arriving = np.full(self.n, t + 1 >= self.last)
        held = (self.true_p, self.true_R.as_quat(), self.mu_p, self.mu_R.as_quat(), self.sigma)
        z_w, z_v = self.rng.standard_normal((self.n, NX)), self.rng.standard_normal((self.n, NX))
        u_det = None if self.u_rng is None else self.u_rng.random(self.n)
        W, dp, D = self._command(target, k)
        self._world_moves(W, dp, D, z_w)
        # EKF predict (identity maps): the predicted mean is the commanded waypoint
        pred_p, pred_R = self.mu_p + dp, self.mu_R * D
        P = self.sigma + W
        self.grasping.decide(t, arriving & ~still, P)
        seen = self._detected(t, u_det)
        V_ekf, y, seen = self._observe(t, pred_p, pred_R, P, seen, z_v)
        self._tracker_update(pred_p, pred_R, P, V_ekf, y, seen)
        if still.any():  # the rollouts that grasped (or ended their plan) hold still
            self._hold_still(t, still, held)
        if self.paths is not None:
            self.paths[0].append(pose_rows(self.true_p, self.true_R))
            self.paths[1].append(pose_rows(self.mu_p, self.mu_R))
        if self.grasping.rule.confidence is not None and self.grasping.done.all() \
                and t + 1 < self.steps:
            # every rollout has grasped: the paths end here
            self.detected = self.detected[:, :t + 1]
            return True
        return False

    def _move_camera(self, Dc: np.ndarray) -> None:
        """A camera move Dc (4x4) before the step: true poses and estimates re-expressed in the new
        frame, the true poses perturbed by a draw of the camera's own motion noise, which the
        tracker adds to its Sigma (rotated with the frame)."""
        n, noise = self.n, self.model.noise
        R_D, t_D = Rotation.from_matrix(Dc[:3, :3]), Dc[:3, 3]
        Wc = (t_D @ t_D) * np.asarray(noise.camera_W_p0, float) + \
            R_D.magnitude() ** 2 * np.asarray(noise.camera_W_o0, float)
        wc = sample_gaussian(np.broadcast_to(Wc, (n, NX, NX)), self.rng.standard_normal((n, NX)))
        self.true_p = R_D.apply(self.true_p) + t_D + wc[:, :3]
        self.true_R = Rotation.from_rotvec(wc[:, 3:]) * R_D * self.true_R
        self.mu_p, self.mu_R = R_D.apply(self.mu_p) + t_D, R_D * self.mu_R
        F = np.zeros((NX, NX))
        F[:3, :3] = F[3:, 3:] = Dc[:3, :3]  # left-perturbation errors rotate with the frame
        self.sigma = F @ self.sigma @ F.T + Wc

    def _replan(self, t: int) -> None:
        """Each rollout's waypoints re-planned from its belief right after the camera move at t."""
        poses, n = self.poses, self.n
        current = np.array(np.broadcast_to(poses, (n, *poses.shape)) if self.own is None
                           else self.own)
        mean = pose_rows(self.mu_p, self.mu_R)
        own = np.asarray(self.replan(t, mean, self.sigma.copy(), current), dtype=float)
        self.own = own
        if own.shape != current.shape or not np.all(np.isfinite(own[:, t + 1:])):
            raise ValueError(f"replan at step {t} returned waypoints of shape {own.shape} "
                             f"(expected {current.shape}, finite)")

    def _policy_targets(self, t: int, still: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The policy's commands for step t: the (N, 6) targets (the goal for a rollout whose plan
        has ended: it dwells there) and which rollouts' step ends on the goal; without a confidence
        `still` (changed in place) gains the rollouts whose plan has ended."""
        n = self.n
        target, moving = self.policy(t, pose_rows(self.mu_p, self.mu_R), self.sigma.copy())
        target, moving = np.asarray(target, float), np.asarray(moving, bool)
        if target.shape != (n, NX) or moving.shape != (n,) or \
                not np.all(np.isfinite(target[moving])):
            raise ValueError(f"policy at step {t} returned targets of shape {target.shape} "
                             f"and a mask of shape {moving.shape} (expected ({n}, {NX}), "
                             f"finite, and ({n},))")
        dwell = ~moving & ~still
        if self.grasping.rule.confidence is None:  # at its plan's end a rollout holds still
            still |= dwell
        target[dwell] = self.goal
        arriving = dwell | np.asarray(getattr(self.policy, "arriving", np.zeros(n, bool)), bool)
        return target, arriving

    def _command(self, target: np.ndarray, k: int):
        """The command of the step: from each estimate to its target, (W of that step, the
        translation dp, the body-frame rotation D)."""
        W = self.noise.motion(pose_rows(self.mu_p, self.mu_R), target)
        dp = target[:, :3] - self.mu_p
        D = self.mu_R.inv() * (self.waypoints[k] if self.own is None and self.policy is None
                               else Rotation.from_rotvec(target[:, 3:]))
        return W, dp, D

    def _world_moves(self, W: np.ndarray, dp: np.ndarray, D: Rotation, z_w: np.ndarray) -> None:
        """The world's step: each true pose moves by the command plus a draw of its motion noise."""
        w = sample_gaussian(W, z_w)
        self.true_p = self.true_p + dp + w[:, :3]
        self.true_R = Rotation.from_rotvec(w[:, 3:]) * self.true_R * D

    def _detected(self, t: int, u_det) -> np.ndarray:
        """(N,) whether the detector sees each true pose after the step (recorded in
        `detected`)."""
        if self.detection is not None:
            prob = self.detection.probability(self.model.camera, self.true_p)
            seen = prob >= 1.0 if u_det is None else u_det < prob
            self.detected[:, t] = seen
        else:
            seen = self.detected[:, t]
        return seen

    def _observe(self, t: int, pred_p: np.ndarray, pred_R: Rotation, P: np.ndarray,
                 seen: np.ndarray, z_v: np.ndarray):
        """The observation of the true poses and the tracker's view of it: (the tracker's
        observation noise V, the innovation y, which rollouts observed after gating)."""
        noise, true_p, true_R = self.noise, self.true_p, self.true_R
        pred = pose_rows(pred_p, pred_R)
        V_pred = noise.observation(pred)
        V_ekf = V_pred if self.tracker_noise == "mean" else noise.expected_observation(pred, P)
        if self.mode == "model":
            V_real = V_pred
        else:  # V at an undetected true pose (e.g. behind the lens) is not used; keep it finite
            V_real = noise.observation(np.where(seen[:, None], pose_rows(true_p, true_R), pred))
        v = sample_gaussian(V_real, z_v)
        z_p, z_R = true_p + v[:, :3], Rotation.from_rotvec(v[:, 3:]) * true_R
        # gating: a reported position outside the detectable region is no detection
        if self.detection is not None:
            seen = seen & (self.detection.probability(self.model.camera, z_p) > 0)
            self.detected[:, t] = seen
        y = np.hstack([z_p - pred_p, (z_R * pred_R.inv()).as_rotvec()])
        return V_ekf, y, seen

    def _tracker_update(self, pred_p: np.ndarray, pred_R: Rotation, P: np.ndarray,
                        V_ekf: np.ndarray, y: np.ndarray, seen: np.ndarray) -> None:
        """The tracker's EKF update from the prediction (none where nothing was observed)."""
        KT, dx = ekf_update(P, V_ekf, y, seen)
        for _ in range(ITERATIONS if self.tracker_noise == "iterated" else 0):
            # V expected under the updated belief, then the update again from the prediction
            # P - P S^-1 P without its cancellation (unseen: P)
            upd = np.where(seen[:, None, None], np.swapaxes(KT, 1, 2) @ V_ekf, P)
            V_ekf = self.noise.expected_observation(
                pose_rows(pred_p + dx[:, :3], Rotation.from_rotvec(dx[:, 3:]) * pred_R),
                0.5 * (upd + np.swapaxes(upd, 1, 2)))
            KT, dx = ekf_update(P, V_ekf, y, seen)
        self.mu_p, self.mu_R = pred_p + dx[:, :3], Rotation.from_rotvec(dx[:, 3:]) * pred_R
        # P - P S^-1 P as P S^-1 V: equal, without the cancellation that loses definiteness
        post = np.where(seen[:, None, None], np.swapaxes(KT, 1, 2) @ V_ekf, P)
        self.sigma = 0.5 * (post + np.swapaxes(post, 1, 2))

    def _hold_still(self, t: int, still: np.ndarray, held: tuple) -> None:
        """The `still` rollouts keep their poses and beliefs from before the step, unobserved."""
        self.detected[still, t] = False
        self.true_p, self.mu_p = np.where(still[:, None], held[0], self.true_p), np.where(
            still[:, None], held[2], self.mu_p)
        self.true_R = Rotation.from_quat(np.where(still[:, None], held[1], self.true_R.as_quat()))
        self.mu_R = Rotation.from_quat(np.where(still[:, None], held[3], self.mu_R.as_quat()))
        self.sigma = np.where(still[:, None, None], held[4], self.sigma)

    def result(self) -> Rollouts:
        """The rollouts' final values (and paths, when kept)."""
        goal, true_p, true_R, mu_p, mu_R = self.goal, self.true_p, self.true_R, self.mu_p, self.mu_R
        goal_R = Rotation.from_rotvec(goal[3:])
        paths_true, paths_est = (None, None) if self.paths is None else self.paths
        return Rollouts(
            mode=self.mode,
            goal=goal,
            final_true=pose_rows(true_p, true_R),
            final_estimate=pose_rows(mu_p, mu_R),
            final_error=np.hstack([true_p - mu_p, (true_R * mu_R.inv()).as_rotvec()]),
            sigma_final=self.sigma,
            pos_err=np.linalg.norm(true_p - goal[:3], axis=1),
            ori_err=(goal_R.inv() * true_R).magnitude(),
            true_path=None if paths_true is None else np.stack(paths_true, axis=1),
            estimate_path=None if paths_est is None else np.stack(paths_est, axis=1),
            detected=self.detected,
            grasp_step=self.grasping.step,
            predicted=self.grasping.predicted,
            capped=self.grasping.capped,
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
