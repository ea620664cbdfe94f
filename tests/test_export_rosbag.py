"""`surestep export --format rosbag2` and `--joint-names`: the bag read back with rosbags' own
reader, and the ROS 2 YAML built into a `trajectory_msgs/msg/JointTrajectory` with rosbags'
typestore, through CDR and back.

The references are the JSON export of the same plan (read as a file), the URDF's limits
(ElementTree) and the dVRK's accelerations (`test_export.ACCEL`), and the names written here; not
the exporter's code.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from test_export import ACCEL, ARM, LIMITS, REL, export, read_json

from surestep_ocp.cli import main
from surestep_ocp.methods.registry import run_method

REPO = Path(__file__).resolve().parents[1]
TS = get_typestore(Stores.ROS2_HUMBLE)
ROS_MODEL = ["outer_yaw", "outer_pitch", "outer_insertion", "outer_roll", "outer_wrist_pitch",
             "outer_wrist_yaw"]
JS, JT = "sensor_msgs/msg/JointState", "trajectory_msgs/msg/JointTrajectory"


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    """The straight line at the paper's pace (retimed by toppra: waypoints between the ticks) and
    the default problem's plan (limits enforced: played at its planned times)."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    d = tmp_path_factory.mktemp("plans")
    base = run_method(build_setup(load_problem(REPO / "problems"
                                               / "needle_regrasp_paper_pace.yaml")), "baseline")
    ocp = run_method(build_setup(load_problem(REPO / "problems" / "needle_regrasp.yaml")), "ocp")
    return {"baseline": base.save(d / "baseline.json"), "ocp": ocp.save(d / "ocp.json")}


