"""The readers of a problem file's scene sections, each validating strictly: the robot (and any
arm given with it), poses in the file's forms, the camera and its moves, the start and the goal
(and the goal's grasp tolerance and confidence).

Each takes the `schema.Reader` of the file and the section's YAML node, and returns its spec
(`sections.py`) or raises a one-line `ProblemError` naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..model.camera import Intrinsics
from ..model.lie import np_exp, rpy_matrix
from .caps import MAX_ANGLE, MAX_FOCAL, MAX_HORIZON, MAX_IMAGE, MAX_POSITION
from .paths import resolve_path
from .schema import Reader
from .sections import CameraMove, CameraSpec, EndpointSpec, GraspSpec, RelativeGoal, RobotSpec


def _robot(rd: Reader, node: Any, key: str, path: Path, default_frame: str,
           joints: bool = False) -> RobotSpec:
    allowed = {"urdf", "frame", "base_pose", "needle"} | ({"joints"} if joints else set())
    m = rd.mapping(node, key, allowed, {"urdf"} | ({"joints"} if joints else set()))
    urdf, rel = resolve_path(rd, m["urdf"], f"{key}.urdf", path)
    base = _pose(rd, m["base_pose"], f"{key}.base_pose") if "base_pose" in m else np.eye(4)
    grasp = radius = None
    if "needle" in m:
        n = rd.mapping(m["needle"], f"{key}.needle", {"radius", "grasp"}, {"radius", "grasp"})
        radius = rd.number(n["radius"], f"{key}.needle.radius", positive=True, low=1e-4, high=1.0)
        grasp = _pose(rd, n["grasp"], f"{key}.needle.grasp")
    return RobotSpec(urdf=urdf, urdf_rel=rel,
                     frame=rd.string(m.get("frame", default_frame), f"{key}.frame"),
                     base_pose=base, grasp=grasp, needle_radius=radius,
                     joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE) if joints
                     else None)


def _pose(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A pose: `position` plus one of `rpy`, `axis_angle`, `minus_z_toward` (a point), or a 4x4
    `matrix`; or the list of 6 `[px, py, pz, rx, ry, rz]` (position, axis-angle) the
    start and goal take."""
    if isinstance(node, (list, tuple)):
        p = _pose6(rd, node, key)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np_exp(p[3:]), p[:3]
        return T
    m = rd.mapping(node, key, {"position", "rpy", "axis_angle", "minus_z_toward", "matrix"})
    if "matrix" in m:
        if len(m) != 1:
            raise rd.fail(key, "a 'matrix' pose takes no other keys")
        T = rd.matrix(m["matrix"], f"{key}.matrix", 4, limit=MAX_POSITION)
        R = T[:3, :3]
        if (not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0
                or not np.allclose(T[3], [0, 0, 0, 1])):
            raise rd.fail(f"{key}.matrix", "not a rigid transform (rotation must be orthonormal, "
                                           "last row 0 0 0 1)")
        return T
    if "position" not in m:
        raise rd.fail(f"{key}.position", "missing required key")
    T = np.eye(4)
    T[:3, 3] = rd.vector(m["position"], f"{key}.position", 3, limit=MAX_POSITION)
    kind = rd.one_of(m, key, ["rpy", "axis_angle", "minus_z_toward"])
    if kind == "rpy":
        T[:3, :3] = rpy_matrix(rd.vector(m["rpy"], f"{key}.rpy", 3, limit=MAX_ANGLE))
    elif kind == "axis_angle":
        T[:3, :3] = np_exp(rd.vector(m["axis_angle"], f"{key}.axis_angle", 3, limit=MAX_ANGLE))
    else:
        target = rd.vector(m["minus_z_toward"], f"{key}.minus_z_toward", 3, limit=MAX_POSITION)
        d = target - T[:3, 3]
        if np.linalg.norm(d) < 1e-9:
            raise rd.fail(f"{key}.minus_z_toward", "the point must differ from the position")
        z = -d / np.linalg.norm(d)
        helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x = np.cross(helper, z)
        x /= np.linalg.norm(x)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    return T


