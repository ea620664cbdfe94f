"""Writers of an exported trajectory: CSV, JSON, the ROS 2 `trajectory_msgs/JointTrajectory` (YAML)
and a ROS 2 bag (`export_rosbag.py`, loaded when one is written); the joints named for the
consumer (`joint_names.py`), the channels and the JointTrajectory message as `export_message.py`
makes them.

The six arm joints (every joint but `jaw` for other robots) and the jaw are separate channels.
Files are written atomically (temporary file and rename), and never with a NaN or an
Infinity in them (`files.check_finite` on everything each format writes: the trajectory, its
limits and the metadata).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import yaml

from ..errors import SurestepError
from ..model.limits import JAW
from .export_message import (  # noqa: F401 (their home before)
    FORMAT_ID,
    channels,
    duration_msg,
    timing_text,
    to_joint_trajectory,
    written_names,
)
from ..model.limits.retiming import Trajectory
from .files import check_finite
from .joint_names import JointNaming
from .solution import write_json_atomic, write_text_atomic

FORMATS = ("csv", "json", "ros2", "rosbag2")


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
        from .export_rosbag import write_bag  # here: it loads rosbags, only rosbag2 needs it

        return [write_bag(traj, output, meta, naming, **bag)]
    raise SurestepError(f"unknown format '{fmt}'; allowed: {', '.join(FORMATS)}")