def read_bag(path):
    """{topic: (type, [(log time ns, message)])} and the metadata's custom_data."""
    out = {}
    with Reader(path) as r:
        for c in r.connections:
            out[c.topic] = (c.msgtype, [])
        for c, t, raw in r.messages():
            out[c.topic][1].append((t, TS.deserialize_cdr(raw, c.msgtype)))
    custom = yaml.safe_load((Path(path) / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]
    return out, custom


def seconds(d):
    return d.sec + 1e-9 * d.nanosec


@pytest.mark.parametrize(("which", "preset", "names", "rate"), [
    ("ocp", None, ARM, 100.0),
    ("baseline", "dvrk-ros-model", ROS_MODEL, 100.0),
    ("ocp", "dvrk-ros-model", ROS_MODEL, 20.0),
])
def test_bag_read_back(plans, tmp_path, which, preset, names, rate):
    flags = ["--no-plot", "--rate", f"{rate:g}"] + (["--joint-names", preset] if preset else [])
    assert export(plans[which], "json", tmp_path / "ref.json", *flags) == 0
    assert export(plans[which], "rosbag2", tmp_path / "bag", *flags) == 0
    # no temporary folder left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "ref.json"]
    ref = read_json(tmp_path / "ref.json")
    bag, custom = read_bag(tmp_path / "bag")
    assert {k: v[0] for k, v in bag.items()} == {"/PSM1/servo_jp": JS, "/PSM1/jaw/servo_jp": JS,
                                                  "/PSM1/trajectory": JT,
                                                 "/PSM1/jaw/trajectory": JT}
    assert json.loads(custom["surestep.joint_names"])["choice"] == (preset or "dvrk")
    assert float(custom["surestep.servo_jp_rate_hz"]) == rate
    vmax = np.array([LIMITS[n][2] for n in ARM + ["jaw"]])
    amax = np.array([ACCEL[n] for n in ARM + ["jaw"]])
    start = bag["/PSM1/trajectory"][1][0][0]

    # the set-points: every 1/rate s from the start, the exported samples at those times, then the
    # last one held
    arm, jaw = bag["/PSM1/servo_jp"][1], bag["/PSM1/jaw/servo_jp"][1]
    assert len(arm) == len(jaw) and arm[0][0] == start
    stamps = np.array([t for t, _ in arm])
    np.testing.assert_array_equal(stamps, [t for t, _ in jaw])
    assert np.all(np.diff(stamps) > 0) and np.all(np.abs(np.diff(stamps) - 1e9 / rate) <= 1)
    for t, m in arm + jaw:
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t
    assert (all(list(m.name) == names for _, m in arm)
            and all(list(m.name) == ["jaw"] for _, m in jaw))
    q = np.column_stack([[m.position for _, m in arm], [m.position for _, m in jaw]])
    v = np.column_stack([[m.velocity for _, m in arm], [m.velocity for _, m in jaw]])
    tick = (stamps - start) * 1e-9
    duration = ref["t"][-1]
    # the first tick at or after the end is the last
    assert tick[-1] >= duration - 1e-9 and tick[-2] < duration - 1e-9
    for k, tk in enumerate(tick):
        row = len(ref["t"]) - 1 if tk >= duration - 1e-9 else int(np.argmin(np.abs(ref["t"] - tk)))
        assert tk >= duration - 1e-9 or abs(ref["t"][row] - tk) <= 1e-9, (k, tk)
        np.testing.assert_array_equal(q[k], ref["positions"][row])
        np.testing.assert_array_equal(v[k], ref["velocities"][row])
    assert np.all(np.abs(v) <= vmax * (1 + REL))
    # the mean speed between set-points
    assert np.all(np.abs(np.diff(q, axis=0)) * rate <= vmax * (1 + REL))
    np.testing.assert_array_equal(v[0], 0.0)
    np.testing.assert_array_equal(v[-1], 0.0)

    # the whole trajectory: the JSON's samples, at their times, within the acceleration limits
    (_, traj), = bag["/PSM1/trajectory"][1]
    (_, jtraj), = bag["/PSM1/jaw/trajectory"][1]
    assert list(traj.joint_names) == names and list(jtraj.joint_names) == ["jaw"]
    for key, attr in (("positions", "positions"), ("velocities", "velocities"),
                      ("accelerations", "accelerations")):
        got = np.column_stack([[getattr(p, attr) for p in traj.points],
                               [getattr(p, attr) for p in jtraj.points]])
        np.testing.assert_array_equal(got, ref[key])
    t = np.array([seconds(p.time_from_start) for p in traj.points])
    np.testing.assert_allclose(t, ref["t"], rtol=0, atol=1e-9)
    assert np.all(np.diff(t) > 0)
    acc = np.column_stack([[p.accelerations for p in traj.points],
                           [p.accelerations for p in jtraj.points]])
    assert np.all(np.abs(acc) <= amax * (1 + REL))


def test_arm_name_and_an_existing_bag(plans, tmp_path, capsys):
    """--arm renames the topics; a non-empty directory is refused (exit 2, one line, untouched), an
    empty one is filled; --arm with another format is an error."""
    out = tmp_path / "bag"
    assert export(plans["ocp"], "rosbag2", out, "--no-plot", "--arm", "PSM2") == 0
    bag, custom = read_bag(out)
    assert set(bag) == {"/PSM2/servo_jp", "/PSM2/jaw/servo_jp", "/PSM2/trajectory",
                        "/PSM2/jaw/trajectory"}
    assert custom["surestep.arm"] == "PSM2"
    before = sorted((p.name, p.stat().st_size) for p in out.iterdir())
    capsys.readouterr()
    assert export(plans["ocp"], "rosbag2", out, "--no-plot") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not empty" in err[0]
    assert sorted((p.name, p.stat().st_size) for p in out.iterdir()) == before
    empty = tmp_path / "empty"
    empty.mkdir()
    assert (export(plans["ocp"], "rosbag2", empty, "--no-plot") == 0
            and (empty / "metadata.yaml").is_file())
    assert export(plans["ocp"], "json", tmp_path / "x.json", "--no-plot", "--arm", "PSM2") == 2
    assert "--arm" in capsys.readouterr().err and not (tmp_path / "x.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "empty"]


def yaml_message(path):
    """A trajectory_msgs/msg/JointTrajectory built with rosbags' typestore from the ROS 2 YAML
    file."""
    d = yaml.safe_load(Path(path).read_text())
    T = TS.types
    Time, Duration = T["builtin_interfaces/msg/Time"], T["builtin_interfaces/msg/Duration"]
    point = T["trajectory_msgs/msg/JointTrajectoryPoint"]
    return d, T[JT](
        header=T["std_msgs/msg/Header"](stamp=Time(**d["header"]["stamp"]),
                                        frame_id=d["header"]["frame_id"]),
        joint_names=d["joint_names"],
        points=[point(positions=np.array(p["positions"], float),
                      velocities=np.array(p["velocities"], float),
                      accelerations=np.array(p["accelerations"], float),
                      effort=np.array(p["effort"], float),
                      time_from_start=Duration(**p["time_from_start"])) for p in d["points"]])


@pytest.mark.parametrize(("preset", "names"),
                         [(None, ARM), ("dvrk", ARM), ("dvrk-ros-model", ROS_MODEL)])
def test_ros2_yaml_is_a_joint_trajectory_message(plans, tmp_path, preset, names):
    """The YAML is a JointTrajectory: through CDR and back the same, times strictly increasing, 6
    positions, velocities and accelerations per point, the chosen names, recorded in the header."""
    out = tmp_path / "t.yaml"
    assert export(plans["baseline"], "ros2", out, "--no-plot",
                  *(["--joint-names", preset] if preset else [])) == 0
    assert export(plans["baseline"], "json", tmp_path / "t.json", "--no-plot") == 0
    ref = read_json(tmp_path / "t.json")
    d, msg = yaml_message(out)
    back = TS.deserialize_cdr(TS.serialize_cdr(msg, JT), JT)
    assert list(back.joint_names) == names == list(d["joint_names"])
    assert len(back.points) == len(d["points"]) == len(ref["t"])
    for p, q in zip(back.points, d["points"]):
        for k in ("positions", "velocities", "accelerations"):
            assert len(getattr(p, k)) == 6 and list(getattr(p, k)) == q[k]
        assert (p.time_from_start.sec, p.time_from_start.nanosec) == (q["time_from_start"]["sec"],
                                                                    q["time_from_start"]["nanosec"])
    t = np.array([seconds(p.time_from_start) for p in back.points])
    assert t[0] == 0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(t, ref["t"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.array([p.positions for p in back.points]),
                                  ref["positions"][:, :6])
    head = [ln for ln in out.read_text().splitlines() if ln.startswith("# joint names: ")]
    assert len(head) == 1 and head[0].startswith(f"# joint names: {preset or 'dvrk'} ")


def test_explicit_joint_names_in_json_and_csv(plans, tmp_path):
    names = ["j1", "j2", "j3", "j4", "j5", "j6"]
    assert export(plans["baseline"], "json", tmp_path / "a.json", "--no-plot", "--joint-names",
                  ",".join(names)) == 0
    d = json.loads((tmp_path / "a.json").read_text())
    assert d["joint_names"] == names and d["jaw"]["name"] == "jaw"
    assert d["joint_naming"] == {"choice": "explicit", "names": dict(zip(ARM, names))}
    assert export(plans["baseline"], "csv", tmp_path / "a.csv", "--no-plot", "--joint-names",
                  ",".join(names)) == 0
    header = (tmp_path / "a.csv").read_text().splitlines()[0].split(",")
    assert header[2:8] == names and header[8:14] == [f"{n}_vel" for n in names] and header[-3:] == [
        "jaw", "jaw_vel", "jaw_acc"]
    assert export(plans["baseline"], "json", tmp_path / "b.json", "--no-plot") == 0
    assert json.loads((tmp_path / "b.json").read_text())["joint_naming"]["choice"] == "dvrk"


@pytest.mark.parametrize("value", ["dvrk-classic", "a,b,c", "a,b,c,d,e,f,g", "a,b,c,d,e,a",
                                   "a,b,c,d,e,jaw", "a,b,c,d,e,f g"])
def test_bad_joint_names_are_one_line_errors(plans, tmp_path, capsys, value):
    capsys.readouterr()
    assert main(["export", str(plans["baseline"]), "--format", "json", "--output",
                 str(tmp_path / "x.json"), "--joint-names", value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--joint-names" in err[0] and "dvrk, dvrk-ros-model" in err[0], err
    assert not list(tmp_path.iterdir())
