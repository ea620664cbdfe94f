"""The SURESTEP Meshcat scene: arm, endoscope, camera frustum, goal, paths, ellipsoids.

Scene tree (under Meshcat's `/meshcat` root), readable as a legend:

    /meshcat/robot/<geometry>          PSM (or any URDF) visual geometry, animated
    /meshcat/ecm/<geometry>            endoscope arm, when the solution has `ecm`
    /meshcat/camera/{frustum,footprint,footprint_fill,triad}
    /meshcat/goal/{triad,marker}
    /meshcat/paths/<method>/{line,tube}
    /meshcat/paths/<method>/ellipsoids/<t>   3-sigma position ellipsoid of node t
                                             (see paths.py for opacity and hiding)

Everything is drawn in the world frame [m]; camera-frame data are mapped with
the solution's `camera_pose`. The `/meshcat` node's own transform is the view's
display transform (see view.py); the poses of the nodes below it are world poses.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import meshcat
import meshcat.geometry as mg
import numpy as np
from meshcat.animation import Animation

from . import style
from .paths import PathInfo, draw_path
from .recorder import recording_visualizer
from .robot_visual import RobotVisual
from .shapes import (frustum_segments, image_corners, line_segments, quad, rectangle_segments,
                     transform_points)
from .solutions import Solution, camera_pose, order_methods, world_pose
from .view import CameraView, overview, set_camera_view, set_endoscope_view

ROOT = "/meshcat"
PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the repository root for an editable install


@dataclass
class SceneInfo:
    """Summary of a built scene, for tests and for the caller's messages."""

    nodes: list[str] = field(default_factory=list)  # every Meshcat node set, full paths
    paths: dict[str, PathInfo] = field(default_factory=dict)
    animated: str | None = None  # method whose trajectory the arm follows
    robot_nodes: list[str] = field(default_factory=list)
    ecm_nodes: list[str] = field(default_factory=list)
    frustum: np.ndarray | None = None  # (16, 3) world segment end points
    footprint: np.ndarray | None = None  # (4, 3) world corners of the image at d*
    goal: np.ndarray | None = None  # 4x4 world goal pose
    view: CameraView | None = None
    n_frames: int = 0  # animation frames


def resolve_file(path: str | Path, repo_root: Path | None, sol: Solution | None = None) -> Path:
    """Find a file named relative to the repository root (or absolute).

    Tries `repo_root`, the current directory, the package's repository root, the
    solution's problem-file folder and the folders above the solution's source
    file. Raises FileNotFoundError.
    """
    p = Path(path)
    if p.is_absolute():
        if p.exists():
            return p
        raise FileNotFoundError(p)
    bases = [repo_root, Path.cwd(), PACKAGE_ROOT]
    if sol is not None and sol.get("problem"):
        bases.append(Path(sol["problem"]).resolve().parent)  # paths relative to the problem file
    if sol is not None and sol.get("_source"):
        bases += list(Path(sol["_source"]).resolve().parents)
    for base in bases:
        if base is not None and (Path(base) / p).exists():
            return Path(base) / p
    raise FileNotFoundError(f"{p} (looked in {[str(b) for b in bases if b is not None]})")


def _load_robot(spec: dict, root: str, repo_root: Path | None, sol: Solution) -> RobotVisual | None:
    """RobotVisual of a `robot`/`ecm` entry, or None with a warning if it cannot be loaded."""
    try:
        urdf = resolve_file(spec["urdf"], repo_root, sol)
        base = np.asarray(spec.get("base_pose", np.eye(4)), dtype=float).reshape(4, 4)
        return RobotVisual.load(urdf, base, root, [p for p in (repo_root, PACKAGE_ROOT) if p])
    except Exception as exc:  # a missing robot must not hide the paths
        warnings.warn(f"cannot draw {root} from {spec.get('urdf')!r}: {exc}")
        return None


