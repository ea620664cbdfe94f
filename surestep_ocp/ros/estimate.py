"""The tracker's estimate as the planner takes it: a ROS 2 PoseWithCovarianceStamped (camera frame)
as a mean `[p, axis-angle]` and a 6x6 covariance (ROS's order: x, y, z, then rotations about X, Y,
Z, the mean's), and moved along the commanded motion from the image's time to the waypoint a
re-plan starts at.

The estimate is of the tool when the image was taken (its stamp); the re-plan starts at a later
waypoint k. The tool's motion between is the kinematics' (its pose at the joints at the stamp to
its pose at the joints at k, in the camera frame), so the camera registration the planner makes
from the moved estimate at k is the one the stamp's estimate and joints give.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..model.lie import pose_to_matrix


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
    return np.hstack([pos, Rotation.from_quat(quat).as_rotvec()]), cov, True


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
    T = pose_to_matrix(np.asarray(mean, float)) @ np.linalg.solve(
        pose_to_matrix(np.asarray(pose_then, float)), pose_to_matrix(np.asarray(pose_at_k, float)))
    return np.hstack([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])
