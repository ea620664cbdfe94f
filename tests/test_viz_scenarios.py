"""Unit tests of the scenario drawing: needles, arms that hold still, a moving camera.

No browser and no solver: the fixture arm and solutions of test_viz.py, extended
with `robot.needle`, `other_arms` and `camera_poses` as `ocp.plan_evaluation.evaluate` writes them.
"""

from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")
pytest.importorskip("meshcat")

from test_viz import ARM_URDF, built, last, make_solution, unpack_points  # noqa: E402

from surestep_ocp.viz import style  # noqa: E402
from surestep_ocp.viz.scene import resolve_file  # noqa: E402
from surestep_ocp.viz.timeline import Timeline  # noqa: E402


@pytest.fixture()
def arm_urdf(tmp_path):
    """test_viz.py's small arm, written for this test."""
    p = tmp_path / "mini_arm.urdf"
    p.write_text(ARM_URDF)
    return p


@pytest.fixture()
def solutions(arm_urdf):
    """test_viz.py's two solutions (baseline and OCP) on that arm."""
    return [make_solution(arm_urdf, "baseline", 0.0, 1), make_solution(arm_urdf, "ocp", 0.15, 2)]


RADIUS = 0.0115


def matrix(window, path: str) -> np.ndarray:
    """4x4 transform last set on a node (meshcat sends it column-major)."""
    return np.reshape(last(window, path, "set_transform")["matrix"], (4, 4)).T


def tracks(window) -> dict[str, dict[str, list]]:
    """Animated node -> {".position"/".quaternion": keys} of the recorded animation."""
    anim = window.decoded["<animation>"][-1]["animations"]
    return {a["path"]: {t["name"]: t["keys"] for t in a["clip"]["tracks"]} for a in anim}


def pose(xyz, rpy) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = pin.rpy.rpyToMatrix(*rpy), xyz
    return T


def fk(urdf, q, frame="tool", base=np.eye(4)) -> np.ndarray:
    """World pose of `frame` at q (Pinocchio), composed with the base pose."""
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    pin.framesForwardKinematics(model, data, np.asarray(q, dtype=float))
    return base @ data.oMf[model.getFrameId(frame)].homogeneous


def needle_solution(urdf, grasp: np.ndarray) -> dict:
    """The fixture ocp solution with a needle in the tool: its poses become the needle's poses."""
    sol = make_solution(urdf, "ocp", 0.15, 2)
    sol["robot"]["needle"] = {"radius": RADIUS, "grasp": grasp.tolist()}
    Cinv = np.linalg.inv(np.asarray(sol["camera_pose"]))
    poses = []
    for q in sol["q"]:
        P = Cinv @ fk(urdf, q) @ grasp
        poses.append(list(P[:3, 3]) + list(pin.log3(P[:3, :3])))
    sol["poses"], sol["goal"] = poses, poses[-1]
    return sol


