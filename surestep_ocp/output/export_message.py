"""The exported trajectory as every format writes it: its channels (the arm's joints and the jaw),
the joint names written (`joint_names.py`), the ROS 2 `trajectory_msgs/JointTrajectory` message
of a channel as a plain mapping, and the timing line; shared by the file writers
(`export_writers.py`) and the bag (`export_rosbag.py`).
"""

from __future__ import annotations

import math

from ..model.limits import CURVE_NAME, JAW
from ..model.limits.retiming import Trajectory
from .joint_names import JointNaming

FORMAT_ID = "surestep-joint-trajectory/1"


def channels(traj: Trajectory) -> tuple[list[int], list[int]]:
    """Indices of the arm joints and of the jaw (empty without one)."""
    arm = [i for i, n in enumerate(traj.joint_names) if n != JAW]
    jaw = [i for i, n in enumerate(traj.joint_names) if n == JAW]
    return arm, jaw


def written_names(traj: Trajectory, naming: JointNaming | None) -> list[str]:
    """The names written for `traj.joint_names` (the URDF's without a naming)."""
    return list(traj.joint_names) if naming is None else naming.of(traj.joint_names)


def duration_msg(t: float) -> dict:
    """builtin_interfaces/Duration of `t` seconds."""
    sec = int(math.floor(t))
    nanosec = int(round((t - sec) * 1e9))
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return {"sec": sec, "nanosec": nanosec}


def to_joint_trajectory(traj: Trajectory, idx: list[int],
                        naming: JointNaming | None = None) -> dict:
    """trajectory_msgs/JointTrajectory (ROS 2) of the joints `idx`, as a plain mapping."""
    names = written_names(traj, naming)
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "joint_names": [names[i] for i in idx],
        "points": [{"positions": [float(v) for v in traj.q[k, idx]],
                    "velocities": [float(v) for v in traj.qd[k, idx]],
                    "accelerations": [float(v) for v in traj.qdd[k, idx]],
                    "effort": [],
                    "time_from_start": duration_msg(float(t))} for k, t in enumerate(traj.times)],
    }


def timing_text(traj: Trajectory) -> str:
    if traj.timing == "planned":
        return f"planned ({CURVE_NAME}, at the planned times)"
    why = (traj.planned_curve or {}).get("not_played", "--timing toppra")
    return f"toppra (time-optimal within the limits; the planned curve: {why})"
