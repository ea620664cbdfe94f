"""`surestep export`: read the exported files back and check them, independently of the exporter.

The limits come from the URDF (parsed here with ElementTree) and from this file's own table of the
dVRK's move_jp accelerations; the checks use only the file's numbers: the reported velocities and
accelerations, and finite differences of the positions and velocities (the mean of a derivative
over an interval is bounded by its maximum, so a trajectory within its limits passes them exactly).
The tool's speed is computed here with Pinocchio directly (FK of the samples' positions, finite
differences; and the frame Jacobian times the reported velocities).
"""

from __future__ import annotations

import csv
import json
import math
import xml.etree.ElementTree as ET
from itertools import pairwise
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from surestep_ocp.cli import main
from surestep_ocp.methods.registry import run_method

REPO = Path(__file__).resolve().parents[1]
PSM = REPO / "robots" / "psm.urdf"
ARM = ["yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw"]
# dVRK move_jp acceleration limits (saw mtsIntuitiveResearchKitPSM.cpp: 90 deg/s^2, 0.2 m/s^2, 720
# deg/s^2)
ACCEL = {"yaw": math.radians(90), "pitch": math.radians(90), "insertion": 0.2,
         "roll": math.radians(720), "wrist_pitch": math.radians(720),
         "wrist_yaw": math.radians(720), "jaw": math.radians(720)}
REL = 1e-6  # relative tolerance on a limit
# [m/s, rad/s] the default tool limits (docs/motion_limits_and_export.md)
TOOL_SPEED, TOOL_ROTATION = 0.1, math.pi / 2


def urdf_limits(path=PSM):
    out = {}
    for j in ET.parse(path).getroot().iter("joint"):
        lim = j.find("limit")
        if lim is not None and lim.get("velocity") is not None:
            out[j.get("name")] = (float(lim.get("lower")), float(lim.get("upper")),
                                  float(lim.get("velocity")))
    return out


