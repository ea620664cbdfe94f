"""Pointing Meshcat's default camera: look-at views and the endoscope's own view.

Meshcat 0.3.2's OrbitControls always aim the camera at the origin of the
three.js world with world +z (the scene's up) as screen-up: `lookAt` takes a
world-space target, whatever transform the camera's parent nodes carry. So a
view is set by moving the *scene* instead of the camera: the scene root
(`/meshcat`) gets the display transform

    M = [A | -A target],   A = [e_x, e_z, -e_y] [x_v, y_v, z_v]^T

(`[x_v, y_v, z_v]` = `look_at_frame(eye, target, up)` rotation), which puts
`target` at the origin, `up` along +z and `eye` at (0, -d, 0); the camera sits
at `(0, 0, d)` in `/Cameras/default/rotated` (meshcat's default +90 deg x
rotation, kept), i.e. at (0, -d, 0) in display coordinates. Mouse orbiting then
turns around `target`. Node transforms below the root stay in world coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np


@dataclass(frozen=True)
class CameraView:
    """A Meshcat camera placement in the world frame.

    Attributes:
        eye: camera centre [m]. target: point looked at (and orbited) [m].
        up: world direction shown as screen-up. fov_deg: vertical field of view [deg].
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_deg: float = 50.0


def look_at_frame(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """4x4 pose at `target` with z towards `eye` and y along `up` (made orthogonal)."""
    eye, target, up = (np.asarray(v, dtype=float) for v in (eye, target, up))
    z = eye - target
    d = np.linalg.norm(z)
    if d < 1e-9:
        raise ValueError("eye and target coincide")
    z /= d
    y = up - z * (up @ z)
    if np.linalg.norm(y) < 1e-9:  # up parallel to the view direction: pick any normal
        y = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = target
    return T


def display_transform(view: CameraView) -> np.ndarray:
    """4x4 world -> display transform M of a view (see the module docstring)."""
    L = look_at_frame(view.eye, view.target, view.up)
    A = np.column_stack([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) @ L[:3, :3].T
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = A, -A @ np.asarray(view.target, dtype=float)
    return M


def set_camera_view(
    vis, view: CameraView, near: float = 0.002, far: float = 20.0, scene_root: str = "/meshcat"
) -> None:
    """Show `scene_root` as seen from `view` (clip planes `near`, `far` in [m])."""
    dist = float(np.linalg.norm(np.asarray(view.eye, float) - np.asarray(view.target, float)))
    vis[scene_root].set_transform(display_transform(view))
    vis["/Cameras/default"].set_transform(np.eye(4))
    rotated = np.eye(4)
    rotated[1:3, 1:3] = [[0.0, -1.0], [1.0, 0.0]]  # meshcat's default: +90 deg about x
    vis["/Cameras/default/rotated"].set_transform(rotated)
    cam = vis["/Cameras/default/rotated/<object>"]
    cam.set_property("position", [0.0, 0.0, dist])
    cam.set_property("fov", float(view.fov_deg))
    cam.set_property("near", float(near))
    cam.set_property("far", float(far))


def endoscope_view(
    camera_pose: np.ndarray, intrinsics: Mapping[str, float], depth: float = 0.15
) -> CameraView:
    """The endoscope's own view: from its centre, along its +z, image y down.

    `camera_pose` is the 4x4 world pose of the OpenCV camera frame; the view
    looks at the point `depth` [m] ahead (the orbit centre) and uses the vertical
    field of view of the intrinsics, 2 atan(H / (2 fy)).
    """
    T = np.asarray(camera_pose, dtype=float)
    half_height = float(intrinsics["height"]) / (2.0 * float(intrinsics["fy"]))
    fov = math.degrees(2.0 * math.atan(half_height))
    return CameraView(T[:3, 3], T[:3, 3] + depth * T[:3, 2], -T[:3, 1], fov)


def set_endoscope_view(
    vis,
    camera_pose: np.ndarray,
    intrinsics: Mapping[str, float],
    depth: float = 0.15,
    scene_root: str = "/meshcat",
) -> CameraView:
    """Show the scene from the endoscope's pose (see `endoscope_view`); return the view."""
    view = endoscope_view(camera_pose, intrinsics, depth)
    set_camera_view(vis, view, near=0.001, scene_root=scene_root)
    return view


def overview(
    points: np.ndarray, camera_pose: np.ndarray, fov_deg: float = 45.0, margin: float = 1.05
) -> CameraView:
    """A three-quarter view framing `points` (N, 3, world) [m], e.g. paths and image footprint.

    The orbit centre is the centre of the points' bounding box and the distance
    fits the sphere around it that holds them. The view comes from behind, right
    of and above the endoscope (in its image axes), so the paths keep the image's
    left/right sense while their depth stays visible; image-up (-y of the camera)
    is screen-up, so the overview is not upside down against the endoscope image
    when the endoscope looks down the world z axis.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    T = np.asarray(camera_pose, dtype=float)
    target = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    radius = max(float(np.linalg.norm(pts - target, axis=1).max()), 0.02)
    direction = -1.0 * T[:3, 2] + 0.35 * T[:3, 0] - 0.5 * T[:3, 1]
    direction /= np.linalg.norm(direction)
    dist = margin * radius / math.sin(math.radians(fov_deg) / 2.0)
    up = -T[:3, 1]
    return CameraView(target + dist * direction, target, up, fov_deg)