def _draw_camera(vis, sol: Solution, info: SceneInfo) -> None:
    """Frustum (to 1.5 d*), image footprint at d* and a triad at the camera."""
    T, K = camera_pose(sol), sol["camera"]
    d_star = float((sol.get("noise") or {}).get("depth_star", 0.15))
    cam = vis["camera"]
    cam.set_transform(T)
    seg = frustum_segments(K, 1.5 * d_star)
    cam["frustum"].set_object(line_segments(seg, style.CAMERA_COLOR))
    corners = image_corners(K, d_star)
    cam["footprint"].set_object(line_segments(rectangle_segments(corners), style.FOOTPRINT_COLOR))
    fill = mg.MeshBasicMaterial(color=style.rgb_int(style.FOOTPRINT_COLOR), opacity=0.08,
                                depthWrite=False)
    cam["footprint_fill"].set_object(quad(corners), fill)
    cam["triad"].set_object(mg.triad(style.TRIAD_SCALE))
    info.frustum, info.footprint = transform_points(T, seg), transform_points(T, corners)
    parts = ("frustum", "footprint", "footprint_fill", "triad")
    info.nodes += [f"{ROOT}/camera/{n}" for n in parts]


def _draw_goal(vis, sol: Solution, info: SceneInfo) -> None:
    """Goal pose as a triad plus a small sphere."""
    if sol.get("goal") is None:
        return
    G = world_pose(sol, sol["goal"])
    vis["goal"].set_transform(G)
    vis["goal"]["triad"].set_object(mg.triad(style.TRIAD_SCALE))
    mat = mg.MeshPhongMaterial(color=style.rgb_int(style.GOAL_COLOR), opacity=0.6)
    vis["goal"]["marker"].set_object(mg.Sphere(style.GOAL_RADIUS), mat)
    info.goal = G
    info.nodes += [f"{ROOT}/goal/triad", f"{ROOT}/goal/marker"]


def _animate(vis, robot: RobotVisual, sol: Solution, seconds_per_step: float, fps: int = 30,
             substeps: int = 4) -> int:
    """Key-frame the arm along the solution's joint path (linear in q between nodes)."""
    names = sol.get("joint_names")
    qs = [robot.q_vector(q, names) for q in sol.get("q") or []]
    anim = Animation(default_framerate=fps)
    frame, last = 0, None
    per_sub = max(1, int(round(seconds_per_step * fps / substeps)))
    for q in qs:
        if q is None:  # unreachable node: hold the previous configuration
            frame += per_sub * substeps
            continue
        steps = [q] if last is None else [last + (q - last) * (k / substeps)
                                          for k in range(1, substeps + 1)]
        for qk in steps:
            with anim.at_frame(vis, frame) as f:
                robot.set_frame(f, qk)
            frame += per_sub
        last = q
    if frame > per_sub:
        vis.set_animation(anim, play=True, repetitions=1)
    return frame


def _first_q(robot: RobotVisual, sol: Solution) -> np.ndarray:
    """First reachable configuration of the solution, else the neutral one."""
    for q in sol.get("q") or []:
        v = robot.q_vector(q, sol.get("joint_names"))
        if v is not None:
            return v
    return robot.q_vector([], [])