LIMITS = urdf_limits()


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    """The default problem's OCP and straight-line plans, and an evaluation configuration whose OCP
    plan turns the roll joint by most of its range in one step (issue 14, configuration 72)."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    d = tmp_path_factory.mktemp("plans")
    setup = build_setup(load_problem(REPO / "problems" / "needle_regrasp_paper_pace.yaml"))
    out = {}
    for m in ("ocp", "baseline"):
        out[m] = run_method(setup, m).save(d / f"{m}.json")
    sampler = ConfigurationSampler(load_evaluation(REPO / "problems" / "evaluations"
                                                   / "evaluation.yaml"))
    out["config72"] = run_method(sampler.setup_of(sampler.sample(0, 72)),
                                 "ocp").save(d / "config72.json")
    return out


def export(solution, fmt, out, *extra):
    return main(["export", str(solution), "--format", fmt, "--output", str(out), *extra])


def read_json(path):
    d = json.loads(Path(path).read_text())
    t = np.array(d["time_s"])
    cols = {"t": t, "names": d["joint_names"] + [d["jaw"]["name"]]}
    for k in ("positions", "velocities", "accelerations"):
        cols[k] = np.column_stack([np.array(d[k]), np.array(d["jaw"][k])])
    cols["waypoint_times"] = np.array([w["time_s"] for w in d["waypoints"]])
    return cols


def read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    names = ARM + ["jaw"]
    cols = {"t": np.array([float(r["time_s"]) for r in rows]), "names": names}
    for k, suffix in (("positions", ""), ("velocities", "_vel"), ("accelerations", "_acc")):
        cols[k] = np.array([[float(r[n + suffix]) for n in names] for r in rows])
    wp = [(int(r["waypoint"]), float(r["time_s"])) for r in rows if r["waypoint"] != ""]
    assert [i for i, _ in wp] == list(range(len(wp)))
    cols["waypoint_times"] = np.array([t for _, t in wp])
    return cols


def safe_load(path):
    # libyaml's C loader where PyYAML has it (faster: docs/cli.md, "Reading problem files")
    return yaml.load(Path(path).read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def read_ros2(path):
    arm = safe_load(path)
    jaw = safe_load(Path(path).with_name(Path(path).stem + "_jaw" + Path(path).suffix))
    for msg, names in ((arm, ARM), (jaw, ["jaw"])):
        assert set(msg) == {"header", "joint_names", "points"}
        assert msg["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
        assert msg["joint_names"] == names
        for p in msg["points"]:
            assert set(p) == {"positions", "velocities", "accelerations", "effort",
                              "time_from_start"}
            assert (set(p["time_from_start"]) == {"sec", "nanosec"}
                    and 0 <= p["time_from_start"]["nanosec"] < 10**9)
            assert (len(p["positions"]) == len(p["velocities"]) == len(p["accelerations"])
                    == len(names))
    t = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"]
                  for p in arm["points"]])
    tj = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"]
                   for p in jaw["points"]])
    np.testing.assert_array_equal(t, tj)
    cols = {"t": t, "names": ARM + ["jaw"]}
    for k in ("positions", "velocities", "accelerations"):
        cols[k] = np.column_stack([np.array([p[k] for p in arm["points"]]),
                                   np.array([p[k] for p in jaw["points"]])])
    return cols


def check_limits(c, velocity=None, acceleration=None):
    """Positions, velocities, accelerations and their finite differences within the limits (URDF and
    ACCEL, with `velocity` / `acceleration` {joint: limit} in their place); at rest at both ends."""
    t, q, v, a = c["t"], c["positions"], c["velocities"], c["accelerations"]
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    lo = np.array([LIMITS[n][0] for n in c["names"]])
    hi = np.array([LIMITS[n][1] for n in c["names"]])
    vmax = np.array([(velocity or {}).get(n, LIMITS[n][2]) for n in c["names"]])
    amax = np.array([(acceleration or {}).get(n, ACCEL[n]) for n in c["names"]])
    assert np.all(q >= lo - 1e-12) and np.all(q <= hi + 1e-12)
    assert np.all(np.abs(v) <= vmax * (1 + REL)), np.max(np.abs(v) / vmax)
    assert np.all(np.abs(a) <= amax * (1 + REL)), np.max(np.abs(a) / amax)
    dt = np.diff(t)[:, None]
    assert np.all(np.abs(np.diff(q, axis=0)) / dt <= vmax * (1 + REL))
    assert np.all(np.abs(np.diff(v, axis=0)) / dt <= amax * (1 + REL))
    np.testing.assert_array_equal(v[0], 0.0)
    np.testing.assert_array_equal(v[-1], 0.0)
    # the velocities are those of the positions (trapezoid rule over each sample interval)
    trap = 0.5 * (v[1:] + v[:-1]) * dt
    assert np.max(np.abs(np.diff(q, axis=0) - trap)) <= 0.02 * np.max(vmax * dt[:, 0].max())


def tool_speeds(c, frame="tool", urdf=PSM):
    """The tool's speed from the samples, by Pinocchio: (chord translation [m/s], chord rotation
    [rad/s]) between consecutive samples (FK of the positions), and (translation, rotation) at each
    sample from the frame Jacobian times the reported velocities."""
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    assert ([model.names[i] for i in range(1, model.njoints)] == c["names"]
            and model.nq == len(c["names"]))
    fid = model.getFrameId(frame)
    poses, inst = [], []
    for qk, vk in zip(c["positions"], c["velocities"]):
        pin.framesForwardKinematics(model, data, qk)
        poses.append(data.oMf[fid].copy())
        J = pin.computeFrameJacobian(model, data, qk, fid, pin.LOCAL_WORLD_ALIGNED)
        inst.append([np.linalg.norm(J[:3] @ vk), np.linalg.norm(J[3:] @ vk)])
    dt = np.diff(c["t"])
    chord_v = np.array([np.linalg.norm(b.translation - a.translation)
                        for a, b in pairwise(poses)]) / dt
    chord_w = np.array([np.linalg.norm(pin.log3(a.rotation.T @ b.rotation))
                        for a, b in pairwise(poses)]) / dt
    return (chord_v, chord_w), np.array(inst)


def check_tool(c, frame="tool", speed=TOOL_SPEED, rotation=TOOL_ROTATION):
    """The tool's translation and rotation speed within their limits; returns the peak ratios."""
    (chord_v, chord_w), inst = tool_speeds(c, frame)
    assert chord_v.max() <= speed * (1 + REL), chord_v.max()
    assert chord_w.max() <= rotation * (1 + REL), chord_w.max()
    assert inst[:, 0].max() <= speed * (1 + REL), inst[:, 0].max()
    assert inst[:, 1].max() <= rotation * (1 + REL), inst[:, 1].max()
    return inst[:, 0].max() / speed, inst[:, 1].max() / rotation


