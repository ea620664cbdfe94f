"""The SURESTEP Meshcat scene: arms, needles, endoscope, camera frustum, goal, paths, ellipsoids.

Scene tree (under Meshcat's `/meshcat` root), readable as a legend:

    /meshcat/robot/<geometry>          PSM (or any URDF) visual geometry, animated
    /meshcat/robot/needle              the needle it holds (`robot.needle`), animated
    /meshcat/other_arms/<k>/<geometry> arms that hold still (`other_arms`), at their q
    /meshcat/other_arms/<k>/needle     ... and their needles (see arms.py)
    /meshcat/ecm/<geometry>            endoscope arm, when the solution has `ecm`
    /meshcat/camera/{frustum,footprint,footprint_fill,triad}   animated if it moves
    /meshcat/camera_history/<k>/frustum  faint, one per distinct `camera_poses` pose
    /meshcat/goal/{triad,marker}
    /meshcat/start/marker              the tool's start position (black sphere)
    /meshcat/paths/<method>/{line,tube}
    /meshcat/paths/<method>/ellipsoids/<t>   3-sigma position ellipsoid of node t
                                             (see paths.py for opacity and hiding; paths the
                                             arm does not follow show a few, fainter)

The static page (`write_static_html`) carries a legend (legend.py): each method's
colour, the start, the goal, the ellipsoids and the camera.

Everything is drawn in the world frame [m]; camera-frame data are mapped with
the solution's `camera_pose` (per node with `camera_poses`). The `/meshcat` node's
own transform is the view's display transform (see view.py); the poses of the
nodes below it are world poses.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import meshcat
import meshcat.geometry as mg
import numpy as np
import umsgpack
from meshcat.animation import Animation

from surestep_ocp.output.files import check_finite
from surestep_ocp.problem.paths import resolve_urdf

from . import style
from .arms import Needle, animate_arm, arm_q, draw_needle, draw_other_arms, first_q, load_arm
from .camera import animate_camera, depth_star, draw_camera
from .legend import legend_html
from .paths import PathInfo, draw_path
from .recorder import recording_visualizer
from .solutions import Solution, camera_pose, order_methods, world_points, world_pose
from .timeline import Timeline
from .view import CameraView, overview, set_camera_view, set_endoscope_view

ROOT = "/meshcat"
PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the repository root for an editable install
ERD_PREFIX = "example-robot-data:"
DEFAULT_ANIMATED = ("ocp", "ocp-replanned")  # the arm follows the first present


@dataclass
class SceneInfo:
    """Summary of a built scene, for tests and for the caller's messages."""

    nodes: list[str] = field(default_factory=list)  # every Meshcat node set, full paths
    paths: dict[str, PathInfo] = field(default_factory=dict)
    animated: str | None = None  # method whose trajectory the arm follows
    robot_nodes: list[str] = field(default_factory=list)
    ecm_nodes: list[str] = field(default_factory=list)
    other_arm_nodes: list[str] = field(default_factory=list)  # other_arms/<k>/<geometry>
    needles: dict[str, np.ndarray] = field(default_factory=dict)  # node -> (n, 3) world arc
    frustum: np.ndarray | None = None  # (16, 3) world segment end points
    footprint: np.ndarray | None = None  # (4, 3) world corners of the image at d*
    camera_history: list[np.ndarray] = field(default_factory=list)  # distinct 4x4 camera poses
    camera_switch_steps: list[int] = field(default_factory=list)  # steps where the camera moves
    goal: np.ndarray | None = None  # 4x4 world goal pose
    start: np.ndarray | None = None  # (3,) world start position of the animated method's tool
    view: CameraView | None = None
    n_frames: int = 0  # animation frames


def resolve_file(path: str | Path, repo_root: Path | None, sol: Solution | None = None) -> Path:
    """Find a file named relative to the repository root (or absolute, or `example-robot-data:`).

    Tries `repo_root`, the current directory, the package's repository root, the
    solution's problem-file folder and the folders above the solution's source
    file; `example-robot-data:<path>` is looked up in that package
    (`surestep_ocp.problem.paths.resolve_urdf`). Raises FileNotFoundError.
    """
    if str(path).startswith(ERD_PREFIX):
        found = resolve_urdf(str(path))
        if found.exists():
            return found
        raise FileNotFoundError(f"{path} ({found})")
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


def _loader(repo_root: Path | None, sol: Solution):
    """`load(spec, root) -> RobotVisual | None` for the arms of one solution."""
    dirs = [p for p in (repo_root, PACKAGE_ROOT) if p]
    return lambda spec, root: load_arm(spec, root, lambda u: resolve_file(u, repo_root, sol), dirs,
                                       sol.get("_source"))


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


def _draw_start(vis, sol: Solution, info: SceneInfo) -> None:
    """The tool's start position as a small black sphere."""
    pts = world_points(sol)
    if not len(pts):
        return
    T = np.eye(4)
    T[:3, 3] = pts[0]
    vis["start"].set_transform(T)
    vis["start"]["marker"].set_object(mg.Sphere(style.START_RADIUS),
                                      mg.MeshPhongMaterial(color=style.rgb_int(style.START_COLOR)))
    info.start = pts[0]
    info.nodes.append(f"{ROOT}/start/marker")


