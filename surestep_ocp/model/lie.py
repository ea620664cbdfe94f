"""Rotation helpers, symbolic (CasADi SX/MX) and numeric (NumPy), smooth everywhere we use them.

Axis-angle vectors `r` [rad] parametrise rotations, `R = exp(r)`. The symbolic
maps avoid the 0/0 at the identity with a Taylor branch evaluated on a safe
argument (so automatic differentiation never meets a NaN in the unused branch).

The belief's means are rotation-valued (docs/orientation.md): a mean is `m = (p, Q)`,
seven numbers, the position and a unit quaternion `(w, x, y, z)` (the double cover of
SO(3), continuous along any joint path). Errors, noises and covariances live in the
tangent at the mean, as left (camera-frame) perturbations `Q_true = exp(e) Q`; residuals
between two means are the tangent of the relative rotation (`quat_step`), near the
identity. Axis-angle vectors are the poses' storage format (solutions, the gradient
variant's decision space); `pose_mean` / `np_means` convert them to means.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

SMALL = 1e-12  # [rad^2] below this squared angle the Taylor branches are used


def skew(v):
    """3x3 skew-symmetric matrix of a 3-vector (CasADi)."""
    return ca.vertcat(
        ca.horzcat(0, -v[2], v[1]),
        ca.horzcat(v[2], 0, -v[0]),
        ca.horzcat(-v[1], v[0], 0),
    )


def so3_exp(r):
    """Rotation matrix of the axis-angle vector `r` (CasADi expression)."""
    th2 = ca.dot(r, r)
    safe = ca.if_else(th2 < SMALL, 1.0, th2)
    th = ca.sqrt(safe)
    a = ca.if_else(th2 < SMALL, 1 - th2 / 6 + th2**2 / 120, ca.sin(th) / th)
    b = ca.if_else(th2 < SMALL, 0.5 - th2 / 24 + th2**2 / 720, (1 - ca.cos(th)) / safe)
    k = skew(r)
    return ca.DM.eye(3) + a * k + b * (k @ k)


def so3_log(R):
    """Axis-angle vector of the rotation matrix `R` (CasADi expression).

    Smooth on angles in [0, pi); at exactly pi the axis-angle chart is singular.
    """
    v = 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])  # sin(th) * axis
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1)  # cos(th)
    s2 = ca.dot(v, v)
    small = ca.logic_and(s2 < SMALL, c > 0)  # near the identity only; near pi sin(th) is small too
    safe = ca.if_else(small, 1.0, ca.fmax(s2, 1e-300))
    s = ca.sqrt(safe)
    f = ca.if_else(small, 1 + s2 / 6 + 3 * s2**2 / 40, ca.atan2(s, c) / s)
    return f * v


def angle_sq(Ra, Rb):
    """Squared geodesic angle [rad^2] between two rotation matrices (CasADi)."""
    r = so3_log(Ra.T @ Rb)
    return ca.dot(r, r)


def quat_mul(a, b):
    """Hamilton product of two quaternions `(w, x, y, z)` (CasADi or NumPy 4-vectors)."""
    va, vb = a[1:], b[1:]
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return np.concatenate([[a[0] * b[0] - va @ vb], a[0] * vb + b[0] * va + np.cross(va, vb)])
    return ca.vertcat(a[0] * b[0] - ca.dot(va, vb), a[0] * vb + b[0] * va + ca.cross(va, vb))


def quat_of(r):
    """Unit quaternion `(w, x, y, z)` of the rotation vector `r` (CasADi), any angle
    (w < 0 beyond pi)."""
    th2 = ca.dot(r, r)
    small = th2 < SMALL
    th = ca.sqrt(ca.if_else(small, 1.0, th2))
    w = ca.if_else(small, 1 - th2 / 8, ca.cos(0.5 * th))
    k = ca.if_else(small, 0.5 - th2 / 48, ca.sin(0.5 * th) / th)
    return ca.vertcat(w, k * r)


def quat_rotvec(Q):
    """Rotation vector of a unit quaternion (CasADi), angle `2 atan2(|v|, w)` in [0, 2 pi).

    Smooth except at `Q = (-1, 0, 0, 0)` (a full turn): the chart of the double cover, with
    no cut at pi.
    """
    w, v = Q[0], Q[1:]
    s2 = ca.dot(v, v)
    small = ca.logic_and(s2 < SMALL, w > 0)
    safe = ca.if_else(small, 1.0, ca.fmax(s2, 1e-300))
    s = ca.sqrt(safe)
    f = ca.if_else(small, 2 / w - 2 * s2 / (3 * w**3), 2 * ca.atan2(s, w) / s)
    return f * v


def quat_conj(Q):
    """Conjugate (the inverse rotation) of a unit quaternion (CasADi)."""
    return ca.vertcat(Q[0], -Q[1:])


def quat_step(Qa, Qb):
    """Rotation vector of the relative rotation `Qa^* Qb` (from a to b in a's frame, angle in [0,
    pi]), CasADi: the tangent residual between two orientation means; the sign of either
    quaternion does not matter."""
    D = quat_mul(quat_conj(Qa), Qb)
    return quat_rotvec(ca.if_else(D[0] < 0, -D, D))


def quat_cos_angle(Qa, Qb):
    """Cosine of the geodesic angle between two rotations given as unit quaternions,
    `2 (Qa.Qb)^2 - 1` (CasADi)."""
    return 2 * ca.dot(Qa, Qb) ** 2 - 1


def quat_tangent(Q):
    """E (4x3) with `dQ = E w` for a left (camera-frame) perturbation `exp(w) Q` at w = 0
    (CasADi); for a unit Q, `E^T E = I / 4`, so `w = 4 E^T dQ`: the map from quaternion
    derivatives to tangent ones."""
    w, v = Q[0], Q[1:]
    return 0.5 * ca.vertcat(-v.T, w * ca.DM.eye(3) - skew(v))


def pose_mean(x):
    """The mean `(p, Q)` (7) of a pose `(p, r)` (6), CasADi: the quaternion of
    the rotation vector."""
    return ca.vertcat(x[:3], quat_of(x[3:6]))


# ---------------------------------------------------------------- NumPy versions


def np_quat_of_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion `(w, x, y, z)` of a rotation matrix (scipy's, reordered; either sign)."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, float)).as_quat()
    return np.array([w, x, y, z])


def np_means(poses: np.ndarray) -> np.ndarray:
    """(N, 7) means `(p, Q)` of (N, 6) poses `(p, r)`: `Q = np_quat(r)` (so a continued vector
    keeps its sheet)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    return np.hstack([poses[:, :3], np_quat(poses[:, 3:])])