def _camera(rd: Reader, node: Any, path: Path) -> CameraSpec:
    m = rd.mapping(node, "camera", {"intrinsics", "pose", "ecm", "moves"}, {"intrinsics"})
    i = rd.mapping(m["intrinsics"], "camera.intrinsics",
                   {"fx", "fy", "cx", "cy", "width", "height"},
                   {"fx", "fy", "cx", "cy", "width", "height"})
    k = "camera.intrinsics"
    intr = Intrinsics(
        fx=rd.number(i["fx"], f"{k}.fx", low=1.0, high=MAX_FOCAL),
        fy=rd.number(i["fy"], f"{k}.fy", low=1.0, high=MAX_FOCAL),
        cx=rd.number(i["cx"], f"{k}.cx", limit=MAX_FOCAL),
        cy=rd.number(i["cy"], f"{k}.cy", limit=MAX_FOCAL),
        width=rd.integer(i["width"], f"{k}.width", minimum=1, maximum=MAX_IMAGE),
        height=rd.integer(i["height"], f"{k}.height", minimum=1, maximum=MAX_IMAGE),
    )
    kind = rd.one_of(m, "camera", ["pose", "ecm"])
    if kind == "pose":
        if "moves" in m:
            raise rd.fail("camera.moves",
                          "camera moves need the camera given as camera.ecm (joint values)")
        return CameraSpec(intrinsics=intr, pose=_pose(rd, m["pose"], "camera.pose"))
    ecm = _robot(rd, m["ecm"], "camera.ecm", path, default_frame="camera", joints=True)
    return CameraSpec(intrinsics=intr, ecm=ecm, ecm_joints=ecm.joints,
                      moves=_moves(rd, m.get("moves", [])))


def _moves(rd: Reader, node: Any) -> tuple[CameraMove, ...]:
    if not isinstance(node, list):
        raise rd.fail("camera.moves", "expected a list of {step, ecm_joints}")
    out = []
    for i, item in enumerate(node):
        k = f"camera.moves[{i}]"
        mv = rd.mapping(item, k, {"step", "ecm_joints"}, {"step", "ecm_joints"})
        step = rd.integer(mv["step"], f"{k}.step", minimum=1, maximum=MAX_HORIZON)
        if out and step <= out[-1].step:
            raise rd.fail(f"{k}.step", "moves must be listed in increasing step order")
        out.append(CameraMove(step, rd.vector(mv["ecm_joints"], f"{k}.ecm_joints",
                                              limit=MAX_ANGLE)))
    return tuple(out)


def _endpoint(rd: Reader, node: Any, key: str, path: Path) -> EndpointSpec:
    grasp = _GRASP_KEYS if key == "goal" else ()  # (read by _grasp)
    m = rd.mapping(node, key, {"joints", "pose", "relative", *grasp})
    kind = rd.one_of(m, key, ["joints", "pose", "relative"])
    if kind == "joints":
        return EndpointSpec(joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE),
                            key=f"{key}.joints")
    if kind == "relative":
        r = rd.mapping(m["relative"], f"{key}.relative", {"arm", "pose"}, {"arm", "pose"})
        arm = _robot(rd, r["arm"], f"{key}.relative.arm", path, default_frame="tool", joints=True)
        pose = _pose6(rd, r["pose"], f"{key}.relative.pose")
        return EndpointSpec(relative=RelativeGoal(arm, pose), key=f"{key}.relative")
    return EndpointSpec(pose=_pose6(rd, m["pose"], f"{key}.pose"), key=f"{key}.pose")


_GRASP_KEYS = ("tolerance", "confidence")


def _grasp(rd: Reader, node: Any) -> GraspSpec:
    """`goal.tolerance: {position, angle}` ([m], [rad]; default 5 mm, 0.2 rad) and
    `goal.confidence` (in (0, 1); default none): the grasp's success and how sure to be of it."""
    m = node if isinstance(node, Mapping) else {}  # (a goal that is no mapping: _endpoint's error)
    d = GraspSpec()
    tol = rd.mapping(m.get("tolerance", {}), "goal.tolerance", {"position", "angle"})
    position = rd.number(tol.get("position", d.position), "goal.tolerance.position",
                         positive=True, high=1.0)
    angle = rd.number(tol.get("angle", d.angle), "goal.tolerance.angle", positive=True,
                      high=np.pi)
    confidence = m.get("confidence")
    if confidence is not None:
        confidence = rd.number(confidence, "goal.confidence")
        if not 0.0 < confidence < 1.0:
            raise rd.fail("goal.confidence", f"must be strictly between 0 and 1 (e.g. 0.95), got "
                                             f"{confidence:g}")
    return GraspSpec(position=position, angle=angle, confidence=confidence)


def _pose6(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A tool pose `{position: [x, y, z], axis_angle: [rx, ry, rz]}` or the same as one
    list of 6 numbers."""
    if isinstance(node, (list, tuple)):
        if len(node) != 6:
            raise rd.fail(key, "expected 6 numbers [px, py, pz, rx, ry, rz] (position [m], "
                               "axis-angle [rad]) or {position, axis_angle}, got a list "
                               f"of {len(node)}")
        return np.array([rd.number(v, f"{key}[{i}]", limit=MAX_POSITION if i < 3 else MAX_ANGLE)
                         for i, v in enumerate(node)])
    p = rd.mapping(node, key, {"position", "axis_angle"}, {"position", "axis_angle"})
    return np.concatenate([rd.vector(p["position"], f"{key}.position", 3, limit=MAX_POSITION),
                           rd.vector(p["axis_angle"], f"{key}.axis_angle", 3, limit=MAX_ANGLE)])
