"""Unit tests of the Meshcat visualisation (no browser, no solver).

The fixture solutions are built here: a small primitive-geometry arm (URDF
written to a temporary folder), a straight and a bent joint path, tool poses from
Pinocchio forward kinematics expressed in a camera frame, and synthetic
covariances with rotated (non-diagonal) position blocks.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")
pytest.importorskip("meshcat")
umsgpack = pytest.importorskip("umsgpack")

from surestep_ocp.viz import (build_scene, load_solutions, set_endoscope_view,  # noqa: E402
                              show, show_main, write_static_html)
from surestep_ocp.viz.recorder import recording_visualizer  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROBOT_RGB = (0.10, 0.75, 0.30)  # the fixture arm's material colour (green)
T_STEPS = 10
INTRINSICS = {"fx": 800.0, "fy": 800.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}
UR5 = (Path(sysconfig.get_paths()["purelib"])
       / "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf")

_LIM = '<limit lower="-3" upper="3" effort="1" velocity="1"/>'
_ARM = '<material name="arm"/>'
ARM_URDF = f"""<?xml version="1.0"?>
<robot name="mini_arm">
  <material name="arm"><color rgba="{ROBOT_RGB[0]} {ROBOT_RGB[1]} {ROBOT_RGB[2]} 1"/></material>
  <link name="base"><visual><geometry><sphere radius="0.012"/></geometry>{_ARM}</visual></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <axis xyz="0 0 1"/>{_LIM}</joint>
  <link name="l1"><visual><origin xyz="0 0 0.05"/>
    <geometry><cylinder radius="0.006" length="0.1"/></geometry>{_ARM}</visual></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 1 0"/>{_LIM}</joint>
  <link name="l2"><visual><origin xyz="0.06 0 0"/>
    <geometry><box size="0.12 0.012 0.012"/></geometry>{_ARM}</visual></link>
  <joint name="j3" type="prismatic"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.12 0 0"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.1" effort="1" velocity="1"/></joint>
  <link name="l3"><visual><origin xyz="0.02 0 0" rpy="0 1.5708 0"/>
    <geometry><cylinder radius="0.003" length="0.04"/></geometry>{_ARM}</visual></link>
  <joint name="tool_joint" type="fixed"><parent link="l3"/><child link="tool"/>
    <origin xyz="0.04 0 0"/></joint>
  <link name="tool"/>
