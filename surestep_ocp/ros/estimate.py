"""The tracker's estimate as the planner takes it: a ROS 2 PoseWithCovarianceStamped (camera frame)
as a mean `[p, axis-angle]` and a 6x6 covariance (ROS's order: x, y, z, then rotations about X, Y,
Z, the mean's), and moved along the commanded motion from the image's time to the waypoint a
re-plan starts at.

The estimate is of the tool when the image was taken (its stamp); the re-plan starts at a later
waypoint k. The tool's motion between is the kinematics' (its pose at the joints at the stamp to
its pose at the joints at k, in the camera frame), so the camera registration the planner makes
from the moved estimate at k is the one the stamp's estimate and joints give.

Both run between an estimate's arrival and its re-plan, so they are plain NumPy on unit
quaternions (x, y, z, w): tens of microseconds, against some hundreds through scipy's Rotation.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation


def from_message(msg) -> tuple[np.ndarray, np.ndarray, bool]:
    """(mean (6,), covariance (6, 6), finite) of a PoseWithCovarianceStamped."""
    p, o = msg.pose.pose.position, msg.pose.pose.orientation
    quat = np.array([o.x, o.y, o.z, o.w], float)
    cov = np.array(msg.pose.covariance, float).reshape(6, 6)
    pos = np.array([p.x, p.y, p.z], float)
    finite = bool(np.all(np.isfinite(quat)) and np.all(np.isfinite(cov))
                  and np.all(np.isfinite(pos)) and np.linalg.norm(quat) > 1e-6)
    if not finite:
        return np.full(6, np.nan), cov, False
    return np.hstack([pos, _rotvec(quat)]), cov, True


def goal_from_message(msg) -> np.ndarray | None:
    """A PoseStamped's pose as `[p, axis-angle]` (the camera frame), or None when not finite or
    its quaternion is zero."""
    p, o = msg.pose.position, msg.pose.orientation
    pos, quat = np.array([p.x, p.y, p.z], float), np.array([o.x, o.y, o.z, o.w], float)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(quat))
            and np.linalg.norm(quat) > 1e-6):
        return None
    return np.hstack([pos, Rotation.from_quat(quat).as_rotvec()])


def quaternion(rotvec) -> np.ndarray:
    """(x, y, z, w) of an axis-angle rotation."""
    return Rotation.from_rotvec(np.asarray(rotvec, float)).as_quat()


def moved(mean, pose_then, pose_at_k) -> np.ndarray:
    """The estimate `mean` (tool at `pose_then`, the kinematics' pose at the image's time) moved to
    the kinematics' `pose_at_k`: T_mean inv(T_then) T_k, as `[p, axis-angle]`."""
    mean, then, at_k = (np.asarray(x, float).tolist() for x in (mean, pose_then, pose_at_k))
    rel = _qmul(_quat(mean[3:]), _qconj(_quat(then[3:])))  # R_mean R_then^T
    d = _rotate(rel, [at_k[i] - then[i] for i in range(3)])
    return np.array([mean[0] + d[0], mean[1] + d[1], mean[2] + d[2],
                     *_rotvec(_qmul(rel, _quat(at_k[3:])))])


# unit quaternions (x, y, z, w) as tuples of floats: a few of these cost microseconds
def _quat(rotvec) -> tuple:
    """Of an axis-angle rotation."""
    x, y, z = (float(c) for c in rotvec)
    angle = math.sqrt(x * x + y * y + z * z)
    f = 0.5 if angle < 1e-12 else math.sin(0.5 * angle) / angle
    return (f * x, f * y, f * z, math.cos(0.5 * angle))


def _rotvec(q) -> tuple:
    """Axis-angle (angle in [0, pi]) of a quaternion, not necessarily unit."""
    x, y, z, w = (float(c) for c in q)
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    s = math.sqrt(x * x + y * y + z * z)
    f = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    return (f * x, f * y, f * z)


def _qmul(a, b) -> tuple:
    """The product a b: the rotation b, then a."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + bw * ax + ay * bz - az * by, aw * by + bw * ay + az * bx - ax * bz,
            aw * bz + bw * az + ax * by - ay * bx, aw * bw - ax * bx - ay * by - az * bz)


def _qconj(q) -> tuple:
    return (-q[0], -q[1], -q[2], q[3])


def _rotate(q, v) -> tuple:
    """The vector v rotated by the unit quaternion q."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty, vy + w * ty + z * tx - x * tz,
            vz + w * tz + x * ty - y * tx)
