"""Writers of an exported trajectory: CSV, JSON, the ROS 2 `trajectory_msgs/JointTrajectory` (YAML)
and a ROS 2 bag (`export_rosbag.py`); the joints named for the consumer (`joint_names.py`).

The six arm joints (every joint but `jaw` for other robots) and the jaw are separate channels.
Files are written atomically (temporary file and rename), and never with a NaN or an
Infinity in them (`files.check_finite` on everything each format writes: the trajectory, its
limits and the metadata).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import yaml

from ..errors import SurestepError
from ..model.limits import CURVE_NAME, JAW
from .export_timing import Trajectory
from .files import check_finite
from .joint_names import JointNaming
from .solution import write_json_atomic, write_text_atomic

FORMATS = ("csv", "json", "ros2", "rosbag2")
FORMAT_ID = "surestep-joint-trajectory/1"


def channels(traj: Trajectory) -> tuple[list[int], list[int]]:
    """Indices of the arm joints and of the jaw (empty without one)."""
    arm = [i for i, n in enumerate(traj.joint_names) if n != JAW]
    jaw = [i for i, n in enumerate(traj.joint_names) if n == JAW]
    return arm, jaw


def written_names(traj: Trajectory, naming: JointNaming | None) -> list[str]:
    """The names written for `traj.joint_names` (the URDF's without a naming)."""
    return list(traj.joint_names) if naming is None else naming.of(traj.joint_names)


def to_json(traj: Trajectory, meta: dict, naming: JointNaming | None = None) -> dict:
    arm, jaw = channels(traj)
    names = written_names(traj, naming)
    out = {
        "format": FORMAT_ID,
        **meta,
        "step_s": traj.step_s,
        "duration_s": traj.duration,
        "planned_duration_s": traj.step_s * (len(traj.waypoint_times) - 1),
        "limits": traj.limits.to_dict(),
        # "planned": the planned curve at the planned times; "toppra": retimed
        "timing": traj.timing,
        "planned_curve": traj.planned_curve,
        "limit_scales": traj.scales,
        "peak_velocity_ratio": dict(zip(traj.joint_names, traj.peak_velocity_ratio.tolist())),
        "peak_acceleration_ratio": dict(zip(traj.joint_names,
                                            traj.peak_acceleration_ratio.tolist())),
        "tool_frame": traj.tool_frame,
        "peak_tool_speed_ratio": None if traj.peak_tool_ratio is None else traj.peak_tool_ratio[0],
        "peak_tool_rotation_ratio": (None if traj.peak_tool_ratio is None
                                     else traj.peak_tool_ratio[1]),
        "waypoints": [{"index": i, "time_s": float(t), "planned_time_s": i * traj.step_s,
                       "row": int(r)}
                      for i, (t, r) in enumerate(zip(traj.waypoint_times, traj.waypoint_rows))],
        "joint_names": [names[i] for i in arm],
        "time_s": traj.times.tolist(),
        "positions": traj.q[:, arm].tolist(),
        "velocities": traj.qd[:, arm].tolist(),
        "accelerations": traj.qdd[:, arm].tolist(),
    }
    if jaw:
        j = jaw[0]
        out["jaw"] = {"name": JAW, "positions": traj.q[:, j].tolist(),
                      "velocities": traj.qd[:, j].tolist(),
                      "accelerations": traj.qdd[:, j].tolist()}
    return out


def to_csv(traj: Trajectory, naming: JointNaming | None = None) -> str:
    arm, jaw = channels(traj)
    names = [written_names(traj, naming)[i] for i in arm]
    jn = [JAW] if jaw else []
    header = (["time_s", "waypoint"] + names + [f"{n}_vel" for n in names]
              + [f"{n}_acc" for n in names] + [f"{n}{s}" for n in jn for s in ("", "_vel", "_acc")])
    wp = {int(r): i for i, r in enumerate(traj.waypoint_rows)}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for k, t in enumerate(traj.times):
        row = [repr(float(t)), str(wp[k]) if k in wp else ""]
        for M in (traj.q, traj.qd, traj.qdd):
            row += [repr(float(v)) for v in M[k, arm]]
        for j in jaw:
            row += [repr(float(traj.q[k, j])), repr(float(traj.qd[k, j])),
                    repr(float(traj.qdd[k, j]))]
        w.writerow(row)
    return buf.getvalue()


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


def _ros2_text(traj: Trajectory, idx: list[int], what: str,
               naming: JointNaming | None = None) -> str:
    times = ", ".join(f"{t:.6f}" for t in traj.waypoint_times)
    head = (f"# trajectory_msgs/JointTrajectory ({what}), written by surestep export\n"
            f"# planned waypoints 0..{len(traj.waypoint_times) - 1} "
            f"at time_from_start [s]: {times}\n"
            f"# timing: {timing_text(traj)}\n")
    if naming is not None:
        head += f"# joint names: {naming.comment()}\n"
    return head + yaml.safe_dump(to_joint_trajectory(traj, idx, naming), sort_keys=False,
                                 default_flow_style=None)


def timing_text(traj: Trajectory) -> str:
    if traj.timing == "planned":
        return f"planned ({CURVE_NAME}, at the planned times)"
    why = (traj.planned_curve or {}).get("not_played", "--timing toppra")
    return f"toppra (time-optimal within the limits; the planned curve: {why})"


def jaw_path(output: Path) -> Path:
    """Where the ros2 form puts the jaw's own JointTrajectory: beside the arm's,
    `<stem>_jaw<suffix>`."""
    return output.with_name(f"{output.stem}_jaw{output.suffix}")


def write(traj: Trajectory, fmt: str, output: Path, meta: dict, naming: JointNaming | None = None,
          **bag) -> list[Path]:
    """Write the trajectory in `fmt` (atomically) with the joints named by `naming`; returns the
    files written. `bag`: rosbag2's `rate_hz` and `arm` (`export_rosbag.write_bag`). Nothing is
    written when any number in them is NaN or Infinity (`files.NonFinite`, naming the key)."""
    check_finite({"meta": meta, "times": traj.times, "q": traj.q, "qd": traj.qd, "qdd": traj.qdd,
                  "waypoint_times": traj.waypoint_times, "step_s": traj.step_s,
                  "limits": traj.limits.to_dict(),
                  "limit_scales": traj.scales, "planned_curve": traj.planned_curve, **bag},
                 "surestep export")
    if fmt == "json":
        doc = to_json(traj, meta, naming)
        check_finite(doc, "surestep export")
        return [write_json_atomic(output, doc)]
    if fmt == "csv":
        return [write_text_atomic(output, to_csv(traj, naming))]
    if fmt == "ros2":
        arm, jaw = channels(traj)
        files = [write_text_atomic(output, _ros2_text(traj, arm, "arm joints", naming))]
        if jaw:
            files.append(write_text_atomic(jaw_path(output), _ros2_text(traj, jaw, "jaw", naming)))
        return files
    if fmt == "rosbag2":
        from .export_rosbag import write_bag  # here: export_rosbag imports this module

        return [write_bag(traj, output, meta, naming, **bag)]
    raise SurestepError(f"unknown format '{fmt}'; allowed: {', '.join(FORMATS)}")