def test_needle_arc_is_fk_times_grasp_in_its_plane(arm_urdf):
    """The held needle is a 3/4 circle of radius r in the x-y plane of FK(frame) @ grasp."""
    grasp = pose([0.0, RADIUS, 0.004], [0.3, -0.2, 0.5])
    sol = needle_solution(arm_urdf, grasp)
    info, window = built([sol])
    node = "/meshcat/robot/needle"
    assert node in info.needles and node in window.nodes and node in info.nodes
    N0 = fk(arm_urdf, sol["q"][0]) @ grasp
    np.testing.assert_allclose(matrix(window, node), N0, atol=1e-9)
    local = (info.needles[node] - N0[:3, 3]) @ N0[:3, :3]  # world arc -> needle frame
    np.testing.assert_allclose(local[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(local[:, :2], axis=1), RADIUS, atol=1e-12)
    ang = np.unwrap(np.arctan2(local[:, 1], local[:, 0]))
    assert abs(ang[-1] - ang[0]) == pytest.approx(np.radians(style.NEEDLE_SWEEP_DEG))
    jaw = np.linalg.inv(grasp)[:3, 3]  # the jaw holds the middle of the arc
    mid = local[len(local) // 2]
    np.testing.assert_allclose(mid[:2] / RADIUS, jaw[:2] / np.linalg.norm(jaw[:2]), atol=1e-9)
    verts = unpack_points(last(window, node, "set_object")["object"])  # the tube, needle frame
    off_circle = np.hypot(np.linalg.norm(verts[:, :2], axis=1) - RADIUS, verts[:, 2])
    np.testing.assert_allclose(off_circle, style.NEEDLE_TUBE_RADIUS, atol=1e-6)


def test_needle_follows_arm_animation_and_path(arm_urdf):
    """The needle is key-framed with the arm and ends where the drawn path (its poses) ends."""
    grasp = pose([0.0, RADIUS, 0.004], [0.0, 0.0, 0.0])
    sol = needle_solution(arm_urdf, grasp)
    info, window = built([sol])
    keys = tracks(window)["/meshcat/robot/needle"]
    arm_keys = tracks(window)[info.robot_nodes[-1]]
    assert [k["time"] for k in keys[".position"]] == [k["time"] for k in arm_keys[".position"]]
    NT = fk(arm_urdf, sol["q"][-1]) @ grasp
    np.testing.assert_allclose(keys[".position"][-1]["value"], NT[:3, 3], atol=1e-9)
    x, y, z, w = keys[".quaternion"][-1]["value"]
    np.testing.assert_allclose(pin.Quaternion(w, x, y, z).matrix(), NT[:3, :3], atol=1e-9)
    np.testing.assert_allclose(info.paths["ocp"].points[-1], NT[:3, 3], atol=1e-9)


def test_other_arms_under_prefix_at_fk(arm_urdf):
    """Two still copies of one URDF get their own prefixes and sit at FK(q) after base_pose."""
    sol = make_solution(arm_urdf, "ocp", 0.15, 2)
    bases = [pose([0.0, 0.2, 0.0], [0.0, 0.0, 0.4]), pose([0.05, -0.2, 0.01], [0.1, 0.0, -0.5])]
    qs = [[0.3, 0.5, 0.03], [-0.4, 0.2, 0.06]]
    grasp = pose([0.0, RADIUS, 0.004], [0.0, 0.0, 0.0])
    sol["other_arms"] = [{"urdf": str(arm_urdf), "frame": "tool", "base_pose": b.tolist(), "q": q}
                         for b, q in zip(bases, qs)]
    sol["other_arms"][1]["needle"] = {"radius": RADIUS, "grasp": grasp.tolist()}
    info, window = built([sol])
    model = pin.buildModelFromUrdf(str(arm_urdf))
    geom = pin.buildGeomFromUrdf(model, str(arm_urdf), pin.GeometryType.VISUAL)
    data = model.createData()
    for k, (base, q) in enumerate(zip(bases, qs)):
        pin.framesForwardKinematics(model, data, np.array(q))
        for g in geom.geometryObjects:
            node = f"/meshcat/other_arms/{k}/{g.name}"
            assert node in info.other_arm_nodes and node in window.nodes
            link = data.oMf[g.parentFrame].homogeneous @ g.placement.homogeneous
            np.testing.assert_allclose(matrix(window, node), base @ link, atol=1e-9)
    assert len(info.other_arm_nodes) == 2 * len(geom.geometryObjects)
    assert list(info.needles) == ["/meshcat/other_arms/1/needle"]
    np.testing.assert_allclose(matrix(window, "/meshcat/other_arms/1/needle"),
                               fk(arm_urdf, qs[1], base=bases[1]) @ grasp, atol=1e-9)
    animated = set(tracks(window))
    assert animated == set(info.robot_nodes) and not animated & set(info.other_arm_nodes)


def test_moving_camera_history_and_keys(arm_urdf):
    """One faint frustum per distinct camera pose; the camera node moves at the switching steps."""
    sol = make_solution(arm_urdf, "ocp", 0.15, 2)
    C0 = np.asarray(sol["camera_pose"])
    moves = {3: pose([0.01, 0.0, 0.0], [0.0, 0.05, 0.0]), 7: pose([0.0, 0.02, -0.01], [0.1, 0, 0])}
    cams, C = [], C0
    for t in range(len(sol["poses"])):
        C = C @ moves[t] if t in moves else C
        cams.append(C)
    sol["camera_poses"] = [c.tolist() for c in cams]
    info, window = built([sol])
    assert info.camera_switch_steps == [3, 7]
    distinct = [cams[0], cams[3], cams[7]]
    for k, Ck in enumerate(distinct):
        np.testing.assert_allclose(info.camera_history[k], Ck, atol=1e-12)
        np.testing.assert_allclose(matrix(window, f"/meshcat/camera_history/{k}"), Ck, atol=1e-12)
        assert f"/meshcat/camera_history/{k}/frustum" in window.nodes
    assert not any(n.startswith("/meshcat/camera_history/3") for n in window.nodes)
    opacity = [last(window, f"/meshcat/camera_history/{k}/frustum", "set_object")["object"]
               ["materials"][0]["opacity"] for k in range(3)]
    assert opacity == sorted(opacity) and opacity[-1] < 1.0  # earlier ones fainter
    np.testing.assert_allclose(matrix(window, "/meshcat/camera"), cams[0], atol=1e-12)
    frame = Timeline(0.5).node_frame
    keys = tracks(window)["/meshcat/camera"][".position"]
    assert [k["time"] for k in keys] == [0, frame(2), frame(3), frame(6), frame(7)]
    expect = [cams[0], cams[2], cams[3], cams[6], cams[7]]
    np.testing.assert_allclose([k["value"] for k in keys], [c[:3, 3] for c in expect], atol=1e-12)
    assert "/meshcat/camera/triad" in window.nodes  # the triad is a child of the moving node


def test_still_camera_draws_no_history(solutions):
    """Without camera_poses the scene is as before: no history frusta, camera not animated."""
    info, window = built(solutions)
    assert not info.camera_history and not info.camera_switch_steps
    assert not any("camera_history" in n or "other_arms" in n for n in window.nodes)
    assert "/meshcat/camera" not in tracks(window)


def test_example_robot_data_urdf_resolves():
    """URDFs named `example-robot-data:<path>` (as problems write them) are found."""
    name = "example-robot-data:ur_description/urdf/ur5_robot.urdf"
    try:
        p = resolve_file(name, None)
    except FileNotFoundError:
        pytest.skip("UR5 not in this example-robot-data install")
    assert p.is_file() and p.name == "ur5_robot.urdf"