</robot>
"""


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """OpenCV camera pose (x right, y down, z forward) at `eye` looking at `target`, world z up."""
    z = (target - eye) / np.linalg.norm(target - eye)
    y = -(np.array([0, 0, 1.0]) - z * z[2])
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = eye
    return T


def random_spd(rng: np.random.Generator, scale: float) -> np.ndarray:
    """Symmetric positive definite 6x6 with a rotated 3x3 position block [m^2]."""
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    S = np.eye(6) * scale * 0.5
    S[:3, :3] = Q @ np.diag(scale * np.array([1.0, 0.4, 0.1])) @ Q.T
    return S


def make_solution(urdf: Path, method: str, bend: float, seed: int = 0, base=None) -> dict:
    """A solution dict for the fixture arm: joint path, camera-frame poses, covariances."""
    base = np.eye(4) if base is None else base
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    fid = model.getFrameId("tool")
    qa, qb = np.array([-0.2, 0.3, 0.02]), np.array([0.2, 0.15, 0.05])
    qs = [qa + (qb - qa) * t / T_STEPS + np.array([0, -bend, 0]) * np.sin(np.pi * t / T_STEPS)
          for t in range(T_STEPS + 1)]
    world = []
    for q in qs:
        pin.framesForwardKinematics(model, data, q)
        world.append(base @ data.oMf[fid].homogeneous)
    pin.framesForwardKinematics(model, data, 0.5 * (qa + qb))  # same camera for every method
    centre = base[:3, :3] @ data.oMf[fid].translation + base[:3, 3]
    cam = look_at(centre + np.array([-0.09, 0.0, 0.12]), centre)
    poses = []
    for W in world:
        C = np.linalg.inv(cam) @ W
        poses.append(list(C[:3, 3]) + list(pin.log3(C[:3, :3])))
    rng = np.random.default_rng(seed)
    sigma = [random_spd(rng, 2e-5 * 0.75 ** t).tolist() for t in range(T_STEPS + 1)]
    return {
        "method": method, "problem": "synthetic.yaml", "success": True, "status": "ok",
        "solve_time_s": 0.1, "iterations": 3, "horizon": T_STEPS,
        "joint_names": ["j1", "j2", "j3"], "q": [q.tolist() for q in qs],
        "poses": poses, "goal": poses[-1], "camera": dict(INTRINSICS),
        "camera_pose": cam.tolist(),
        "robot": {"urdf": str(urdf), "frame": "tool", "base_pose": base.tolist()},
        "noise": {"depth_star": 0.15}, "trace": [float(np.trace(s)) for s in sigma],
        "sigma": sigma, "sigma_final": sigma[-1], "objective": float(np.trace(sigma[-1])),
    }


@pytest.fixture()
def arm_urdf(tmp_path: Path) -> Path:
    p = tmp_path / "mini_arm.urdf"
    p.write_text(ARM_URDF)
    return p


@pytest.fixture()
def solutions(arm_urdf: Path) -> list[dict]:
    return [make_solution(arm_urdf, "baseline", 0.0, 1), make_solution(arm_urdf, "ocp", 0.15, 2)]


def built(sols, **kw):
    vis, window = recording_visualizer()
    return build_scene(sols, vis=vis, **kw), window


def unpack_points(obj: dict) -> np.ndarray:
    """(N, 3) float positions of a lowered meshcat object (Line / LineSegments / BufferGeometry)."""
    attr = obj["geometries"][0]["data"]["attributes"]["position"]["array"]
    return np.frombuffer(attr.data, dtype=np.float32).reshape(-1, 3).astype(float)


def html_paths(html: str) -> set[str]:
    """Scene paths of the commands embedded in a static HTML page."""
    return {umsgpack.unpackb(base64.b64decode(b64)).get("path", "")
            for b64 in re.findall(r'^"([A-Za-z0-9+/=]+)",?$', html, flags=re.M)}


def last(window, path: str, kind: str) -> dict:
    return [c for c in window.decoded[path] if c["type"] == kind][-1]


def test_load_solutions_directory_skips_comparison(tmp_path, solutions):
    for s in solutions:
        (tmp_path / f"{s['method']}.json").write_text(json.dumps(s))
    (tmp_path / "comparison.json").write_text(json.dumps({"methods": ["baseline", "ocp"]}))
    loaded = load_solutions(tmp_path)
    assert sorted(s["method"] for s in loaded) == ["baseline", "ocp"]
    assert load_solutions(tmp_path / "ocp.json")[0]["method"] == "ocp"


def test_scene_nodes_and_ellipsoid_count(solutions):
    info, window = built(solutions)
    for m in ("baseline", "ocp"):
        assert f"/meshcat/paths/{m}/line" in window.nodes
        assert f"/meshcat/paths/{m}/tube" in window.nodes
        ell = [k for k in window.nodes if k.startswith(f"/meshcat/paths/{m}/ellipsoids/")]
        assert len(ell) == T_STEPS + 1 == len(info.paths[m].ellipsoid_nodes)
    for n in ("frustum", "footprint", "triad"):
        assert f"/meshcat/camera/{n}" in window.nodes
    assert "/meshcat/goal/triad" in window.nodes
    assert len(info.robot_nodes) == 4 and all(n in window.nodes for n in info.robot_nodes)
    assert info.animated == "ocp" and window.animation is not None
    assert set(info.nodes) <= set(window.nodes)


def test_ellipsoids_are_3_sigma_of_position_block(solutions):
    info, window = built(solutions)
    for sol in solutions:
        R = np.asarray(sol["camera_pose"])[:3, :3]
        p = info.paths[sol["method"]]
        for k, t in enumerate(p.nodes):
            S = np.asarray(sol["sigma"][t])[:3, :3]
            expect = np.sort(3 * np.sqrt(np.linalg.eigvalsh(S)))
            np.testing.assert_allclose(np.sort(p.radii[k]), expect, rtol=1e-9)
            node = p.ellipsoid_nodes[k]
            obj = last(window, node, "set_object")["object"]["object"]
            radii = np.diag(np.reshape(obj["matrix"], (4, 4)))[:3]
            A = np.reshape(last(window, node, "set_transform")["matrix"], (4, 4)).T  # column-major
            np.testing.assert_allclose(A[:3, :3] @ np.diag((radii / 3) ** 2) @ A[:3, :3].T,
                                       R @ S @ R.T, atol=1e-12)
            np.testing.assert_allclose(A[:3, 3], p.points[k], atol=1e-12)


def test_prior_sized_ellipsoid_starts_hidden_and_big_ones_are_faint(solutions):
    solutions[1]["sigma"][0] = (1e-2 * np.eye(6)).tolist()  # the paper's prior: 3 sigma = 0.3 m
    info, window = built(solutions)
    p = info.paths["ocp"]
    assert len(p.ellipsoid_nodes) == T_STEPS + 1 and p.hidden == [p.ellipsoid_nodes[0]]
    assert {"property": "visible", "value": False}.items() <= last(
        window, p.hidden[0], "set_property").items()
    np.testing.assert_allclose(p.radii[0], 0.3)
    opacity = [last(window, n, "set_object")["object"]["materials"][0]["opacity"]
               for n in p.ellipsoid_nodes]
    assert opacity[0] < min(opacity[1:]) and max(opacity) <= 0.3


def test_polyline_is_camera_pose_times_poses(solutions):
    info, window = built(solutions)
    for sol in solutions:
        C = np.asarray(sol["camera_pose"])
        expect = np.array([C[:3, :3] @ np.asarray(x[:3]) + C[:3, 3] for x in sol["poses"]])
        np.testing.assert_allclose(info.paths[sol["method"]].points, expect, atol=1e-12)
        line = last(window, f"/meshcat/paths/{sol['method']}/line", "set_object")["object"]
        assert line["object"]["type"] == "Line"
        np.testing.assert_allclose(unpack_points(line), expect, atol=1e-6)  # float32


def test_path_end_matches_robot_fk_and_goal(solutions):
    """The drawn path ends where the arm's tool frame is at the last q (a units/frame check)."""
    info, _ = built(solutions)
    sol = solutions[1]
    model = pin.buildModelFromUrdf(sol["robot"]["urdf"])
    data = model.createData()
    pin.framesForwardKinematics(model, data, np.array(sol["q"][-1]))
    np.testing.assert_allclose(info.paths["ocp"].points[-1],
                               data.oMf[model.getFrameId("tool")].translation, atol=1e-9)
    np.testing.assert_allclose(info.goal[:3, 3], info.paths["ocp"].points[-1], atol=1e-9)


