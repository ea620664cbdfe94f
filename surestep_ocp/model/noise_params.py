"""The belief model's noise constants (`NoiseParams`, the paper's values by default) and the names
of its options: the observation components, the orientation formulas, the observation noise's
forms and the covariance the planners minimise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..equality import ArrayEquality
from .vech import NX

COMPONENTS = ("depth", "fov", "orientation")
ORIENTATION_FORMULAS = ("cosine", "geodesic")
OBSERVATION_NOISE_FORMS = ("mean", "expected")
OBJECTIVES = ("posterior", "predicted")
# The default guard g of |r| in the paper's cosine formula, cos = r.o* / (sqrt(|r|^2 + g^2) |o*|),
# as its square [rad^2] (`NoiseParams.cosine_guard` is g [rad]). The formula is undefined at r = 0,
# and near it the direction of r is free, which an optimiser exploits to make the orientation noise
# vanish; with the guard small rotations see the full orientation noise and larger ones nearly the
# paper's cosine (docs/orientation.md, "The paper's cosine": the guard).
DEFAULT_COSINE_GUARD = 0.05  # [rad]
DEFAULT_CUT_BAND = 0.2  # [rad] (see `paper_cosine`)
COSINE_GUARD = DEFAULT_COSINE_GUARD**2


@dataclass(frozen=True, eq=False)
class NoiseParams(ArrayEquality):
    """Noise constants (6x6 matrices; the paper's values by default) and options."""

    W_p0: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(NX))
    W_o0: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(NX))
    V_d0: np.ndarray = field(default_factory=lambda: 1e-1 * np.eye(NX))
    V_f0: np.ndarray = field(default_factory=lambda: 1e-2 * np.eye(NX))
    V_o0: np.ndarray = field(default_factory=lambda: 5e-3 * np.eye(NX))
    Sigma0: np.ndarray = field(default_factory=lambda: 1e-2 * np.eye(NX))
    depth_star: float = 0.15  # [m]
    o_star: tuple[float, float, float] = (0.0, 0.0, 1.0)  # [rad] axis-angle
    components: tuple[str, ...] = COMPONENTS
    orientation_formula: str = "cosine"
    # mean (the paper's) | expected (under the predicted belief, section 8)
    observation_noise: str = "mean"
    # planners minimise Tr(Sigma_T|T) (posterior) or Tr(Sigma_T|T-1) (predicted)
    objective: str = "posterior"
    # per camera move [1/m^2 scale]
    camera_W_p0: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(NX))
    camera_W_o0: np.ndarray = field(default_factory=lambda: 1e-3 * np.eye(NX))
    # observation noise floor (PSD)
    V_min: np.ndarray = field(default_factory=lambda: np.zeros((NX, NX)))
    # [rad] g in the cosine formula; 0: the paper's formula (r != 0)
    cosine_guard: float = DEFAULT_COSINE_GUARD
    # [rad] below pi where the cosine fades to 0 (`paper_cosine`); 0: a jump
    cut_band: float = DEFAULT_CUT_BAND
    # joint-space motion noise `W_q = J diag(sigma_q^2 dq^2) J^T` (joint_noise.py): sigma_q per
    # joint [-], or None
    joint_sigma: tuple[float, ...] | None = None