def build_scene(
    solutions: Sequence[Solution],
    repo_root: Path | None = None,
    vis: meshcat.Visualizer | None = None,
    animate: str | None = None,
    endoscope: bool = False,
    robot_color: Sequence[float] | None = None,
    seconds_per_step: float = 0.5,
    hide_above: float | None = None,
) -> SceneInfo:
    """Draw all solutions into `vis` (default: a new server-less recording visualizer).

    Args:
        solutions: solution dicts (see `solutions.load_solutions`); camera, goal and
            arm are taken from the animated one.
        repo_root: folder the `urdf` paths are relative to (default: tried in order,
            see `resolve_file`).
        vis: Meshcat visualizer (live server or recording); None makes a recording one.
        animate: method the arm follows; default "ocp" if present, else the first.
        endoscope: start from the endoscope's view instead of the overview.
        robot_color: RGB(A) in [0, 1] overriding the URDF colours of the arm.
        seconds_per_step: animation time per trajectory step [s].
        hide_above: ellipsoids whose largest radius exceeds this [m] are drawn but
            start hidden (toggle them in Meshcat's "Open Controls" scene tree);
            default: half the diagonal of the image footprint at d* (this hides
            the prior Sigma_0, 0.3 m for the paper's 1e-2 I); `math.inf`: never.

    Returns:
        SceneInfo listing the nodes and what was drawn (`info.vis` is not kept; pass
        your own `vis` to keep a handle).
    """
    if not solutions:
        raise ValueError("no solutions to show")
    sols = order_methods(solutions)
    if vis is None:
        vis, _ = recording_visualizer()
    methods = [s["method"] for s in sols]
    chosen = animate or ("ocp" if "ocp" in methods else methods[0])
    if chosen not in methods:
        raise ValueError(f"no solution for method {chosen!r} (have {methods})")
    main = sols[methods.index(chosen)]
    info = SceneInfo(animated=chosen)
    vis["/Background"].set_property("top_color", list(style.BACKGROUND_TOP))
    vis["/Background"].set_property("bottom_color", list(style.BACKGROUND_BOTTOM))
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)
    scene = vis[ROOT]
    _draw_camera(scene, main, info)
    _draw_goal(scene, main, info)
    if hide_above is None:  # ellipsoids wider than the image at d* start hidden
        hide_above = 0.5 * float(np.linalg.norm(info.footprint[2] - info.footprint[0]))
    for k, (sol, color) in enumerate(zip(sols, style.method_colors(methods).values())):
        p = draw_path(scene["paths"], sol, color, hide_above, priority=len(sols) - k)
        info.paths[p.method] = p
        info.nodes += [p.line_node, f"{ROOT}/paths/{p.method}/tube", *p.ellipsoid_nodes]
    robot = _load_robot(main["robot"], "robot", repo_root, main) if main.get("robot") else None
    if robot is not None:
        info.robot_nodes = robot.draw(scene, _first_q(robot, main), robot_color)
        info.n_frames = _animate(scene, robot, main, seconds_per_step)
    ecm_spec = main.get("ecm")
    ecm = _load_robot(ecm_spec, "ecm", repo_root, main) if ecm_spec else None
    if ecm is not None:
        q = ecm_spec.get("q") or []
        qv = ecm.q_vector(list(q.values()), list(q)) if isinstance(q, dict) else \
            ecm.q_vector(q, ecm_spec.get("joint_names"))
        info.ecm_nodes = ecm.draw(scene, qv if qv is not None else ecm.q_vector([], []))
    info.nodes += info.robot_nodes + info.ecm_nodes
    d_star = float((main.get("noise") or {}).get("depth_star", 0.15))
    if endoscope:
        info.view = set_endoscope_view(vis, camera_pose(main), main["camera"], d_star)
    else:
        pts = [p.points for p in info.paths.values()] + [info.footprint]
        if info.goal is not None:
            pts.append(info.goal[None, :3, 3])
        info.view = overview(np.concatenate(pts), camera_pose(main))
        set_camera_view(vis, info.view)
    return info


def write_static_html(
    solutions: Sequence[Solution], path: Path | str, repo_root: Path | None = None, **kwargs
) -> SceneInfo:
    """Build the scene offline (no server) and write it as one standalone HTML file.

    The file is written atomically: to a temporary file in the same folder, then
    `os.replace`d. `kwargs` go to `build_scene` (animate, endoscope, robot_color, ...).
    """
    path = Path(path)
    vis, window = recording_visualizer()
    info = build_scene(solutions, repo_root=repo_root, vis=vis, **kwargs)
    html = window.get_scene()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(html)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return info
