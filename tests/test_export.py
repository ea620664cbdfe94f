"""`surestep export`: read the exported files back and check them, independently of the exporter.

The limits come from the URDF (parsed here with ElementTree) and from this file's own table of the
dVRK's move_jp accelerations; the checks use only the file's numbers: the reported velocities and
accelerations, and finite differences of the positions and velocities (the mean of a derivative
over an interval is bounded by its maximum, so a trajectory within its limits passes them exactly).
"""

from __future__ import annotations

import csv
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from surestep_ocp.cli import main
from surestep_ocp.methods import run_method

REPO = Path(__file__).resolve().parents[1]
PSM = REPO / "robots" / "psm.urdf"
ARM = ["yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw"]
# dVRK move_jp acceleration limits (saw mtsIntuitiveResearchKitPSM.cpp: 90 deg/s^2, 0.2 m/s^2, 720 deg/s^2)
ACCEL = {"yaw": math.radians(90), "pitch": math.radians(90), "insertion": 0.2, "roll": math.radians(720),
         "wrist_pitch": math.radians(720), "wrist_yaw": math.radians(720), "jaw": math.radians(720)}
REL = 1e-6  # relative tolerance on a limit


def urdf_limits(path=PSM):
    out = {}
    for j in ET.parse(path).getroot().iter("joint"):
        lim = j.find("limit")
        if lim is not None and lim.get("velocity") is not None:
            out[j.get("name")] = (float(lim.get("lower")), float(lim.get("upper")), float(lim.get("velocity")))
    return out


LIMITS = urdf_limits()


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    """The default problem's OCP and straight-line plans, and an evaluation configuration whose OCP plan
    turns the roll joint by most of its range in one step (issue 14, configuration 72)."""
    from surestep_ocp.configs import ConfigurationSampler, load_evaluation
    from surestep_ocp.problem import load_problem
    from surestep_ocp.setup import build_setup

    d = tmp_path_factory.mktemp("plans")
    setup = build_setup(load_problem(REPO / "problems" / "needle_regrasp.yaml"))
    out = {}
    for m in ("ocp", "baseline"):
        out[m] = run_method(setup, m).save(d / f"{m}.json")
    sampler = ConfigurationSampler(load_evaluation(REPO / "problems" / "evaluations" / "evaluation.yaml"))
    out["config72"] = run_method(sampler.setup_of(sampler.sample(0, 72)), "ocp").save(d / "config72.json")
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


def read_ros2(path):
    arm = yaml.safe_load(Path(path).read_text())
    jaw = yaml.safe_load(Path(path).with_name(Path(path).stem + "_jaw" + Path(path).suffix).read_text())
    for msg, names in ((arm, ARM), (jaw, ["jaw"])):
        assert set(msg) == {"header", "joint_names", "points"}
        assert msg["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
        assert msg["joint_names"] == names
        for p in msg["points"]:
            assert set(p) == {"positions", "velocities", "accelerations", "effort", "time_from_start"}
            assert set(p["time_from_start"]) == {"sec", "nanosec"} and 0 <= p["time_from_start"]["nanosec"] < 10**9
            assert len(p["positions"]) == len(p["velocities"]) == len(p["accelerations"]) == len(names)
    t = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in arm["points"]])
    tj = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in jaw["points"]])
    np.testing.assert_array_equal(t, tj)
    cols = {"t": t, "names": ARM + ["jaw"]}
    for k in ("positions", "velocities", "accelerations"):
        cols[k] = np.column_stack([np.array([p[k] for p in arm["points"]]), np.array([p[k] for p in jaw["points"]])])
    return cols


def check_limits(c):
    """Positions, velocities, accelerations and their finite differences within the limits; at rest at both ends."""
    t, q, v, a = c["t"], c["positions"], c["velocities"], c["accelerations"]
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    lo = np.array([LIMITS[n][0] for n in c["names"]])
    hi = np.array([LIMITS[n][1] for n in c["names"]])
    vmax = np.array([LIMITS[n][2] for n in c["names"]])
    amax = np.array([ACCEL[n] for n in c["names"]])
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


def check_waypoints(c, sol, waypoint_times):
    """Every planned waypoint is a sample at its stated time, never earlier than the planned pace."""
    q = np.array(sol["q"])
    step = sol["timing"]["step_s"]
    assert len(waypoint_times) == len(q)
    assert waypoint_times[0] == 0.0 and abs(waypoint_times[-1] - c["t"][-1]) <= 1e-9  # ros2: whole nanoseconds
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
    sol = json.loads(Path(plans[which]).read_text())
    check_waypoints(c, sol, c["waypoint_times"])
    assert (tmp_path / "traj_motion.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["traj.json", "traj_motion.png"]  # no temp files left


def test_csv_and_ros2_carry_the_same_trajectory(plans, tmp_path):
    sol = json.loads(Path(plans["ocp"]).read_text())
    assert export(plans["ocp"], "json", tmp_path / "a.json", "--no-plot") == 0
    assert export(plans["ocp"], "csv", tmp_path / "a.csv", "--no-plot") == 0
    assert export(plans["ocp"], "ros2", tmp_path / "a.yaml", "--no-plot") == 0
    j, c, r = read_json(tmp_path / "a.json"), read_csv(tmp_path / "a.csv"), read_ros2(tmp_path / "a.yaml")
    for x in (c, r):
        check_limits(x)
        np.testing.assert_allclose(x["t"], j["t"], rtol=0, atol=1e-9)
        for k in ("positions", "velocities", "accelerations"):
            np.testing.assert_allclose(x[k], j[k], rtol=0, atol=1e-12)
    check_waypoints(c, sol, c["waypoint_times"])
    check_waypoints(r, sol, j["waypoint_times"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json", "a.yaml", "a_jaw.yaml"]


def test_the_ocp_plan_is_slowed_where_the_limits_need_it(plans, tmp_path):
    """The OCP's first step (31 mm, issue 14) cannot run in 0.05 s: the exported step takes longer."""
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
    assert np.max(np.abs(c["velocities"][:, k])) >= 0.05  # and the bound is used, not just met by a crawl
    d = json.loads(out.read_text())
    assert d["limits"]["sources"]["velocity"]["yaw"] == "override"


@pytest.mark.parametrize(("args", "needle"), [
    (["--velocity-limit", "elbow=1"], "elbow"),
    (["--velocity-limit", "yaw=-1"], "yaw=-1"),
    (["--acceleration-limit", "yaw"], "JOINT=VALUE"),
    (["--step-s", "0"], "--step-s"),
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
