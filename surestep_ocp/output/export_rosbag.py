"""`surestep export --format rosbag2 --output DIR`: the plan as a ROS 2 bag a robot can play,
written by `rosbags`.

Topics (ARM: `--arm`, default PSM1; the jaw's only when the plan has a jaw):
- `/ARM/servo_jp`, `sensor_msgs/msg/JointState`: the dVRK's crtk joint set-point stream, one message
  every 1/rate s from the bag's start (the export's `--rate`), position and velocity of the six arm
  joints at that time; after the trajectory's end, one more at the next tick holding the last
  waypoint (at rest); header stamp = the message's time in the bag;
- `/ARM/jaw/servo_jp`: the same for the jaw;
- `/ARM/trajectory` (and `/ARM/jaw/trajectory`), `trajectory_msgs/msg/JointTrajectory`: the whole
  exported trajectory in one message at the bag's start, every sample with its time from the start
  (the `ros2` format's message); not a dVRK command, for a trajectory controller or a viewer.
The bag: rosbag2 format version 8, sqlite3 storage, CDR; its metadata's `custom_data`
records the export (`surestep.*`: source, timing, rate, joint names). The directory is
written whole or not at all.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer, WriterError  # this module is loaded on use (export_writers)
from rosbags.typesys import Stores, get_typestore

from ..errors import SurestepError, shown
from .export_message import FORMAT_ID, channels, timing_text, to_joint_trajectory, written_names
from .export_setpoints import DEFAULT_ARM, setpoint_rows, topics
from ..model.limits.retiming import Trajectory
from .files import check_finite, write_dir_atomic
from .joint_names import JointNaming

BAG_VERSION = 8  # rosbag2 metadata version (rosbags writes 8 or 9; 9 adds type hashes)
# the message definitions (JointState, JointTrajectory: the same in later releases)
TYPESTORE = "ROS2_HUMBLE"


@contextlib.contextmanager
def _bag_errors(output: Path):
    """The storage's failures (sqlite3's `database or disk is full`, an OSError, rosbags' own) as
    one line naming the bag (they were `internal error: OperationalError`)."""
    try:
        yield
    except (sqlite3.Error, OSError, WriterError) as exc:
        why = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        raise SurestepError(f"{shown(str(output), 200)}: cannot write the bag ({why})") from None


def _stamp(ns: int) -> tuple[int, int]:
    return ns // 1_000_000_000, ns % 1_000_000_000


def write_bag(traj: Trajectory, output: Path, meta: dict, naming: JointNaming | None = None, *,
              rate_hz: float, arm: str = DEFAULT_ARM, start_ns: int | None = None) -> Path:
    """Write the bag directory `output` (module docstring); `start_ns`: the bag's start
    time (default now)."""
    ts = get_typestore(getattr(Stores, TYPESTORE))
    T = ts.types
    Time, Duration, Header = (T["builtin_interfaces/msg/Time"],
                              T["builtin_interfaces/msg/Duration"], T["std_msgs/msg/Header"])
    JointState, JT, JTP = (T["sensor_msgs/msg/JointState"],
                           T["trajectory_msgs/msg/JointTrajectory"],
                           T["trajectory_msgs/msg/JointTrajectoryPoint"])
    # never NaN or Infinity in a bag
    check_finite({"q": traj.q, "qd": traj.qd, "qdd": traj.qdd}, "the trajectory")
    arm_idx, jaw_idx = channels(traj)
    names = written_names(traj, naming)
    start = time.time_ns() if start_ns is None else int(start_ns)
    ticks, rows = setpoint_rows(traj, rate_hz)
    tick_ns = [start + round(int(k) * 1e9 / rate_hz) for k in ticks]
    top = topics(arm)
    empty = np.zeros(0)

    def trajectory_msg(idx):
        d = to_joint_trajectory(traj, idx, naming)
        return JT(header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""),
                  joint_names=d["joint_names"],
                  points=[JTP(positions=np.array(p["positions"]),
                              velocities=np.array(p["velocities"]),
                              accelerations=np.array(p["accelerations"]), effort=empty,
                              time_from_start=Duration(**p["time_from_start"]))
                          for p in d["points"]])

    channels_out = [("trajectory", "servo_jp", arm_idx)] + (
        [("jaw_trajectory", "jaw_servo_jp", jaw_idx)] if jaw_idx else [])
    custom = {"surestep.format": FORMAT_ID, "surestep.source": str(meta.get("source")),
              "surestep.method": str(meta.get("method")), "surestep.timing": timing_text(traj),
              "surestep.duration_s": repr(traj.duration),
              "surestep.servo_jp_rate_hz": repr(float(rate_hz)),
              "surestep.arm": arm, "surestep.topics": json.dumps(top),
              "surestep.joint_names": json.dumps(naming.to_dict() if naming else None)}
    with write_dir_atomic(output, "the bag") as path, _bag_errors(output):
        with Writer(path, version=BAG_VERSION) as w:
            for key, value in custom.items():
                w.set_custom_data(key, value)
            conns = {}
            for traj_role, servo_role, _ in channels_out:
                conns[traj_role] = w.add_connection(top[traj_role], JT.__msgtype__, typestore=ts)
                conns[servo_role] = w.add_connection(top[servo_role], JointState.__msgtype__,
                                                     typestore=ts)
            for traj_role, _, idx in channels_out:
                w.write(conns[traj_role], start, ts.serialize_cdr(trajectory_msg(idx),
                                                                  JT.__msgtype__))
            for ns, r in zip(tick_ns, rows):
                # the last sample is at rest (velocity 0): held after the end
                sec, nsec = _stamp(ns)
                for _, servo_role, idx in channels_out:
                    msg = JointState(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=""),
                                     name=[names[i] for i in idx],
                                     position=np.array(traj.q[r, idx], float),
                                     velocity=np.array(traj.qd[r, idx], float), effort=empty)
                    w.write(conns[servo_role], ns, ts.serialize_cdr(msg, JointState.__msgtype__))
    return output