def check_waypoints(c, sol, waypoint_times):
    """Every planned waypoint is a sample at its stated time, never earlier than the planned pace (a
    waypoint a solver's tolerance beyond a position limit: on the limit)."""
    q = np.array(sol["q"])
    lo = np.array([LIMITS[n][0] for n in c["names"]])
    hi = np.array([LIMITS[n][1] for n in c["names"]])
    assert np.abs(np.clip(q, lo, hi) - q).max() <= 1e-6
    q = np.clip(q, lo, hi)
    step = sol["timing"]["step_s"]
    assert len(waypoint_times) == len(q)
    # ros2: whole nanoseconds
    assert waypoint_times[0] == 0.0 and abs(waypoint_times[-1] - c["t"][-1]) <= 1e-9
    assert np.all(np.diff(waypoint_times) >= step * (1 - 1e-9))  # each step takes at least step_s
    for i, ti in enumerate(waypoint_times):
        k = int(np.argmin(np.abs(c["t"] - ti)))
        assert abs(c["t"][k] - ti) <= 1e-9, (i, ti)
        np.testing.assert_allclose(c["positions"][k], q[i], rtol=0, atol=1e-9)


@pytest.mark.parametrize("which", ["ocp", "baseline", "config72"])
def test_json_export_within_limits_through_every_waypoint(plans, tmp_path, which):
    out = tmp_path / "traj.json"
    assert export(plans[which], "json", out) == 0
    c = read_json(out)
    check_limits(c)
    check_tool(c)
    sol = json.loads(Path(plans[which]).read_text())
    check_waypoints(c, sol, c["waypoint_times"])
    assert (tmp_path / "traj.json_motion.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # no temp files left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj.json", "traj.json_motion.png"]


