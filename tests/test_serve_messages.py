"""The ROS 2 messages of `surestep serve` as Cyclone writes them, decoded by an independent ROS 2
type store (rosbags, ROS 2 Humble): the encapsulation (CDR little-endian), every field, the DDS
type names of ROS 2's mapping; and one sample over loopback DDS, taken off the wire as bytes."""

import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from serve_dds import Recorder, free_domain, loopback_env  # noqa: E402
from surestep_ocp.ros import messages as m  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)


def _decode(msg):
    data = msg.serialize()
    assert data[:4] == b"\x00\x01\x00\x00"  # CDR_LE, XCDR1
    return TS.deserialize_cdr(data, m.ROS_NAMES[type(msg)])


def test_joint_state_fields():
    msg = m.JointState(header=m.Header(stamp=m.stamp(1_733_390_000_123_456_789), frame_id="f"),
                       name=["yaw", "pitch"], position=[0.1, -0.2], velocity=[1.5, 2.5], effort=[])
    d = _decode(msg)
    assert (d.header.stamp.sec, d.header.stamp.nanosec) == (1_733_390_000, 123_456_789)
    assert d.header.frame_id == "f" and d.name == ["yaw", "pitch"]
    assert d.position.tolist() == [0.1, -0.2] and d.velocity.tolist() == [1.5, 2.5]
    assert len(d.effort) == 0
    # and back: rosbags' bytes read by the Cyclone type
    assert m.JointState.deserialize(TS.serialize_cdr(d, "sensor_msgs/msg/JointState")) == msg


def test_pose_with_covariance_and_trajectory_and_scalars():
    cov = np.arange(36.0) / 7
    msg = m.PoseWithCovarianceStamped(
        header=m.Header(stamp=m.stamp(5), frame_id="camera"),
        pose=m.PoseWithCovariance(pose=m.Pose(m.Point(0.01, -0.02, 0.12),
                                              m.Quaternion(0.1, 0.2, 0.3, 0.9)),
                                  covariance=cov.tolist()))
    d = _decode(msg)
    p, q = d.pose.pose.position, d.pose.pose.orientation
    assert (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == (0.01, -0.02, 0.12, 0.1, 0.2, 0.3, 0.9)
    assert np.array_equal(d.pose.covariance, cov) and d.header.frame_id == "camera"
    traj = m.JointTrajectory(joint_names=["a", "b"], points=[
        m.JointTrajectoryPoint(positions=[1.0, 2.0], velocities=[0.0, 0.1], accelerations=[3, 4],
                               time_from_start=m.Duration(1, 50_000_000)) for _ in range(3)])
    d = _decode(traj)
    assert d.joint_names == ["a", "b"] and len(d.points) == 3
    assert d.points[2].accelerations.tolist() == [3.0, 4.0]
    assert (d.points[1].time_from_start.sec, d.points[1].time_from_start.nanosec) == (1, 5e7)
    assert _decode(m.String("hold: tracker silent")).data == "hold: tracker silent"
    assert _decode(m.Float64(2.5e-3)).data == 2.5e-3
    goal = _decode(m.PoseStamped(pose=m.Pose(m.Point(1, 2, 3))))
    assert goal.pose.position.z == 3


def test_type_names_follow_ros2_dds_mapping():
    for kind, ros in m.ROS_NAMES.items():
        pkg, _, name = ros.split("/")
        assert kind.__idl_typename__ == f"{pkg}::msg::dds_::{name}_"
    assert m.Header.__idl_typename__ == "std_msgs::msg::dds_::Header_"
    assert m.Time.__idl_typename__ == "builtin_interfaces::msg::dds_::Time_"


def test_on_the_wire_over_loopback(tmp_path, monkeypatch):
    """A JointState written on `rt/PSM1/servo_jp` (loopback only) arrives as bytes rosbags
    decodes."""
    domain = free_domain()
    env = loopback_env(tmp_path, domain)
    monkeypatch.setenv("CYCLONEDDS_URI", env["CYCLONEDDS_URI"])
    from surestep_ocp.ros.dds import Bus

    rec = Recorder(domain, {"/PSM1/servo_jp": m.JointState})
    bus = Bus(domain)
    w = bus.writer("/PSM1/servo_jp", m.JointState)
    deadline = time.time() + 10
    while time.time() < deadline and not rec.samples["/PSM1/servo_jp"]:
        w.write(m.JointState(name=["yaw"], position=[0.25]))
        time.sleep(0.05)
        rec.poll()
    got = rec.decoded("/PSM1/servo_jp", "sensor_msgs/msg/JointState")
    assert got and got[0][1].name == ["yaw"] and got[0][1].position.tolist() == [0.25]
