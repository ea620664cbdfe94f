"""A simulated tracker for re-planning loops: one rollout of `rollout.py`, stepped one waypoint at a
time.

Per call the tool is commanded from the tracker's estimate to the next waypoint, moves with the
model's motion noise, is observed with its observation noise, and the EKF updates (the formulas and
the noise draws of `rollout.rollout` with n = 1, mode `model`, always detected, a fixed camera).
Between calls the planner may change the plan, which a whole-plan rollout cannot express.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..model.belief import NX, BeliefModel
from .rollout import BatchedNoise, sample_gaussian


class SimulatedTracker:
    """The true tool pose and the tracker's estimate (mean [m, rad] and covariance), camera frame.

    Args:
        model: the belief model of the noise and of the EKF (use `Setup.eval_model`: every
            component).
        start: (6,) the true and estimated start pose `[p, axis-angle]`.
        sigma0: (6, 6) the estimate's initial covariance (default: the model's Sigma0).
        rng: a NumPy Generator or a seed.
    """

    def __init__(self, model: BeliefModel, start, sigma0=None, rng=0):
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._noise = BatchedNoise(model, 1)
        start = np.asarray(start, float)
        self.true_p, self.true_R = start[:3].copy(), Rotation.from_rotvec(start[3:])
        self.mu_p, self.mu_R = start[:3].copy(), Rotation.from_rotvec(start[3:])
        self.covariance = np.array(model.noise.Sigma0 if sigma0 is None else sigma0, float)

    @property
    def mean(self) -> np.ndarray:
        """(6,) the estimated pose [m, rad]."""
        return np.hstack([self.mu_p, self.mu_R.as_rotvec()])

    @property
    def true_pose(self) -> np.ndarray:
        """(6,) the true pose [m, rad]."""
        return np.hstack([self.true_p, self.true_R.as_rotvec()])

    def move_to(self, waypoint) -> tuple[np.ndarray, np.ndarray]:
        """Command the step from the estimate to `waypoint` (6,), move, observe, update; the new
        (mean, covariance)."""
        x = np.asarray(waypoint, float)
        z_w, z_v = self.rng.standard_normal((1, NX)), self.rng.standard_normal((1, NX))
        W = self._noise.motion(self.mean[None], x[None])[0]
        target_R = Rotation.from_rotvec(x[3:])
        D = self.mu_R.inv() * target_R
        w = sample_gaussian(W[None], z_w)[0]
        self.true_p = self.true_p + (x[:3] - self.mu_p) + w[:3]
        self.true_R = Rotation.from_rotvec(w[3:]) * self.true_R * D
        pred_p, pred_R = x[:3], self.mu_R * D  # the predicted mean is the commanded waypoint
        P = self.covariance + W
        V = self._noise.observation(np.hstack([pred_p, pred_R.as_rotvec()])[None])[0]
        v = sample_gaussian(V[None], z_v)[0]
        z_p, z_R = self.true_p + v[:3], Rotation.from_rotvec(v[3:]) * self.true_R
        y = np.hstack([z_p - pred_p, (z_R * pred_R.inv()).as_rotvec()])
        KT = np.linalg.solve(P + V, P)  # K^T = S^-1 P
        dx = KT.T @ y
        self.mu_p, self.mu_R = pred_p + dx[:3], Rotation.from_rotvec(dx[3:]) * pred_R
        post = KT.T @ V  # P - P S^-1 P as P S^-1 V: no cancellation (rollout.py)
        self.covariance = 0.5 * (post + post.T)
        return self.mean, self.covariance