def _draw_arms(vis, scene, main: Solution, info: SceneInfo, load, robot_color, timeline) -> None:
    """The animated arm and its needle, the still arms, the ECM; the animation (arm, needle,
    moving camera) on one `timeline`."""
    anim = Animation(default_framerate=timeline.fps)
    robot = load(main["robot"], "robot") if main.get("robot") else None
    if robot is not None:
        q0 = first_q(robot, main)
        info.robot_nodes = robot.draw(scene, q0, robot_color)
        needle = Needle.of(main["robot"])
        if needle is not None:
            drawn = draw_needle(scene["robot"], robot, needle, q0)
            info.needles.update(drawn)
            needle = needle if drawn else None
        info.n_frames = animate_arm(anim, scene, robot, main, timeline, needle)
    still = draw_other_arms(scene, main, load)
    info.other_arm_nodes = still.nodes
    info.needles.update(still.needles)
    ecm_spec = main.get("ecm")
    ecm = load(ecm_spec, "ecm") if ecm_spec else None
    if ecm is not None:
        info.ecm_nodes = ecm.draw(scene, arm_q(ecm, ecm_spec))
    info.nodes += info.robot_nodes + info.other_arm_nodes + list(info.needles) + info.ecm_nodes
    info.n_frames = max(info.n_frames, animate_camera(anim, scene, main, timeline))
    if info.n_frames > 0 and anim.clips:
        vis.set_animation(anim, play=True, repetitions=1)


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
        animate: method the arm follows; default "ocp" if present, else "ocp-replanned"
            (`surestep replan`), else the first.
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
    chosen = animate or next((m for m in DEFAULT_ANIMATED if m in methods), methods[0])
    if chosen not in methods:
        raise ValueError(f"no solution for method {chosen!r} (have {methods})")
    main = sols[methods.index(chosen)]
    info = SceneInfo(animated=chosen)
    vis["/Background"].set_property("top_color", list(style.BACKGROUND_TOP))
    vis["/Background"].set_property("bottom_color", list(style.BACKGROUND_BOTTOM))
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)
    scene = vis[ROOT]
    cam = draw_camera(scene, main)
    info.frustum, info.footprint, info.nodes = cam.frustum, cam.footprint, cam.nodes
    info.camera_history, info.camera_switch_steps = cam.history, cam.switch_steps
    _draw_goal(scene, main, info)
    _draw_start(scene, main, info)
    if hide_above is None:  # ellipsoids wider than the image at d* start hidden
        hide_above = 0.5 * float(np.linalg.norm(info.footprint[2] - info.footprint[0]))
    for k, (sol, color) in enumerate(zip(sols, style.method_colors(methods).values())):
        wide = style.ANIMATED_TUBE_SCALE if sol is main else 1.0  # the arm's path on top
        p = draw_path(scene["paths"], sol, color, hide_above, priority=len(sols) - k,
                      tube_radius=wide * style.TUBE_RADIUS,
                      ellipsoids_shown=None if sol is main else style.OTHER_ELLIPSOIDS,
                      opacity_scale=1.0 if sol is main else style.OTHER_ELLIPSOID_OPACITY)
        info.paths[p.method] = p
        info.nodes += [p.line_node, f"{ROOT}/paths/{p.method}/tube", *p.ellipsoid_nodes]
    _draw_arms(vis, scene, main, info, _loader(repo_root, main), robot_color,
               Timeline(seconds_per_step))
    d_star = depth_star(main)
    if endoscope:
        info.view = set_endoscope_view(vis, camera_pose(main), main["camera"], d_star)
    else:
        pts = [p.points for p in info.paths.values()] + cam.footprints
        pts += list(info.needles.values())
        if info.goal is not None:
            pts.append(info.goal[None, :3, 3])
        info.view = overview(np.concatenate(pts), camera_pose(main))
        set_camera_view(vis, info.view)
    return info


def _unpacked(obj):
    """A lowered Meshcat command with its packed float arrays (msgpack Ext) as numpy arrays."""
    if isinstance(obj, dict):
        if (obj.get("type") in ("Float32Array", "Float64Array")
                and isinstance(obj.get("array"), umsgpack.Ext)):
            dtype = np.float32 if obj["type"] == "Float32Array" else np.float64
            return {**obj, "array": np.frombuffer(obj["array"].data, dtype=dtype)}
        return {k: _unpacked(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_unpacked(v) for v in obj]
    return obj


def check_scene_finite(window) -> None:
    """`files.NonFinite` naming the first scene node holding NaN or Infinity (its transform,
    property, object or animation), so that no page or picture is written with one."""
    for path, commands in window.decoded.items():
        for command in commands:
            check_finite({path: _unpacked(command)}, "surestep show")


def write_static_html(
    solutions: Sequence[Solution], path: Path | str, repo_root: Path | None = None, **kwargs
) -> SceneInfo:
    """Build the scene offline (no server) and write it as one standalone HTML file with a legend.

    The file is written atomically: to a temporary file in the same folder, then
    `os.replace`d. `kwargs` go to `build_scene` (animate, endoscope, robot_color, ...).
    """
    path = Path(path)
    vis, window = recording_visualizer()
    info = build_scene(solutions, repo_root=repo_root, vis=vis, **kwargs)
    check_scene_finite(window)
    html = window.get_scene(overlay=legend_html(info))
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
