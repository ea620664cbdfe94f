"""The belief model: noise models and the EKF step under maximum-likelihood observations.

The mean is rotation-valued, `m = (p, Q)` (NM = 7 numbers): the tool position [m] and the unit
quaternion of its orientation, in the camera frame. The covariance Sigma (6x6) is that of the
error in the tangent at the mean, `(p_true - p, e)` with `R_true = exp(e) R` (a left,
camera-frame perturbation; the rollouts use the same). With the motion applied as a body-frame
step (`R_t+1 = R_t D`) and the tracker reporting `exp(v) R_true`, the error-state EKF's maps are
the identity (F = Q = H = R = I) for any noise matrices: exactly for the mean's step, to first order
in the noises for their composition (the noises are milliradians); a camera move rotates the error
(`camera_change`). Residuals between means are tangents of the relative rotation (`lie.quat_step`),
so no axis-angle chart enters the model; poses `(p, r)` are converted at the boundary
(`propagate`, `lie.np_means`). The covariance is carried as `vech(Sigma)` (21 numbers, the lower
triangle column by column; `vech.py`), the noise constants are `NoiseParams`
(`noise_params.py`; both importable from here). All maps are named CasADi Functions built once;
every method (OCP, gradient variant, baseline, rollouts) uses these.

    predict:  P  = F Sigma F^T + Q (W(x_t, x_t+1) + W_q) Q^T
              (W_q: the optional joint-space term, joint_noise.py)
    update:   S  = H P H^T + R V(x_t+1) R^T,  K = P H^T S^-1,  Sigma+ = sym((I - K H) P),
              evaluated without its cancellation (`posterior`): the product form
              sym(P S^-1 R V R^T) for H = I (and as such for a constant invertible H), the
              Joseph form otherwise
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache, cached_property

import casadi as ca
import numpy as np

from .camera import Intrinsics
from .lie import (SMALL, np_log, np_means, np_quat_of_matrix, quat_cos_angle, quat_mul, quat_of,
                  quat_step, quat_tangent)
from .noise_params import (  # noqa: F401 (their home before)
    COMPONENTS,
    COSINE_GUARD,
    DEFAULT_COSINE_GUARD,
    DEFAULT_CUT_BAND,
    OBJECTIVES,
    OBSERVATION_NOISE_FORMS,
    ORIENTATION_FORMULAS,
    NoiseParams,
)
from .vech import _TRIL, DIAG, NV, NX, trace_vech, unvech, unvech_many, vech  # noqa: F401

NM = 7  # a mean: position, unit quaternion (w, x, y, z)


_SHARED: dict[tuple, ca.Function] = {}


def _shared(model, name, build) -> ca.Function:
    """`build()` once per model constants (`BeliefModel.key`) and `name`, shared by every
    BeliefModel with those constants (a setup's variants, e.g. the second start's diagonal model or
    a re-plan's Sigma_0, are new models with the same Functions); models with their own maps keep
    theirs (keyed by the maps' id, which a collected Function's successor may reuse)."""
    if not model.identity_maps:
        return build()
    key = (model.key(), name)
    if key not in _SHARED:
        _SHARED[key] = build()
    return _SHARED[key]


def shared_function(build):
    """A model's named CasADi Function as a property, built once and shared (`_shared`)."""
    name = build.__name__

    def get(self):
        if name not in self.__dict__:
            self.__dict__[name] = _shared(self, name, lambda: build(self))
        return self.__dict__[name]

    get.__doc__ = build.__doc__
    return property(get)


def paper_cosine(Q, o_star, guard: float, band: float):
    """The paper's `cos = r.o* / (|r| |o*|)` as a function of the rotation (CasADi), from
    its unit quaternion Q.

    The paper's formula is one of the axis-angle chart: it is evaluated on the rotation's principal
    vector r_p (angle in [0, pi]), so both signs of Q give the same value; the guard g [rad] makes
    it `r_p.o* / (sqrt(|r_p|^2 + g^2) |o*|)` (defined at r = 0); within `band` [rad] below pi it
    fades to 0 at pi by a smoothstep in Q's w, where the paper's formula jumps (r_p and -r_p are
    the same rotation there): continuous on SO(3), smooth in the joints, the paper's own value at
    angles up to pi - band.
    """
    w, v = Q[0], Q[1:]
    aw, s2 = ca.fabs(w), ca.dot(v, v)
    vsmall = ca.logic_and(s2 < SMALL, aw > 0.5)
    sv = ca.sqrt(ca.if_else(vsmall, 1.0, ca.fmax(s2, 1e-300)))
    f = ca.if_else(vsmall, 2 / aw - 2 * s2 / (3 * aw**3), 2 * ca.atan2(sv, aw) / sv)  # |r_p| / |v|
    if band > 0:  # sign(w), the side of the cut, smoothed: odd, 1 beyond w_b = sin(band / 2), C1
        u = w / float(np.sin(0.5 * band))
        side = ca.if_else(ca.fabs(u) >= 1, ca.sign(u), 0.5 * (3 * u - u**3))
    else:
        side = ca.sign(w)
    # sqrt(|r_p|^2 + g^2); cos = 0 at r = 0 unguarded
    norm = ca.sqrt(ca.fmax(f**2 * s2 + guard**2, 1e-300))
    return side * f * ca.dot(v, ca.DM(o_star)) / (norm * float(np.linalg.norm(o_star)))


def posterior(P, H, M, H_inv: np.ndarray | None, solve=ca.solve):
    """The EKF's posterior covariance `(I - K H) P` (CasADi, symmetrised) without the
    cancellation of `P - K H P`, which loses definiteness when the observation is far better than
    the prior (V = 1e-30 against P = 1e6 gave Sigma = 0).

    With `H_inv` (H constant and invertible; I for the identity maps) the observation is that of
    the state itself with noise `M' = H^-1 M H^-T` (`M = R V R^T`), and the posterior the product
    form `P (P + M')^-1 M'`: equal to `P - P S^-1 P` exactly, it only multiplies, so it is as
    accurate as P and M themselves. Otherwise (H depends on the means) the Joseph form
    `A P A^T + K M K^T`, `A = I - K H`: a sum of two positive semidefinite terms, definite for any
    H, accurate while A is not all rounding (K H not I to working precision). `solve(S, B)`:
    `S^-1 B` for the symmetric positive definite S (`surrogate.spd_solve` on SX is shorter).
    """
    if H_inv is not None:
        if not np.array_equal(H_inv, np.eye(NX)):
            M = ca.DM(H_inv) @ M @ ca.DM(H_inv).T
        post = solve(P + M, P).T @ M  # ((P + M')^-1 P)^T M' = P (P + M')^-1 M'
    else:
        KT = solve(H @ P @ H.T + M, H @ P)  # K^T = S^-1 H P (S symmetric)
        A = ca.SX.eye(NX) - KT.T @ H if isinstance(P, ca.SX) else ca.MX.eye(NX) - KT.T @ H
        post = A @ P @ A.T + KT.T @ M @ KT
    return 0.5 * (post + post.T)


@cache  # one Function for every model (a re-plan builds two models)
def _identity_jacobians() -> ca.Function:
    x0, x1 = ca.SX.sym("x0", NM), ca.SX.sym("x1", NM)
    eye = ca.SX.eye(NX)
    return ca.Function("jacobians", [x0, x1], [eye, eye, eye, eye], ["x0", "x1"],
                       ["F", "Q", "H", "R"])


class BeliefModel:
    """Noise models and the EKF belief step as named CasADi Functions.

    Args:
        noise: constants and options.
        camera: intrinsics (for the field-of-view term).
        components: observation components to include; defaults to `noise.components`.
        jacobians: optional Function `(m0, m1) -> (F, Q, H, R)` of the step's two means (7 numbers
            each) for models whose motion or observation maps (in the tangent) are not the identity
            (e.g. built with `casadi.jacobian`).
    """

    def __init__(
        self,
        noise: NoiseParams,
        camera: Intrinsics,
        components: tuple[str, ...] | None = None,
        jacobians: ca.Function | None = None,
    ):
        self.noise = noise
        self.camera = camera
        self.components = tuple(noise.components if components is None else components)
        unknown = set(self.components) - set(COMPONENTS)
        if unknown:
            raise ValueError(f"unknown observation components {sorted(unknown)}; "
                             f"allowed: {COMPONENTS}")
        self.identity_maps = jacobians is None
        self.jacobians = jacobians or _identity_jacobians()

    @cached_property  # (the model's constants: asked on every re-plan)
    def diagonal(self) -> bool:
        """Whether every covariance stays diagonal along any path (exactly).

        True when F = Q = H = R = I and all base covariances are diagonal: then each
        noise matrix is diagonal, and so is every predicted and posterior covariance.
        """
        n = self.noise
        mats = [n.W_p0, n.W_o0, n.V_d0, n.V_f0, n.V_o0, n.V_min, n.Sigma0]
        return (self.identity_maps and not self.joint_noise
                and all(np.count_nonzero(M - np.diag(np.diag(M))) == 0 for M in mats))

    @cached_property
    def joint_noise(self) -> bool:
        """Whether the motion noise has the joint-space term `J diag(sigma_q^2 dq^2) J^T`
        (joint_noise.py): then every step also takes that matrix (vech, from the joints), and the
        covariance is not diagonal."""
        return self.noise.joint_sigma is not None and any(v > 0 for v in self.noise.joint_sigma)

    @cached_property
    def isotropic(self) -> bool:
        """Whether F = Q = H = R = I and every motion and observation base
        matrix is a multiple of I.

        Then each step adds `w I` and observes with `v I`, which keeps the eigenvectors of the
        covariance: from any Sigma_0 the EKF runs as six scalar recursions on its eigenvalues.
        """
        n = self.noise
        mats = [n.W_p0, n.W_o0, n.V_d0, n.V_f0, n.V_o0, n.V_min]
        return (self.identity_maps and not self.joint_noise
                and all(np.array_equal(M, M[0, 0] * np.eye(NX)) for M in mats))

    @property
    def scalar(self) -> bool:
        """Whether the covariance recursion is exactly six independent scalar Kalman recursions."""
        return self.diagonal or self.isotropic

    @cached_property
    def constant_maps(self) -> tuple[np.ndarray, ...] | None:
        """(F, Q, H, R) as NumPy arrays when they do not depend on the means (identity maps
        always), else None."""
        if self.identity_maps:
            return tuple(np.eye(NX) for _ in range(4))
        x0, x1 = ca.SX.sym("m0", NM), ca.SX.sym("m1", NM)
        out = self.jacobians(x0, x1)
        if any(ca.depends_on(M, ca.vertcat(x0, x1)) for M in out):
            return None
        return tuple(np.asarray(ca.evalf(M)) for M in out)

    @cached_property
    def observation_inverse(self) -> np.ndarray | None:
        """H^-1 when H is constant and invertible (condition number below 1e8; I for identity
        maps): the update in product form (`posterior`); None: the Joseph form."""
        maps = self.constant_maps
        if maps is None or np.linalg.cond(maps[2]) > 1e8:
            return None
        return np.eye(NX) if np.array_equal(maps[2], np.eye(NX)) else np.linalg.inv(maps[2])

    @property
    def structured(self) -> bool:
        """Whether Tr(Sigma_T) is a function S(c) of the scalar noise coefficients alone,
        concave and nondecreasing: constant F, Q, H, R and the mean observation noise
        (any SPD base matrices).

        The posterior `P - P H^T (H P H^T + R V R^T)^-1 H P` is a Schur complement, jointly concave
        and nondecreasing in (P, V); the predict step is affine in (Sigma, W); each noise matrix is
        `sum_k c_k M_k` with constant M_k >= 0, and the joint-space term enters W as a matrix
        whose weight is `dS/dW` (positive semidefinite). So the surrogate Hessian and the
        Newton solver apply.
        """
        return self.noise.observation_noise == "mean" and self.constant_maps is not None

    def channel_variances(self, sigma0: np.ndarray) -> np.ndarray:
        """The six scalar recursions' initial variances: Sigma_0's diagonal, or its
        eigenvalues (isotropic)."""
        sigma0 = np.asarray(sigma0, float)
        return np.diag(sigma0) if self.diagonal else np.linalg.eigvalsh(sigma0)

    def recursion_sigma0(self, sigma0: np.ndarray) -> np.ndarray:
        """vech of the initial covariance as the condensed recursion takes it: the channel variances
        on the diagonal for a scalar model, Sigma_0 itself otherwise."""
        sigma0 = np.asarray(sigma0, float)
        return vech(np.diag(self.channel_variances(sigma0)) if self.scalar else sigma0)

    def key(self) -> tuple:
        """Hashable identity of the model's constants (for caching built solvers)."""
        n = self.noise
        mats = tuple(np.asarray(getattr(n, k), float).tobytes()
                     for k in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "V_min", "camera_W_p0",
                               "camera_W_o0"))
        return (mats, n.depth_star, tuple(n.o_star), self.components, n.orientation_formula,
                n.observation_noise, n.objective, n.cosine_guard, n.cut_band, n.joint_sigma,
                tuple(self.camera.to_dict().items()), self.identity_maps or id(self.jacobians))

    def with_components(self, components: tuple[str, ...]) -> BeliefModel:
        """The same model with another set of observation components."""
        return BeliefModel(self.noise, self.camera, components,
                           None if self.identity_maps else self.jacobians)

    def evaluation_model(self) -> BeliefModel:
        """The model every plan is evaluated with: all components, the paper's (mean) noise."""
        noise = replace(self.noise, observation_noise="mean", components=COMPONENTS)
        return BeliefModel(noise, self.camera, COMPONENTS,
                           None if self.identity_maps else self.jacobians)

    # --------------------------------------------------------------- noise models
    def motion_residuals(self, x0, x1):
        """Vectors whose squared norms are the motion coefficients of the step between the
        means x0 -> x1: the translation and the tangent of the relative rotation (its norm is
        the geodesic angle)."""
        return [x1[:3] - x0[:3], quat_step(x0[3:], x1[3:])]

    def motion_coefficients(self, x0, x1):
        """Scalars multiplying (W_p0, W_o0): squared step length [m^2] and squared angle [rad^2]."""
        return [ca.sumsqr(r) for r in self.motion_residuals(x0, x1)]

    def motion_matrices(self) -> list[np.ndarray]:
        return [self.noise.W_p0, self.noise.W_o0]

    def observation_coefficients(self, x, P=None):
        """Scalars multiplying the base matrices of the selected components (same order).

        With `P` (the predicted covariance, 6x6, of the tangent error) and `noise.observation_noise
        == "expected"`, each term is its expectation under that error: exact for the depth term,
        first order for the field-of-view and orientation terms (surestep_method.md, section 8),
        with the orientation residual's Jacobian taken in the tangent (`lie.quat_tangent`).
        """
        expected = P is not None and self.noise.observation_noise == "expected"
        out = []
        for e, i in self.observation_residuals(x):
            c = ca.sumsqr(e)
            if expected:
                # E|e(x + d)|^2 ~ |e(x)|^2 + tr(J P J^T), exact for the (affine) depth residual
                J = (ca.jacobian(e, x[:3]) if i == 0
                     else ca.jacobian(e, x[3:7]) @ quat_tangent(x[3:7]))
                c += ca.trace(J @ P[i : i + 3, i : i + 3] @ J.T)
            out.append(c)
        return out

    def observation_residuals(self, x):
        """Per selected component at the mean x, `(e, i)`: the coefficient (mean form) is
        `|e(x)|^2`, and `e` depends on the position (i = 0) or on the orientation (i = 3, the
        tangent's rows) only."""
        n = self.noise
        p, Q = x[:3], x[3:7]
        out = []
        if "depth" in self.components:
            out.append((p[2] - n.depth_star, 0))
        if "fov" in self.components:
            out.append((ca.vertcat(*self.camera.offset(p)), 0))
        if "orientation" in self.components:
            o = ca.DM(n.o_star)
            if n.orientation_formula == "cosine":
                cos = paper_cosine(Q, n.o_star, n.cosine_guard, n.cut_band)
            else:  # geodesic: cosine of the angle between the rotations
                cos = quat_cos_angle(Q, quat_of(o))
            out.append((1 - cos, 3))
        return out

    def observation_matrices(self) -> list[np.ndarray]:
        n = self.noise
        table = {"depth": n.V_d0, "fov": n.V_f0, "orientation": n.V_o0}
        return [table[c] for c in COMPONENTS if c in self.components]

    def motion_noise_expr(self, x0, x1):
        """W = ||p1 - p0||^2 W_p0 + angle(r0, r1)^2 W_o0."""
        return sum(c * ca.DM(M) for c, M in zip(self.motion_coefficients(x0, x1),
                                                self.motion_matrices()))

    def observation_noise_expr(self, x, P=None):
        """V(x) = sum of the selected depth, field-of-view and orientation terms
        (see coefficients)."""
        V = ca.DM(self.noise.V_min) + (ca.SX.zeros(NX, NX) if isinstance(x, ca.SX)
                                       else ca.MX.zeros(NX, NX))
        for c, M in zip(self.observation_coefficients(x, P), self.observation_matrices()):
            V += c * ca.DM(M)
        return V

    @shared_function
    def motion_noise(self) -> ca.Function:
        x0, x1 = ca.SX.sym("x0", NM), ca.SX.sym("x1", NM)
        return ca.Function("motion_noise", [x0, x1], [self.motion_noise_expr(x0, x1)], ["x0", "x1"],
                           ["W"])

    @shared_function
    def planning_noise(self) -> ca.Function:
        """V used by the planner's EKF step: `(x, P_pred vech) -> V` (equals
        `observation_noise` in mean form)."""
        x, p = ca.SX.sym("x", NM), ca.SX.sym("sigma_pred", NV)
        return ca.Function("planning_noise", [x, p], [self.observation_noise_expr(x, unvech(p))],
                           ["x", "sigma_pred"], ["V"])

    @shared_function
    def observation_noise(self) -> ca.Function:
        x = ca.SX.sym("x", NM)
        return ca.Function("observation_noise", [x], [self.observation_noise_expr(x)], ["x"], ["V"])

    # --------------------------------------------------------------- EKF
    def predict_expr(self, x0, x1, s, w=None):
        """vech of the predicted covariance P (the prior before observing x1); `w`: vech of a
        further motion noise of the step (the joint-space term, joint_noise.py), added to W."""
        F, Q, _, _ = self.jacobians(x0, x1)
        W = self.motion_noise(x0, x1) if w is None else self.motion_noise(x0, x1) + unvech(w)
        return vech(F @ unvech(s) @ F.T + Q @ W @ Q.T)

    def innovation_expr(self, x0, x1, p):
        """(S, H) of the update at x1 given the predicted covariance vech `p`."""
        S, H, _ = self.observation_expr(x0, x1, p)
        return S, H

    def observation_expr(self, x0, x1, p):
        """(S, H, M) of the update at x1 given the predicted covariance vech `p`: the innovation
        covariance `S = H P H^T + M`, `M = R V R^T` the observation noise as observed."""
        _, _, H, R = self.jacobians(x0, x1)
        M = R @ self.planning_noise(x1, p) @ R.T
        return H @ unvech(p) @ H.T + M, H, M

    def step_expr(self, x0, x1, s, w=None):
        """vech(Sigma_t+1|t+1) from vech(Sigma_t|t) for the step x0 -> x1 (`w`:
        see `predict_expr`)."""
        p = self.predict_expr(x0, x1, s, w)
        P = unvech(p)
        _, H, M = self.observation_expr(x0, x1, p)
        return vech(posterior(P, H, M, self.observation_inverse))

    @shared_function
    def predict(self) -> ca.Function:
        x0, x1, s = ca.SX.sym("x0", NM), ca.SX.sym("x1", NM), ca.SX.sym("sigma", NV)
        return ca.Function("predict", [x0, x1, s], [self.predict_expr(x0, x1, s)],
                           ["x0", "x1", "sigma"], ["sigma_pred"])

    @shared_function
    def step(self) -> ca.Function:
        x0, x1, s = ca.SX.sym("x0", NM), ca.SX.sym("x1", NM), ca.SX.sym("sigma", NV)
        return ca.Function("belief_step", [x0, x1, s], [self.step_expr(x0, x1, s)],
                           ["x0", "x1", "sigma"], ["sigma_next"])

    def sigma0_vech(self) -> np.ndarray:
        return vech(np.asarray(self.noise.Sigma0, dtype=float))

    def camera_change(self, x: np.ndarray, s: np.ndarray,
                      D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A camera move (NumPy): `(mean, vech sigma, D) -> (mean', vech sigma')`, D (4x4) maps old
        to new camera coordinates.

        The mean is re-expressed in the new camera frame (`p' = R_D p + t`, `Q' = Q_D Q`); the
        tangent error rotates with the frame (`F = diag(R_D, R_D)`, exact for left perturbations),
        plus motion noise of the camera's own displacement,
        `|t|^2 camera_W_p0 + angle(R_D)^2 camera_W_o0` (ECM cable stretch).
        """
        x, D = np.asarray(x, float).ravel(), np.asarray(D, float)
        Rd, td = D[:3, :3], D[:3, 3]
        xn = np.concatenate([Rd @ x[:3] + td, quat_mul(np_quat_of_matrix(Rd), x[3:7])])
        F = np.zeros((NX, NX))
        F[:3, :3] = F[3:, 3:] = Rd
        n = self.noise
        W = ((td @ td) * np.asarray(n.camera_W_p0, float)
             + float(np.linalg.norm(np_log(Rd))) ** 2 * np.asarray(n.camera_W_o0, float))
        return xn, vech(F @ unvech(np.asarray(s, float).ravel()) @ F.T + W)

    @shared_function
    def step_pair(self) -> ca.Function:
        """`(x0, x1, sigma, w) -> (sigma_next, sigma_pred)`: `step` and `predict` in one Function,
        with the step's further motion noise `w` (vech; the joint-space term) as a fourth input."""
        x0, x1, s, w = (ca.SX.sym("x0", NM), ca.SX.sym("x1", NM), ca.SX.sym("sigma", NV),
                        ca.SX.sym("w", NV))
        return ca.Function("belief_step_pair", [x0, x1, s, w], [self.step_expr(x0, x1, s, w),
                                                                 self.predict_expr(x0, x1, s, w)])

    def _roll(self, T: int) -> ca.Function:
        """`step_pair` accumulated over T steps (mapaccum: one step's code whatever T),
        shared like the others."""
        return _shared(self, ("roll", T),
                       lambda: self.step_pair.mapaccum("belief_roll", T, [2], [0]))

    def propagate(self, poses: np.ndarray, changes: list | None = None,
                  sigma0: np.ndarray | None = None,
                  joint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Covariances along a trajectory of poses under maximum likelihood
        (`propagate_means` of their means).

        Args:
            poses: (T+1, 6) waypoints `(p, r)`, each in the camera frame of its own step.
            changes: optional list of T camera moves; entry t (4x4 or None) maps the camera
                frame of step t to that of step t+1 and is applied before the step t -> t+1.
            sigma0: initial covariance (default: the model's Sigma0).
            joint: (T, 21) vech of each step's joint-space motion noise (`Setup.joint_noises`);
                required exactly when the model has that term, so it is never dropped silently.

        Returns:
            (sigmas (T+1, 6, 6) posterior covariances Sigma_t|t, predicted (T, 6, 6) Sigma_t+1|t).
        """
        return self.propagate_means(np_means(poses), changes, sigma0, joint)

    def propagate_means(self, poses: np.ndarray, changes: list | None = None,
                        sigma0: np.ndarray | None = None,
                        joint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`propagate` along (T+1, 7) means `(p, Q)`."""
        poses = np.asarray(poses, dtype=float)
        if (joint is not None) != self.joint_noise:
            raise ValueError("propagate: the joint-space motion noise (`joint`) is given exactly "
                             "when the model has it")
        s = self.sigma0_vech() if sigma0 is None else vech(np.asarray(sigma0, float))
        T = len(poses) - 1
        w = np.zeros((NV, T)) if joint is None else np.asarray(joint, float).T  # W + 0 is W exactly
        if T > 0 and (changes is None or all(c is None for c in changes)):
            # one call over the horizon
            post, prior = (np.asarray(v) for v in self._roll(T)(poses[:-1].T, poses[1:].T, s, w))
            return np.concatenate([unvech(s)[None], unvech_many(post.T)]), unvech_many(prior.T)
        sig, pred = [unvech(s)], []
        for t in range(T):
            x0 = poses[t]
            if changes is not None and changes[t] is not None:
                x0, s = self.camera_change(x0, s, changes[t])
            s, p = (np.asarray(v).ravel() for v in self.step_pair(x0, poses[t + 1], s, w[:, t]))
            pred.append(unvech(p))
            sig.append(unvech(s))
        return np.array(sig), np.array(pred)


def entropy(sigma: np.ndarray) -> float:
    """Differential entropy [nats] of a Gaussian with covariance `sigma`."""
    n = sigma.shape[0]
    sign, logdet = np.linalg.slogdet(sigma)
    if sign <= 0:
        return float("-inf")
    return float(0.5 * (n * (1 + np.log(2 * np.pi)) + logdet))
