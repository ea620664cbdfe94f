"""A plain NumPy EKF belief model, written from surestep_method.md sections 3-4.

Independent of the package's CasADi code: rotations come from
`scipy.spatial.transform.Rotation`, the noise models and the EKF step are the
textbook formulas. Only plain data (noise constants, intrinsics) is read from
the package's objects, by attribute name.

State `x = (p, r)`: position [m] and axis-angle orientation [rad], camera frame.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

ALL_COMPONENTS = ("depth", "fov", "orientation")
I6 = np.eye(6)


def geodesic_angle(ra, rb) -> float:
    """Angle [rad] of the relative rotation R(ra)^T R(rb)."""
    return float((Rotation.from_rotvec(ra).inv() * Rotation.from_rotvec(rb)).magnitude())


def motion_noise(x0, x1, noise) -> np.ndarray:
    """W = ||p1 - p0||^2 W_p0 + angle(r0, r1)^2 W_o0."""
    x0, x1 = np.asarray(x0, float), np.asarray(x1, float)
    dp = x1[:3] - x0[:3]
    return float(dp @ dp) * np.asarray(noise.W_p0) + geodesic_angle(
        x0[3:], x1[3:]
    ) ** 2 * np.asarray(noise.W_o0)


def image_offset(p, camera) -> tuple[float, float]:
    """Pinhole projection (u, v) minus the image centre, on the normalised plane."""
    u = camera.fx * p[0] / p[2] + camera.cx
    v = camera.fy * p[1] / p[2] + camera.cy
    return (u - camera.width / 2) / camera.fx, (v - camera.height / 2) / camera.fy


def observation_noise(
    x, noise, camera, components=ALL_COMPONENTS, formula="cosine", guard: float = 0.0,
    band: float = 0.0
) -> np.ndarray:
    """V(x) = depth + field-of-view + orientation terms (those in `components`).

    `guard` [rad^2] is added under the square root of |r|^2 in the cosine formula (undefined at
    r = 0, section 4: "guard it"); 0 gives the paper's formula exactly. The cosine is taken of the
    principal rotation vector (angle in [0, pi], scipy's); `band` [rad] > 0 fades it to 0 over the
    angles (pi - band, pi] by the smoothstep (3u - u^3) / 2, u = cos(angle / 2) / sin(band / 2).
    """
    x = np.asarray(x, float)
    p, r = x[:3], x[3:]
    o = np.asarray(noise.o_star, float)
    # the noise floor (0 in the paper)
    V = np.array(getattr(noise, "V_min", np.zeros((6, 6))), float)
    if "depth" in components:
        V += (p[2] - noise.depth_star) ** 2 * np.asarray(noise.V_d0)
    if "fov" in components:
        du, dv = image_offset(p, camera)
        V += (du**2 + dv**2) * np.asarray(noise.V_f0)
    if "orientation" in components:
        if formula == "cosine":  # the paper's cosine between the axis-angle vectors
            r = Rotation.from_rotvec(r).as_rotvec()  # the principal vector
            cos = float(r @ o) / (np.sqrt(r @ r + guard) * np.linalg.norm(o))
            u = np.cos(0.5 * np.linalg.norm(r)) / np.sin(0.5 * band) if band > 0 else 1.0
            cos *= 1.0 if u >= 1 else 0.5 * (3 * u - u**3)
        elif formula == "geodesic":
            cos = np.cos(geodesic_angle(r, o))
        else:
            raise ValueError(formula)
        V += (1.0 - cos) ** 2 * np.asarray(noise.V_o0)
    return V


def ekf_step(sigma, W, V, F=I6, Q=I6, H=I6, R=I6):
    """EKF covariance step: (posterior, predicted), the posterior in a form that cannot lose
    definiteness to cancellation: the information form `(P^-1 + H^T M^-1 H)^-1` (M = R V R^T)
    where P and M are invertible, else the Joseph form `(I - K H) P (I - K H)^T + K M K^T`."""
    P = F @ sigma @ F.T + Q @ W @ Q.T
    M = R @ V @ R.T
    post = information_posterior(P, M, H)
    if post is None:
        S = H @ P @ H.T + M
        K = P @ H.T @ np.linalg.inv(S)
        A = np.eye(len(P)) - K @ H
        post = A @ P @ A.T + K @ M @ K.T
    return 0.5 * (post + post.T), P


def information_posterior(P, M, H=I6):
    """`(P^-1 + H^T M^-1 H)^-1`, or None when P or M is not invertible to working precision."""
    if max(np.linalg.cond(P), np.linalg.cond(M)) > 1e12:
        return None
    return np.linalg.inv(np.linalg.inv(P) + H.T @ np.linalg.inv(M) @ H)


def propagate(
    poses, noise, camera, components=ALL_COMPONENTS, formula=None, jacobians=None, guard=0.0,
    band=None, extra_W=None,
):
    """Posterior covariances (T+1, 6, 6) and predicted ones (T, 6, 6) along `poses` (T+1, 6).

    `jacobians(x0, x1) -> (F, Q, H, R)` (NumPy arrays); identity when omitted.
    `extra_W`: T further motion noise matrices (6x6) added to each step's W (the joint-space term).
    `formula` defaults to `noise.orientation_formula`, `band` to `noise.cut_band` (0 if absent).
    """
    formula = formula or getattr(noise, "orientation_formula", "cosine")
    band = getattr(noise, "cut_band", 0.0) if band is None else band
    poses = np.asarray(poses, float)
    sig = np.asarray(noise.Sigma0, float)
    sigmas, preds = [sig], []
    for t in range(len(poses) - 1):
        x0, x1 = poses[t], poses[t + 1]
        F, Q, H, R = jacobians(x0, x1) if jacobians is not None else (I6, I6, I6, I6)
        W = motion_noise(x0, x1, noise) + (0 if extra_W is None else np.asarray(extra_W[t], float))
        V = observation_noise(x1, noise, camera, components, formula, guard, band)
        sig, P = ekf_step(sig, W, V, F, Q, H, R)
        sigmas.append(sig)
        preds.append(P)
    return np.array(sigmas), np.array(preds)


def rel_err(a, b) -> float:
    """Largest entry-wise difference relative to the largest entry of `b`."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def camera_frame_pose(robot, T_cam_base, q) -> np.ndarray:
    """[p, rotation vector] of the tracked frame in the camera frame, from Pinocchio's FK
    (`robot.frame_pose`) and scipy's principal rotation vector."""
    M = T_cam_base @ robot.frame_pose(q)
    return np.concatenate([M[:3, 3], Rotation.from_matrix(M[:3, :3]).as_rotvec()])


def joint_motion_noise(robot, T_cam_base, q0, q1, sigma, h=1e-6) -> np.ndarray:
    """`J diag(sigma^2 (q1 - q0)^2) J^T` with J the central-difference Jacobian at q0 in the
    belief's tangent:
    the position's, and the rotation's as a left (camera-frame) perturbation,
    `log(R(q0 +- h e_j) R(q0)^T)`."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    M0 = T_cam_base @ robot.frame_pose(q0)
    R0 = Rotation.from_matrix(M0[:3, :3])
    J = np.zeros((6, len(q0)))
    for j in range(len(q0)):
        e = np.zeros(len(q0))
        e[j] = h
        Mp, Mm = (T_cam_base @ robot.frame_pose(q0 + e)), (T_cam_base @ robot.frame_pose(q0 - e))
        J[:3, j] = (Mp[:3, 3] - Mm[:3, 3]) / (2 * h)
        J[3:, j] = ((Rotation.from_matrix(Mp[:3, :3]) * R0.inv()).as_rotvec()
                    - (Rotation.from_matrix(Mm[:3, :3]) * R0.inv()).as_rotvec()) / (2 * h)
    D = np.diag((np.asarray(sigma, float) * (q1 - q0)) ** 2)
    return J @ D @ J.T
