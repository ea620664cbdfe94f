"""The grasp's confidence: the probability, under a Gaussian belief, that the tool's pose error at
the grasp is within the grasp's tolerance.

The error is e ~ N(0, Sigma), Sigma 6x6 over (position [m], orientation as the rotation vector of
a left perturbation [rad]); the grasp succeeds when |e_p| <= position and |e_r| <= angle (one
definition, `within`, for predictions and for counting rollouts). With e = L z (Sigma = L L^T, z
standard normal in R^6) and z = rho u, where rho^2 ~ chi^2_6 is independent of the direction u
(uniform on the sphere), the event is rho^2 <= m(u) = min(position^2 / |L_p u|^2,
angle^2 / |L_r u|^2). So

    P(grasp) = E_u[F(m(u))],   F(x) = 1 - exp(-x/2) (1 + x/2 + x^2/8)   (chi^2_6's CDF),

exact along each direction, and averaged over a fixed set of directions (a scrambled Sobol set of
normals, normalised): a deterministic number for any Sigma (correlated blocks, singular ones),
vectorised over a stack of covariances. Its error against sampling is checked in
tests/test_grasp.py.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import ndtri
from scipy.stats import qmc

# directions on the sphere S^5 the expectation is taken over (2^12: within 0.1 points of 10^6
# samples on the Table II types' covariances, tests/test_grasp.py)
DIRECTIONS_LOG2 = 12


@lru_cache(maxsize=2)
def directions(log2: int = DIRECTIONS_LOG2) -> np.ndarray:
    """(2^log2, 6) unit vectors: a scrambled Sobol set (fixed seed) of normals, normalised."""
    u = qmc.Sobol(6, scramble=True, seed=20240512).random_base2(log2)
    z = ndtri(np.clip(u, 1e-12, 1 - 1e-12))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    z.setflags(write=False)
    return z


def chi2_6_cdf(x: np.ndarray) -> np.ndarray:
    """The chi-square CDF with 6 degrees of freedom, in closed form (x >= 0, inf allowed)."""
    h = 0.5 * np.asarray(x, float)
    with np.errstate(over="ignore", invalid="ignore"):
        out = 1.0 - np.exp(-h) * (1.0 + h + 0.5 * h * h)
    return np.where(np.isinf(h), 1.0, out)


def grasp_probability(cov, position: float, angle: float) -> np.ndarray | float:
    """P(|e_p| <= position and |e_r| <= angle) for e ~ N(0, cov); cov (6, 6) or a stack (..., 6, 6)
    [m^2, m rad, rad^2]; a float for one covariance (module docstring)."""
    C = np.asarray(cov, float)
    stack = C.reshape(-1, 6, 6)
    lam, U = np.linalg.eigh(0.5 * (stack + np.swapaxes(stack, 1, 2)))
    L = U * np.sqrt(np.clip(lam, 0.0, None))[:, None, :]  # Sigma = L L^T (PSD part)
    Lu = np.matmul(directions()[None], np.swapaxes(L, 1, 2))  # (K, M, 6): L u per direction
    p_, r_ = Lu[..., :3], Lu[..., 3:]
    # the larger of |L_p u|^2 / position^2 and |L_r u|^2 / angle^2: the event is rho^2 <= 1 / r
    r = np.maximum(np.einsum("kmi,kmi->km", p_, p_) / position**2,
                   np.einsum("kmi,kmi->km", r_, r_) / angle**2)
    with np.errstate(divide="ignore"):
        m = np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), np.inf)
    p = chi2_6_cdf(m).mean(axis=1).reshape(C.shape[:-2])
    return float(p) if p.ndim == 0 else p


def within(pos_err, ori_err, position: float, angle: float) -> np.ndarray:
    """Whether each final error is within the grasp's tolerance (|position error| <= position [m]
    and orientation error <= angle [rad]): the success the rollouts count."""
    return (np.asarray(pos_err) <= position) & (np.asarray(ori_err) <= angle)


def nees(error, cov) -> np.ndarray:
    """(N,) normalised estimation error squared e^T Sigma^-1 e of errors (N, 6) against their
    covariances (N, 6, 6): the tracker's consistency (mean 6 when it is consistent)."""
    e, C = np.asarray(error, float), np.asarray(cov, float)
    return np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0])
