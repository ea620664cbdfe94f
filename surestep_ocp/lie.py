"""Rotation helpers, symbolic (CasADi SX/MX) and numeric (NumPy), smooth everywhere we use them.

Axis-angle vectors `r` [rad] parametrise rotations, `R = exp(r)`. The symbolic
maps avoid the 0/0 at the identity with a Taylor branch evaluated on a safe
argument (so automatic differentiation never meets a NaN in the unused branch).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

_SMALL = 1e-12  # [rad^2] below this squared angle the Taylor branches are used


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
    safe = ca.if_else(th2 < _SMALL, 1.0, th2)
    th = ca.sqrt(safe)
    a = ca.if_else(th2 < _SMALL, 1 - th2 / 6 + th2**2 / 120, ca.sin(th) / th)
    b = ca.if_else(th2 < _SMALL, 0.5 - th2 / 24 + th2**2 / 720, (1 - ca.cos(th)) / safe)
    k = skew(r)
    return ca.DM.eye(3) + a * k + b * (k @ k)


def so3_log(R):
    """Axis-angle vector of the rotation matrix `R` (CasADi expression).

    Smooth on angles in [0, pi); at exactly pi the axis-angle chart is singular.
    """
    v = 0.5 * ca.vertcat(R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1])  # sin(th) * axis
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1)  # cos(th)
    s2 = ca.dot(v, v)
    small = ca.logic_and(s2 < _SMALL, c > 0)  # near the identity only; near pi sin(th) is small too
    safe = ca.if_else(small, 1.0, ca.fmax(s2, 1e-300))
    s = ca.sqrt(safe)
    f = ca.if_else(small, 1 + s2 / 6 + 3 * s2**2 / 40, ca.atan2(s, c) / s)
    return f * v


def angle_sq(Ra, Rb):
    """Squared geodesic angle [rad^2] between two rotation matrices (CasADi)."""
    r = so3_log(Ra.T @ Rb)
    return ca.dot(r, r)


# ---------------------------------------------------------------- NumPy versions


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
    v = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    s = np.linalg.norm(v, axis=1)
    th = np.arctan2(s, c)
    out = np.where((s < 1e-9)[:, None], v, (th / np.where(s < 1e-9, 1.0, s))[:, None] * v)
    for k in np.flatnonzero((s < 1e-9) & (c <= 0)):  # angle near pi: the axis from the symmetric part
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
