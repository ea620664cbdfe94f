"""Arms and needles: the animated arm (with its needle) and the arms that hold still.

Nodes, under the scene root (`/meshcat`):

    robot/<geometry>            the solution's arm, animated along `q`
    robot/needle                the needle it holds (`robot.needle`), animated with it
    other_arms/<k>/<geometry>   `other_arms[k]` at its fixed `q` (own prefix per arm, so two
                                PSMs with the same link names do not collide)
    other_arms/<k>/needle       the needle that arm holds, if any

A needle `{"radius": r, "grasp": G}` held by an arm has the world pose
`frame_pose(q, arm.frame) @ G`; it is drawn as a silver tube (0.5 mm thick) along a
3/4 circle of radius r in that frame's x-y plane, centred at its origin. The arc's
gap faces away from the jaw (the jaw holds the middle of the arc); Pinocchio names
geometry objects `<link>_<k>`, so `needle` never clashes with a link's node.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import meshcat.geometry as mg
import numpy as np
from meshcat.animation import Animation

from surestep_ocp.errors import SurestepError, shown
from surestep_ocp.output.files import MAX_URDF_BYTES, input_file_problem

from . import style
from .robot_visual import RobotVisual
from .shapes import arc_points, transform_points, tube
from .solutions import Solution
from .timeline import Timeline

NEEDLE_NODE = "needle"


@dataclass(frozen=True)
class Needle:
    """A needle held by an arm: arc radius [m], 4x4 pose in the arm's frame, that frame's name."""

    radius: float
    grasp: np.ndarray
    frame: str

    @classmethod
    def of(cls, arm: dict) -> "Needle | None":
        """The needle of a `robot` / `other_arms[k]` entry, or None."""
        spec = arm.get("needle")
        if not spec:
            return None
        grasp = np.asarray(spec.get("grasp", np.eye(4)), dtype=float).reshape(4, 4)
        return cls(float(spec["radius"]), grasp, str(arm.get("frame", "tool")))

    def local_points(self, n: int = 61) -> np.ndarray:
        """(n, 3) arc points [m] in the needle frame (x-y plane, centred, NEEDLE_SWEEP_DEG)."""
        jaw = -self.grasp[:3, :3].T @ self.grasp[:3, 3]  # the jaw's origin in the needle frame
        mid = math.atan2(jaw[1], jaw[0]) if np.hypot(jaw[0], jaw[1]) > 1e-9 else -math.pi / 2
        sweep = math.radians(style.NEEDLE_SWEEP_DEG)
        return arc_points(self.radius, mid - sweep / 2, sweep, n)

    def pose(self, robot: RobotVisual, q: np.ndarray) -> np.ndarray:
        """4x4 world pose of the needle frame with the arm at q."""
        return robot.frame_pose(q, self.frame) @ self.grasp

    def draw(self, node, robot: RobotVisual, q: np.ndarray) -> np.ndarray:
        """Set the needle's object and pose at q on `node`; return its world arc points (n, 3)."""
        local = self.local_points()
        mat = mg.MeshPhongMaterial(color=style.rgb_int(style.NEEDLE_COLOR), shininess=60,
                                   specular=0x999999)
        node.set_object(tube(local, style.NEEDLE_TUBE_RADIUS), mat)
        T = self.pose(robot, q)
        node.set_transform(T)
        return transform_points(T, local)


def arm_q(robot: RobotVisual, spec: dict) -> np.ndarray:
    """Configuration of an arm entry's `q` (a list in model joint order, or with
    `joint_names`, or a {joint: value} dict); neutral if missing."""
    q = spec.get("q") or []
    qv = (robot.q_vector(list(q.values()), list(q)) if isinstance(q, dict)
          else robot.q_vector(q, spec.get("joint_names")))
    return qv if qv is not None else robot.q_vector([], [])


def first_q(robot: RobotVisual, sol: Solution) -> np.ndarray:
    """First reachable configuration of the solution, else the neutral one."""
    for q in sol.get("q") or []:
        v = robot.q_vector(q, sol.get("joint_names"))
        if v is not None:
            return v
    return robot.q_vector([], [])