def test_csv_and_ros2_carry_the_same_trajectory(plans, tmp_path):
    sol = json.loads(Path(plans["ocp"]).read_text())
    assert export(plans["ocp"], "json", tmp_path / "a.json", "--no-plot") == 0
    assert export(plans["ocp"], "csv", tmp_path / "a.csv", "--no-plot") == 0
    assert export(plans["ocp"], "ros2", tmp_path / "a.yaml", "--no-plot") == 0
    j, c, r = (read_json(tmp_path / "a.json"), read_csv(tmp_path / "a.csv"),
               read_ros2(tmp_path / "a.yaml"))
    for x in (c, r):
        check_limits(x)
        np.testing.assert_allclose(x["t"], j["t"], rtol=0, atol=1e-9)
        for k in ("positions", "velocities", "accelerations"):
            np.testing.assert_allclose(x[k], j[k], rtol=0, atol=1e-12)
    check_waypoints(c, sol, c["waypoint_times"])
    check_waypoints(r, sol, j["waypoint_times"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json", "a.yaml", "a_jaw.yaml"]


def test_the_ocp_plan_is_slowed_where_the_limits_need_it(plans, tmp_path):
    """The OCP's first step (31 mm, issue 14) cannot run in 0.05 s: the exported step takes
    longer."""
    assert export(plans["ocp"], "json", tmp_path / "o.json", "--no-plot") == 0
    wt = read_json(tmp_path / "o.json")["waypoint_times"]
    assert wt[1] > 5 * 0.05


def test_overridden_limits_are_honoured(plans, tmp_path):
    out = tmp_path / "slow.json"
    assert export(plans["baseline"], "json", out, "--no-plot", "--velocity-limit", "yaw=0.1",
                  "--acceleration-limit", "yaw=0.2") == 0
    c = read_json(out)
    k = c["names"].index("yaw")
    assert np.max(np.abs(c["velocities"][:, k])) <= 0.1 * (1 + REL)
    assert np.max(np.abs(c["accelerations"][:, k])) <= 0.2 * (1 + REL)
    # and the bound is used, not just met by a crawl
    assert np.max(np.abs(c["velocities"][:, k])) >= 0.05
    d = json.loads(out.read_text())
    assert d["limits"]["sources"]["velocity"]["yaw"] == "command line"
    assert d["limits"]["sources"]["velocity"]["pitch"] == "urdf"


def test_the_problems_limits_are_honoured_and_flags_override_them(write_problem, tmp_path):
    """A plan made with a `limits:` section (not enforced: the plan ignores them, the export does
    not) records them; the export honours them without flags, the flags override them, and the file
    says which is which."""
    path = write_problem(lambda t: t.update(limits={"joint_velocity": {"yaw": 0.3},
                                                    "tool_speed": 0.05,
                                                     "tool_rotation_speed": 1.0}), "slow")
    sol = tmp_path / "ocp.json"
    assert main(["solve", str(path), "--method", "ocp", "--output", str(sol)]) == 0
    rec = json.loads(sol.read_text())["limits"]
    assert rec["enforce"] is False and rec["tool_speed_m_s"] == 0.05 and rec["velocity"][0] == 0.3
    assert export(sol, "json", tmp_path / "a.json", "--no-plot") == 0
    c = read_json(tmp_path / "a.json")
    check_limits(c, velocity={"yaw": 0.3})
    assert max(check_tool(c, speed=0.05, rotation=1.0)) >= 0.5  # the bound is used
    d = json.loads((tmp_path / "a.json").read_text())
    src = d["limits"]["sources"]
    assert src["velocity"]["yaw"] == src["tool_speed"] == src["tool_rotation"] == "problem file"
    assert src["velocity"]["pitch"] == "urdf" and src["recorded"].startswith("solution")
    assert (d["step_s_source"] == "solution (timing.step_s)"
            and d["limits_enforced_in_plan"] is False)
    assert export(sol, "json", tmp_path / "b.json", "--no-plot", "--tool-speed", "0.03",
                  "--velocity-limit", "yaw=0.2") == 0
    c = read_json(tmp_path / "b.json")
    check_limits(c, velocity={"yaw": 0.2})
    check_tool(c, speed=0.03, rotation=1.0)
    src = json.loads((tmp_path / "b.json").read_text())["limits"]["sources"]
    assert (src["velocity"]["yaw"] == src["tool_speed"] == "command line"
            and src["tool_rotation"] == "problem file")
    assert c["t"][-1] > read_json(tmp_path / "a.json")["t"][-1]


def test_a_solution_without_recorded_limits_gets_the_defaults(plans, tmp_path):
    """Solution files written before they recorded their limits (and timing) export within the
    defaults."""
    sol = json.loads(Path(plans["ocp"]).read_text())
    del sol["limits"], sol["timing"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(sol))
    assert export(old, "csv", tmp_path / "o.csv", "--no-plot") == 0
    c = read_csv(tmp_path / "o.csv")
    check_limits(c)
    check_tool(c)
    assert export(old, "json", tmp_path / "o.json", "--no-plot") == 0
    d = json.loads((tmp_path / "o.json").read_text())
    assert (d["limits"]["sources"]["recorded"].startswith("none")
            and d["step_s_source"].startswith("default"))


@pytest.mark.parametrize(("args", "needle"), [
    (["--velocity-limit", "elbow=1"], "elbow"),
    (["--velocity-limit", "yaw=-1"], "yaw=-1"),
    (["--acceleration-limit", "yaw"], "JOINT=VALUE"),
    (["--step-s", "0"], "--step-s"),
    (["--tool-speed", "-0.1"], "--tool-speed"),
    (["--rate", "0"], "--rate"),
])
def test_bad_options_are_one_line_errors(plans, tmp_path, capsys, args, needle):
    assert export(plans["baseline"], "json", tmp_path / "x.json", *args) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.json").exists()


def test_bad_solution_files_are_one_line_errors(plans, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert export(bad, "csv", tmp_path / "o.csv") == 2
    sol = json.loads(Path(plans["baseline"]).read_text())
    sol["q"][3] = None
    holed = tmp_path / "holed.json"
    holed.write_text(json.dumps(sol))
    assert export(holed, "csv", tmp_path / "o.csv") == 2
    assert export(tmp_path / "missing.json", "csv", tmp_path / "o.csv") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "q[3] is null" in err[1] and "no such solution file" in err[2]
    with pytest.raises(SystemExit) as exc:  # argparse: an unknown format lists the allowed ones
        export(plans["baseline"], "xml", tmp_path / "o.xml")
    assert exc.value.code == 2 and "csv" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


READERS = {"json": read_json, "csv": read_csv, "ros2": read_ros2}
SUFFIX = {"json": ".json", "csv": ".csv", "ros2": ".yaml"}


def test_every_evaluation_configuration_exports_within_every_limit(tmp_path):
    """Issue 14's criterion: the OCP plan of each of the 100 evaluation configurations (seed 0),
    exported in turn as JSON, CSV and ROS 2 and read back, is within every joint position, velocity
    and acceleration limit and the tool's speed limits (computed here), and passes every waypoint at
    its stated time."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

    sampler = ConfigurationSampler(load_evaluation(REPO / "problems" / "evaluations"
                                                   / "evaluation.yaml"))
    peaks = []
    for i in range(100):
        sol_path = run_method(sampler.setup_of(sampler.sample(0, i)),
                              "ocp").save(tmp_path / f"c{i}.json")
        sol = json.loads(sol_path.read_text())
        fmt = ("json", "csv", "ros2")[i % 3]
        out = tmp_path / f"c{i}_trajectory{SUFFIX[fmt]}"  # not the solution file itself (c{i}.json)
        assert export(sol_path, fmt, out, "--no-plot") == 0, i
        c = READERS[fmt](out)
        check_limits(c)
        peaks.append(check_tool(c, sol["robot"]["frame"]))
        check_waypoints(c, sol, c["waypoint_times"] if fmt != "ros2"
                        else ros2_waypoint_times(out, c["t"]))
    assert np.max(peaks) >= 0.9  # the tool's limits bind somewhere


def ros2_waypoint_times(path, t):
    """The ros2 form states the waypoints' times (to the microsecond) in its header comment: the
    samples at them."""
    head = Path(path).read_text().splitlines()[1]
    stated = np.array([float(x) for x in head.split("[s]:", 1)[1].split(",")])
    k = np.array([int(np.argmin(np.abs(t - ti))) for ti in stated])
    assert np.all(np.abs(t[k] - stated) <= 1e-6)
    return t[k]


def test_a_waypoint_beyond_a_position_limit(plans, tmp_path, capsys):
    """A solver's tolerance beyond a limit (1e-8 rad) is clipped onto it, and said; 0.1 rad is a
    one-line error."""
    sol = json.loads(Path(plans["baseline"]).read_text())
    lower = LIMITS["roll"][0]
    for i, (dq, code) in enumerate(((-1e-8, 0), (-0.1, 2))):
        sol["q"][5][3] = lower + dq
        f = tmp_path / f"s{i}.json"
        f.write_text(json.dumps(sol))
        assert export(f, "json", tmp_path / f"o{i}.json", "--no-plot") == code
    d = json.loads((tmp_path / "o0.json").read_text())
    assert d["waypoints_clipped_by"] == pytest.approx(1e-8, rel=1e-3)
    check_limits(read_json(tmp_path / "o0.json"))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "q[5] roll" in err[0] and not (tmp_path / "o1.json").exists()


def test_export_never_overwrites_its_inputs(plans, tmp_path, capsys):
    """The solution itself, the URDF it names, or a folder as --output, or a ros2 jaw file landing
    on the solution:
    exit 2 in one line before any work, the inputs unchanged."""
    src = tmp_path / "plan.json"
    src.write_text(Path(plans["ocp"]).read_text())
    before = src.read_bytes()
    from surestep_ocp.problem.paths import resolve_urdf

    urdf = resolve_urdf(json.loads(before)["robot"]["urdf"])
    urdf_before = urdf.read_bytes()
    for out in (src, urdf, tmp_path):
        capsys.readouterr()
        code = main(["export", str(src), "--format", "csv", "--output", str(out)])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1, err
    # ros2 writes <stem>_jaw<suffix> beside the output: the solution named like that is refused too
    jaw_named = tmp_path / "arm_jaw.json"
    jaw_named.write_bytes(before)
    assert main(["export", str(jaw_named), "--format", "ros2", "--output",
                 str(tmp_path / "arm.json")]) == 2
    assert (src.read_bytes() == before and jaw_named.read_bytes() == before
            and urdf.read_bytes() == urdf_before)


@pytest.mark.parametrize("case", ["urdf_not_urdf", "robot_not_mapping", "frame_unknown",
                                  "limits_other_form", "limits_not_mapping", "step_negative",
                                  "step_string"])
def test_malformed_solution_files_are_one_line_errors(plans, tmp_path, capsys, case):
    """Solution files edited by hand or by another tool: each a one-line exit-2 error naming the
    file and the key (before, most ended in an internal error or exported silently with the default
    limits; the unknown frame's error did not name the file)."""
    d = json.loads(Path(plans["ocp"]).read_text())
    junk = tmp_path / "junk.urdf"
    junk.write_text("not a urdf\n")
    edit = {"urdf_not_urdf": lambda: d["robot"].update(urdf=str(junk)),
            "robot_not_mapping": lambda: d.update(robot="psm"),
            "frame_unknown": lambda: d["robot"].update(frame="no_such_frame"),
            "limits_other_form": lambda: d.update(limits={"enforce": True,
                                                          "joint_velocity": {"yaw": 1.0}}),
            "limits_not_mapping": lambda: d.update(limits=[1, 2]),
            "step_negative": lambda: d.update(timing={"step_s": -0.05}),
            "step_string": lambda: d.update(timing={"step_s": "fast"})}
    edit[case]()
    src = tmp_path / "plan.json"
    src.write_text(json.dumps(d))
    capsys.readouterr()
    code = main(["export", str(src), "--format", "csv", "--output", str(tmp_path / "out.csv"),
                 "--no-plot"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "plan.json" in err, err
    assert not (tmp_path / "out.csv").exists()


@pytest.fixture(scope="module")
def enforced_plan(tmp_path_factory):
    """The default problem as shipped: 40 steps of 0.05 s (2 s) with its limits enforced, so the
    OCP's rows bound the curve the export plays at the planned times."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    prob = load_problem(REPO / "problems" / "needle_regrasp.yaml")
    assert prob.limits.enforce and prob.horizon == 40 and prob.timing.step_s == 0.05
    sol = run_method(build_setup(prob), "ocp")
    assert sol.success, sol.status
    return sol.save(tmp_path_factory.mktemp("enforced") / "ocp.json")


@pytest.mark.parametrize("fmt", ["json", "csv", "ros2"])
def test_an_enforced_plan_is_exported_at_its_planned_pace(enforced_plan, tmp_path, fmt):
    """Duration the planned 40 x 0.05 s, every waypoint at its planned time, within every limit
    (read back)."""
    out = tmp_path / f"p{SUFFIX[fmt]}"
    assert export(enforced_plan, fmt, out, "--no-plot") == 0
    c = READERS[fmt](out)
    check_limits(c)
    peaks = check_tool(c)
    sol = json.loads(Path(enforced_plan).read_text())
    wt = c["waypoint_times"] if fmt != "ros2" else ros2_waypoint_times(out, c["t"])
    check_waypoints(c, sol, wt)
    assert abs(c["t"][-1] - 2.0) <= 1e-9
    np.testing.assert_allclose(wt, 0.05 * np.arange(41), rtol=0, atol=1e-9)
    assert max(peaks) >= 0.5  # the tool moves at a good part of its limits
    if fmt == "json":
        d = json.loads(out.read_text())
        assert d["timing"] == "planned" and d["planned_curve"]["within"] and d["duration_s"] == 2.0
    if fmt == "ros2":
        assert Path(out).read_text().splitlines()[2].startswith("# timing: planned")


def test_timing_toppra_retimes_and_planned_refuses_a_plan_over_its_limits(enforced_plan, plans,
                                                                          tmp_path, capsys):
    """--timing toppra retimes even a plan within its limits (no faster than planned); --timing
    planned on the straight line (over its acceleration limits at the planned pace) is a one-line
    error, exit 2, nothing written; by default that plan is retimed and the file says why."""
    assert export(enforced_plan, "json", tmp_path / "t.json", "--no-plot", "--timing",
                  "toppra") == 0
    d = json.loads((tmp_path / "t.json").read_text())
    assert d["timing"] == "toppra" and d["duration_s"] >= 2.0 - 1e-9
    check_limits(read_json(tmp_path / "t.json"))
    capsys.readouterr()
    assert export(plans["baseline"], "json", tmp_path / "b.json", "--no-plot", "--timing",
                  "planned") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "joint_acceleration" in err[0] and not (tmp_path / "b.json").exists()
    assert export(plans["baseline"], "json", tmp_path / "b.json", "--no-plot") == 0
    d = json.loads((tmp_path / "b.json").read_text())
    assert d["timing"] == "toppra" and not d["planned_curve"]["within"]
    assert "joint_acceleration" in d["planned_curve"]["not_played"] and d["duration_s"] > 1.0