def test_frustum_and_footprint(solutions):
    info, _ = built(solutions)
    C = np.asarray(solutions[1]["camera_pose"])
    local = (info.footprint - C[:3, 3]) @ C[:3, :3]
    np.testing.assert_allclose(local[:, 2], 0.15, atol=1e-12)  # image footprint at d*
    u = INTRINSICS["fx"] * local[:, 0] / local[:, 2] + INTRINSICS["cx"]
    v = INTRINSICS["fy"] * local[:, 1] / local[:, 2] + INTRINSICS["cy"]
    np.testing.assert_allclose(np.column_stack([u, v]), [[0, 0], [640, 0], [640, 480], [0, 480]],
                               atol=1e-9)
    np.testing.assert_allclose(info.frustum[0], C[:3, 3], atol=1e-12)  # lines start at the centre


def test_animation_follows_chosen_method(solutions):
    info, window = built(solutions, animate="baseline")
    assert info.animated == "baseline"
    anim = window.decoded["<animation>"][-1]["animations"]
    tracked = {a["path"] for a in anim}
    assert tracked == set(info.robot_nodes)
    keys = [a for a in anim if a["path"].endswith("/l3_0")][0]["clip"]["tracks"][0]["keys"]
    # The last key frame puts the tool link where FK at the last q puts it.
    model = pin.buildModelFromUrdf(solutions[0]["robot"]["urdf"])
    geom = pin.buildGeomFromUrdf(model, solutions[0]["robot"]["urdf"], pin.GeometryType.VISUAL)
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(model, data, np.array(solutions[0]["q"][-1]))
    pin.updateGeometryPlacements(model, data, geom, gdata)
    np.testing.assert_allclose(keys[-1]["value"], gdata.oMg[geom.getGeometryId("l3_0")].translation,
                               atol=1e-9)
    assert info.n_frames > T_STEPS


def test_null_q_and_ecm(solutions, arm_urdf):
    sol = solutions[1]
    sol["q"][3] = None
    base = np.eye(4)
    base[:3, 3] = [0.0, -0.25, 0.0]
    sol["ecm"] = {"urdf": str(arm_urdf), "q": [0.2, 0.4, 0.0], "base_pose": base.tolist()}
    info, window = built(solutions)
    assert len(info.ecm_nodes) == 4 and all(n.startswith("/meshcat/ecm/") for n in info.ecm_nodes)
    assert info.n_frames > 0


def test_endoscope_view_points_along_camera_axis(solutions):
    """Effective view = scene-root display transform M, camera at Rx(90) (0, 0, d), aimed at 0."""
    vis, window = recording_visualizer()
    C = np.asarray(solutions[0]["camera_pose"])
    view = set_endoscope_view(vis, C, INTRINSICS)
    M = np.reshape(last(window, "/meshcat", "set_transform")["matrix"], (4, 4)).T  # column-major
    Rx90 = np.reshape(last(window, "/Cameras/default/rotated", "set_transform")["matrix"], (4, 4)).T
    np.testing.assert_allclose(
        np.reshape(last(window, "/Cameras/default", "set_transform")["matrix"], (4, 4)), np.eye(4))
    props = {c["property"]: c["value"] for c in window.decoded["/Cameras/default/rotated/<object>"]}
    eye_display = Rx90[:3, :3] @ np.asarray(props["position"]) + Rx90[:3, 3]
    Minv = np.linalg.inv(M)
    np.testing.assert_allclose(Minv[:3, :3] @ eye_display + Minv[:3, 3], C[:3, 3], atol=1e-12)
    forward = -eye_display / np.linalg.norm(eye_display)  # OrbitControls aim at the origin
    np.testing.assert_allclose(Minv[:3, :3] @ forward, C[:3, 2], atol=1e-12)  # along camera z
    np.testing.assert_allclose(Minv[:3, :3] @ [0, 0, 1.0], -C[:3, 1], atol=1e-12)  # up = -y
    assert props["fov"] == pytest.approx(np.degrees(2 * np.arctan(240 / 800)))
    np.testing.assert_allclose(view.target, C[:3, 3] + 0.15 * C[:3, 2])


