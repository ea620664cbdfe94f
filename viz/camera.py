"""The endoscope camera: frustum, image footprint and triad, and where the camera moves.

Nodes, under the scene root (`/meshcat`):

    camera/{frustum,footprint,footprint_fill,triad}   the current camera (node transform =
                                                      its world pose), animated when it moves
    camera_history/<k>/frustum                        one faint frustum per distinct camera
                                                      pose k (fainter the earlier), only
                                                      when the solution has `camera_poses`

With `camera_poses` (one 4x4 world pose per node; the camera moves during the motion),
the camera node starts at `camera_poses[0]` and, at every step t where the pose
changes, is key-framed at `camera_poses[t-1]` when node t-1 is reached and at
`camera_poses[t]` when node t is (it moves during that step, as the arm does).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import meshcat.geometry as mg
import numpy as np
from meshcat.animation import Animation

from . import style
from .shapes import (frustum_segments, image_corners, line_segments, quad, rectangle_segments,
                     transform_points)
from .solutions import Solution, camera_pose
from .timeline import Timeline


@dataclass
class CameraInfo:
    """What was drawn for the camera (world frame, metres)."""

    nodes: list[str] = field(default_factory=list)
    frustum: np.ndarray | None = None  # (16, 3) segment end points at the first pose
    footprint: np.ndarray | None = None  # (4, 3) image corners at d*, first pose
    history: list[np.ndarray] = field(default_factory=list)  # distinct 4x4 poses, in order
    history_nodes: list[str] = field(default_factory=list)  # camera_history/<k> per pose
    footprints: list[np.ndarray] = field(default_factory=list)  # (4, 3) per distinct pose
    switch_steps: list[int] = field(default_factory=list)  # steps t where the pose changes


def camera_schedule(sol: Solution) -> list[np.ndarray]:
    """4x4 world camera pose per node (`camera_poses`), or [] when the camera holds still."""
    return [np.asarray(C, dtype=float).reshape(4, 4) for C in sol.get("camera_poses") or []]


def switch_steps(cams: list[np.ndarray], tol: float = 1e-12) -> list[int]:
    """Steps t >= 1 whose camera pose differs from that of step t-1."""
    return [t for t in range(1, len(cams)) if np.abs(cams[t] - cams[t - 1]).max() > tol]


def depth_star(sol: Solution) -> float:
    """The solution's preferred depth d* [m] (0.15 if not given)."""
    return float((sol.get("noise") or {}).get("depth_star", 0.15))


def draw_camera(scene, sol: Solution) -> CameraInfo:
    """Frustum (to 1.5 d*), image footprint at d* and a triad at the (first) camera pose;
    with `camera_poses`, a faint frustum at every distinct pose too."""
    T, K, d = camera_pose(sol), sol["camera"], depth_star(sol)
    info = CameraInfo()
    cams = camera_schedule(sol)
    if cams:
        T = cams[0]
    cam = scene["camera"]
    cam.set_transform(T)
    seg, corners = frustum_segments(K, 1.5 * d), image_corners(K, d)
    cam["frustum"].set_object(line_segments(seg, style.CAMERA_COLOR))
    cam["footprint"].set_object(line_segments(rectangle_segments(corners), style.FOOTPRINT_COLOR))
    fill = mg.MeshBasicMaterial(color=style.rgb_int(style.FOOTPRINT_COLOR), opacity=0.08,
                                depthWrite=False)
    cam["footprint_fill"].set_object(quad(corners), fill)
    cam["triad"].set_object(mg.triad(style.TRIAD_SCALE))
    info.frustum, info.footprint = transform_points(T, seg), transform_points(T, corners)
    info.nodes += [f"{cam.path.lower()}/{n}" for n in ("frustum", "footprint", "footprint_fill",
                                                       "triad")]
    info.footprints = [info.footprint]
    if not cams:
        return info
    info.switch_steps = switch_steps(cams)
    info.history = [cams[0]] + [cams[t] for t in info.switch_steps]
    lo, hi = style.CAMERA_HISTORY_OPACITY
    n = len(info.history)
    for k, C in enumerate(info.history):
        alpha = hi if n == 1 else lo + (hi - lo) * k / (n - 1)
        node = scene["camera_history"][str(k)]
        node.set_transform(C)
        node["frustum"].set_object(line_segments(seg, style.CAMERA_COLOR, alpha))
        info.history_nodes.append(node.path.lower())
        info.nodes.append(f"{node.path.lower()}/frustum")
    info.footprints = [transform_points(C, corners) for C in info.history]
    return info


def animate_camera(anim: Animation, scene, sol: Solution, timeline: Timeline) -> int:
    """Key-frame the camera node at the steps where `camera_poses` changes (see the module
    docstring); return the last keyed frame (0: the camera holds still)."""
    cams = camera_schedule(sol)
    keys: dict[int, np.ndarray] = {}
    for t in switch_steps(cams):
        keys.setdefault(0, cams[0])
        keys[timeline.node_frame(t - 1)] = cams[t - 1]
        keys[timeline.node_frame(t)] = cams[t]
    for frame in sorted(keys):
        with anim.at_frame(scene, frame) as f:
            f["camera"].set_transform(keys[frame])
    return max(keys, default=0)