@dataclass
class StillArms:
    """What `draw_other_arms` drew: geometry nodes and needle arcs (world points) per node."""

    nodes: list[str]
    needles: dict[str, np.ndarray]


def draw_other_arms(scene, sol: Solution, load: Callable[[dict, str], RobotVisual | None],
                    color: Sequence[float] | None = None) -> StillArms:
    """Draw every `other_arms[k]` (and its needle) at its fixed q under `scene/other_arms/k`.

    `load(spec, root)` gives the arm's RobotVisual (None: skipped, already warned).
    """
    out = StillArms([], {})
    for k, spec in enumerate(sol.get("other_arms") or []):
        robot = load(spec, str(k))
        if robot is None:
            continue
        q = arm_q(robot, spec)
        parent = scene["other_arms"]
        out.nodes += robot.draw(parent, q, color)
        needle = Needle.of(spec)
        if needle is not None:
            out.needles.update(draw_needle(parent[str(k)], robot, needle, q))
    return out


def draw_needle(parent, robot: RobotVisual, needle: Needle, q: np.ndarray) -> dict[str, np.ndarray]:
    """Draw `needle` at `parent/needle`; {node path: world arc points}, {} if FK fails."""
    try:
        node = parent[NEEDLE_NODE]
        return {node.path.lower(): needle.draw(node, robot, q)}
    except Exception as exc:  # e.g. an unknown frame name: draw the rest of the scene
        warnings.warn(f"cannot draw the needle of {parent.path.lower()}: {exc}")
        return {}


def animate_arm(anim: Animation, scene, robot: RobotVisual, sol: Solution, timeline: Timeline,
                needle: Needle | None = None) -> int:
    """Key-frame the arm (and its needle) along the solution's joint path, linear in q between
    nodes; an unreachable node (q null) holds the previous configuration. Returns the number
    of frames (0 if there is nothing to animate)."""
    names = sol.get("joint_names")
    qs = [robot.q_vector(q, names) for q in sol.get("q") or []]
    last = None

    def key(frame: int, q: np.ndarray) -> None:
        with anim.at_frame(scene, frame) as f:
            robot.set_frame(f, q)
            if needle is not None:
                f[robot.root][NEEDLE_NODE].set_transform(needle.pose(robot, q))

    for t, q in enumerate(qs):
        if q is None:
            continue
        if last is None:
            key(timeline.node_frame(t), q)
        else:
            for frame, s in timeline.sub_frames(t):
                key(frame, last + (q - last) * s)
        last = q
    return timeline.node_frame(len(qs) - 1) + timeline.per_sub if len(qs) > 1 else 0




def check_urdf_file(urdf: Path, root: str, given, source: str | None = None) -> None:
    """A one-line SurestepError unless `urdf` is a regular file of at most MAX_URDF_BYTES: a device
    (/dev/zero) would be read until memory runs out, a pipe would block forever."""
    name = "robot" if root == "robot" else "ecm" if root == "ecm" else f"other_arms[{root}]"
    name = f"{shown(str(source), 200)}: {name}" if source else name
    try:
        problem = input_file_problem(urdf, MAX_URDF_BYTES)
    except OSError as exc:
        raise FileNotFoundError(str(urdf)) from exc  # a warning: the rest of the scene is drawn
    if problem is not None:
        raise SurestepError(f"{name}.urdf {shown(str(given), 120)}: {problem}; a URDF file is read")


def load_arm(spec: dict, root: str, resolve: Callable[[str], Path],
             package_dirs: Sequence[Path], source: str | None = None) -> RobotVisual | None:
    """RobotVisual of an arm entry (`urdf`, `base_pose`), or None with a warning."""
    try:
        base = np.asarray(spec.get("base_pose", np.eye(4)), dtype=float).reshape(4, 4)
        urdf = resolve(spec["urdf"])
        check_urdf_file(urdf, root, spec["urdf"], source)
        return RobotVisual.load(urdf, base, root, package_dirs)
    except SurestepError:  # a device, a pipe or a huge file: an error, not a warning
        raise
    except Exception as exc:  # a missing robot must not hide the paths
        warnings.warn(f"cannot draw {root} from {spec.get('urdf')!r}: {exc}")
        return None