def test_static_html_written_atomically(tmp_path, solutions, monkeypatch):
    out = tmp_path / "scene" / "view.html"
    calls = []
    real_replace = os.replace

    def spy(src, dst):
        calls.append((Path(src), Path(dst)))
        assert Path(src).parent == out.parent and Path(src).exists() and not Path(dst).exists()
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", spy)
    info = write_static_html(solutions, out)
    assert calls and calls[0][1] == out
    html = out.read_text()
    assert "MeshCat.Viewer" in html and "<script" in html
    assert set(info.nodes) <= html_paths(html)
    assert [p.name for p in out.parent.iterdir()] == ["view.html"]  # no temp file left

    # A failure while writing leaves the previous file untouched and no temporary file.
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError):
        write_static_html(solutions[:1], out)
    assert out.read_text() == html and [p.name for p in out.parent.iterdir()] == ["view.html"]


def test_show_html_and_show_main(tmp_path, solutions):
    for s in solutions:
        (tmp_path / f"{s['method']}.json").write_text(json.dumps(s))
    out = tmp_path / "a.html"
    assert show(tmp_path, html=out) == 0 and out.exists()
    assert "/meshcat/paths/ocp/line" in html_paths(out.read_text())
    # Solutions passed directly (the CLI solved a problem YAML first) replace the target.
    assert show(tmp_path / "nonexistent.yaml", html=tmp_path / "c.html",
                solutions=solutions[:1]) == 0
    assert not any("paths/ocp" in p for p in html_paths((tmp_path / "c.html").read_text()))
    args = argparse.Namespace(target=tmp_path / "baseline.json", open_browser=False,
                              html=tmp_path / "b.html", endoscope_view=True, animate=None)
    assert show_main(args) == 0 and (tmp_path / "b.html").exists()


@pytest.mark.skipif(not UR5.exists(), reason="example-robot-data UR5 not installed")
def test_mesh_robot_ur5(solutions):
    sol = solutions[0]
    sol["robot"] = {"urdf": str(UR5), "frame": "tool0", "base_pose": np.eye(4).tolist()}
    sol["joint_names"] = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint"]
    info, window = built([sol])
    assert len(info.robot_nodes) == 7
    obj = last(window, info.robot_nodes[2], "set_object")["object"]
    assert obj["geometries"][0]["type"] == "BufferGeometry" and len(unpack_points(obj)) > 1000


@pytest.mark.skipif(not all((REPO / f"robots/{r}.urdf").exists() for r in ("psm", "ecm")),
                    reason="robots/psm.urdf or robots/ecm.urdf not present")
def test_psm_and_ecm_urdfs_draw(solutions):
    sol = solutions[1]
    sol["robot"] = {"urdf": "robots/psm.urdf", "frame": "tool", "base_pose": np.eye(4).tolist()}
    sol["joint_names"] = ["yaw", "pitch", "insertion"]
    sol["ecm"] = {"urdf": "robots/ecm.urdf", "q": [0.0, 0.0, 0.05, 0.0],
                  "base_pose": np.eye(4).tolist()}
    info, _ = built([sol], repo_root=REPO)
    assert info.robot_nodes and info.ecm_nodes


def test_viz_package_imports_without_meshcat():
    code = "import sys, surestep_ocp.viz; assert 'meshcat' not in sys.modules; print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr


def test_live_server_on_loopback(solutions):
    """The live path: a real Meshcat server subprocess on 127.0.0.1 receives the scene."""
    from surestep_ocp.viz import serve

    vis, info = serve(solutions)
    try:
        assert vis.url().startswith("http://127.0.0.1:")
        html = vis.static_html()  # asks the server for its scene tree
        assert "paths/ocp/line" in "".join(
            base64.b64decode(b).decode("latin-1")
            for b in re.findall(r"base64,([A-Za-z0-9+/=]+)", html))
    finally:
        proc = vis.window.server_proc
        proc.kill()
        proc.wait(timeout=30)
