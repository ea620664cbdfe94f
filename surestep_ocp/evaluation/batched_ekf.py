"""The rollouts' arithmetic on N poses at once (`rollout.py`, `tracker.py`): the belief model's
noise Functions mapped over N poses, Gaussian draws from stacks of covariances, and the EKF's
update of a stack of beliefs.

Poses are `(p, r)` rows (axis-angle `r`); stacks are indexed by rollout first.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..model.belief import _TRIL, NX, BeliefModel
from ..model.lie import np_means


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


def pose_rows(p: np.ndarray, R: Rotation) -> np.ndarray:
    """(N, 6) poses `(p, r)` of positions (N, 3) and rotations."""
    return np.hstack([p, R.as_rotvec()])


def _gain(P: np.ndarray, S: np.ndarray) -> np.ndarray:
    """K^T = S^-1 P for a stack; pseudo-inverse where S is singular (e.g. all noise constants 0)."""
    try:
        return np.linalg.solve(S, P)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(S, hermitian=True) @ P


def ekf_update(P, V, y, seen) -> tuple[np.ndarray, np.ndarray]:
    """(K^T, K y) of the update with observation noise V (stacks); no observation: no update."""
    KT = _gain(P, P + V)  # K^T = S^-1 P (S, P symmetric); K = P S^-1
    KT[~seen] = 0.0  # no observation: the EKF only predicts
    return KT, np.einsum("nji,nj->ni", KT, y)  # K y