def np_poses(means: np.ndarray, flip_w: float = 0.9) -> np.ndarray:
    """(N, 6) poses `(p, r)` of (N, 7) means: r the log of Q (angle in [0, 2 pi), the double cover's
    vector, so it continues along the sheet of Q), with Q's sign flipped where w < -flip_w (near a
    full turn the log is singular; past 2 acos(-flip_w), 5.4 rad, the other vector of the same
    rotation is used)."""
    m = np.asarray(means, dtype=float).reshape(-1, 7)
    Q = np.where((m[:, 3] < -flip_w)[:, None], -m[:, 3:], m[:, 3:])
    return np.hstack([m[:, :3], np_quat_rotvec(Q)])


def np_quat(r: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions `(w, x, y, z)` of (N, 3) rotation vectors, any angle (w < 0 beyond pi)."""
    r = np.asarray(r, dtype=float).reshape(-1, 3)
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-8
    k = np.where(small, 0.5 - th**2 / 48, np.sin(0.5 * th) / np.where(small, 1.0, th))
    return np.hstack([np.cos(0.5 * th)[:, None], k[:, None] * r])


def np_quat_rotvec(Q: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors of (N, 4) unit quaternions, angle `2 atan2(|v|, w)` in [0, 2 pi]."""
    Q = np.asarray(Q, dtype=float).reshape(-1, 4)
    s = np.linalg.norm(Q[:, 1:], axis=1)
    small = s < 1e-9
    f = np.where(small, 2 / np.where(small, Q[:, 0], 1.0),
                 2 * np.arctan2(s, Q[:, 0]) / np.where(small, 1.0, s))
    return f[:, None] * Q[:, 1:]


def continued(r: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors of the rotations `exp(r_i)`, each continued to the side of
    `reference_i` (the representative whose quaternion is nearest the reference's), e.g. a goal pose
    on the side of the mean at its joints (`problem.setup`)."""
    Q, ref = np_quat(r), np_quat(np.broadcast_to(reference, np.shape(np.asarray(r).reshape(-1, 3))))
    return np_quat_rotvec(np.where((np.sum(Q * ref, axis=1) < 0)[:, None], -Q, Q))


def continued_along(r: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors of the rotations `exp(r_i)`, continued along the sequence from
    `r_0` (kept): each quaternion on the side of its predecessor's (steps below pi), so no vector
    jumps at the cut."""
    Q = np_quat(r)
    for i in range(1, len(Q)):
        if Q[i] @ Q[i - 1] < 0:
            Q[i] = -Q[i]
    out = np_quat_rotvec(Q)
    out[0] = np.asarray(r, float).reshape(-1, 3)[0]
    return out




def np_exp(r: np.ndarray) -> np.ndarray:
    """Rotation matrix of an axis-angle vector (NumPy)."""
    r = np.asarray(r, dtype=float)
    th = float(np.linalg.norm(r))
    k = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    if th < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * k @ k


def np_log(R: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (NumPy), angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    c = np.clip(0.5 * (np.trace(R) - 1), -1.0, 1.0)
    v = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(v))
    th = float(np.arctan2(s, c))
    if s < 1e-9:
        if c > 0:
            return v
        # angle near pi: axis from the symmetric part
        B = 0.5 * (R + np.eye(3))
        axis = np.sqrt(np.clip(np.diag(B), 0, None))
        i = int(np.argmax(axis))
        axis = B[i] / np.sqrt(B[i, i])
        return np.pi * axis / np.linalg.norm(axis)
    return th / s * v


def np_angle(ra: np.ndarray, rb: np.ndarray) -> float:
    """Geodesic angle [rad] between two axis-angle orientations (NumPy)."""
    return float(np.linalg.norm(np_log(np_exp(ra).T @ np_exp(rb))))


def slerp(ra: np.ndarray, rb: np.ndarray, s: float) -> np.ndarray:
    """Axis-angle of the geodesic interpolation from `ra` (s=0) to `rb` (s=1)."""
    Ra = np_exp(ra)
    return np_log(Ra @ np_exp(s * np_log(Ra.T @ np_exp(rb))))


def slerp_many(ra: np.ndarray, rb: np.ndarray, s: np.ndarray) -> np.ndarray:
    """`slerp(ra, rb, s_i)` for every s_i, as rows (vectorised; angles in [0, pi])."""
    Ra = np_exp(ra)
    rel = np_log(Ra.T @ np_exp(rb))
    R = Ra @ np_exp_many(np.outer(s, rel))
    return np_log_many(R)


def np_exp_many(r: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 3) axis-angle vectors (Rodrigues, vectorised)."""
    r = np.asarray(r, dtype=float).reshape(-1, 3)
    th = np.linalg.norm(r, axis=1)
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    K -= K.transpose(0, 2, 1)
    small = th < 1e-8
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1 - np.cos(safe)) / safe**2)
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def np_log_many(R: np.ndarray) -> np.ndarray:
    """(N, 3) axis-angle vectors of (N, 3, 3) rotations; `np_log` where the angle is near pi."""
    R = np.asarray(R, dtype=float)
    c = np.clip(0.5 * (np.trace(R, axis1=1, axis2=2) - 1), -1.0, 1.0)
    v = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]],
                       axis=1)
    s = np.linalg.norm(v, axis=1)
    th = np.arctan2(s, c)
    out = np.where((s < 1e-9)[:, None], v, (th / np.where(s < 1e-9, 1.0, s))[:, None] * v)
    for k in np.flatnonzero((s < 1e-9) & (c <= 0)):
        # angle near pi: the axis from the symmetric part
        out[k] = np_log(R[k])
    return out


def pose_to_matrix(x: np.ndarray) -> np.ndarray:
    """4x4 homogeneous matrix of a pose `[px, py, pz, rx, ry, rz]`."""
    T = np.eye(4)
    T[:3, :3] = np_exp(np.asarray(x)[3:6])
    T[:3, 3] = np.asarray(x)[:3]
    return T


def matrix_to_pose(T: np.ndarray) -> np.ndarray:
    """Pose `[px, py, pz, rx, ry, rz]` of a 4x4 homogeneous matrix."""
    return np.concatenate([np.asarray(T)[:3, 3], np_log(np.asarray(T)[:3, :3])])


def rpy_matrix(rpy) -> np.ndarray:
    """Rotation of URDF roll-pitch-yaw angles [rad]: Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
