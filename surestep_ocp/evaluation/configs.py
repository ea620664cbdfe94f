"""Random initial configurations for the evaluation (`problems/evaluations/evaluation.yaml`).

An evaluation file names a base problem (robot, camera intrinsics, noise, solver
settings; its `horizon`, `gradient` and `limits` sections can be replaced) and uniform boxes of ECM
joints (the camera pose), PSM start joints and PSM goal joints. Configuration `i` of seed `s` is
drawn by rejection sampling from its own generator `numpy.random.default_rng([s, i])`, so it does
not depend on how many configurations are run, in which order, or in which process; every method
sees the same configurations. A draw is kept when start and goal are in front of the camera, at a
depth inside `accept.depth`, project inside the image with `accept.image_margin` to spare, and are
at least `accept.min_distance` apart. Start and goal are joint samples inside the limits, so
reachable by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurestepError
from ..model.lie import matrix_to_pose
from ..problem.load import load_problem, read_yaml
from ..problem.parse import MAX_HORIZON, _gradient, _limits, read_detection
from ..problem.paths import find_shipped, resolve_path
from ..problem.spec import EndpointSpec, Problem
from ..model.robot import Robot
from .pacing import PACES
from .rollout import Detection
from ..problem.schema import Reader
from ..problem.setup import Setup, build_setup, load_robot

_TOP = {"description", "base", "horizon", "ecm_joints", "start_joints", "goal_joints", "accept",
        "max_tries", "gradient", "detection", "grasp", "limits", "execution"}

# Grasp tolerances of the simulated Table II (docs/evaluation.md, "Table II"): the final true pose
# counts as a successful regrasp within these of the goal. 5 mm: half the Large Needle Driver's
# 10.2 mm jaw (wrist-yaw pivot to tip), so the needle's wire still lands between the jaws, and under
# half the 11.5 mm needle radius; 0.2 rad: the jaw tip then moves 10.2 mm x 0.2 = 2 mm, inside that
# budget.
GRASP_POSITION_M = 0.005
GRASP_ANGLE_RAD = 0.2


@dataclass(frozen=True)
class Box:
    """Uniform joint box [low, high] (one value per joint)."""

    low: np.ndarray
    high: np.ndarray

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.low, self.high)


@dataclass(frozen=True)
class EvaluationSpec:
    path: Path
    base_path: Path
    base: Problem  # with the evaluation's horizon
    horizon: int
    ecm_joints: Box | None  # None: the base problem's camera is kept
    start_joints: Box
    goal_joints: Box
    depth: tuple[float, float]  # [m] accepted depth of start and goal
    image_margin: float  # fraction of the image width/height kept free at each border
    min_distance: float  # [m] between start and goal positions
    max_tries: int
    description: str = ""
    # None: every rollout step observes (detection.enabled: false)
    detection: Detection | None = Detection()
    grasp_position: float = GRASP_POSITION_M  # [m] success tolerance of the final true position
    grasp_angle: float = GRASP_ANGLE_RAD  # [rad] ... and of the final true orientation
    # how the rollouts run a plan (pacing.py): planned | limits (the tool's speed limits)
    pace: str = "planned"


@dataclass(frozen=True)
class Configuration:
    index: int
    ecm_joints: np.ndarray | None
    q_start: np.ndarray
    q_goal: np.ndarray
    x_start: np.ndarray  # camera frame
    x_goal: np.ndarray
    tries: int

    def to_dict(self) -> dict:
        return {"ecm_joints": None if self.ecm_joints is None else self.ecm_joints.tolist(),
                "q_start": self.q_start.tolist(), "q_goal": self.q_goal.tolist(),
                "x_start": self.x_start.tolist(), "x_goal": self.x_goal.tolist(),
                "tries": self.tries}


def load_evaluation(path: str | Path) -> EvaluationSpec:
    """Read an evaluation file strictly (errors name the file and the key).

    Raises:
        ProblemError: unknown or missing keys, wrong types, boxes outside the joint limits.
    """
    path = find_shipped(path)  # a shipped evaluation file is found from any folder
    tree = read_yaml(path)
    rd = Reader(str(path))
    top = rd.mapping(tree, "", _TOP, {"base", "start_joints", "goal_joints"})
    base_path, _ = resolve_path(rd, top["base"], "base", path)
    base = load_problem(base_path)
    horizon = rd.integer(top.get("horizon", base.horizon), "horizon", minimum=1,
                         maximum=MAX_HORIZON)
    base = replace(base, horizon=horizon)
    if "gradient" in top:  # replaces the base problem's gradient section (e.g. {preset: paper})
        base = replace(base, gradient=_gradient(rd, top["gradient"]))
    # replaces the base problem's limits section (a problem file's `limits:`, checked as there)
    if "limits" in top:
        base = replace(base, limits=_limits(rd, top["limits"], base.robot))
    detection = read_detection(rd, top.get("detection"))
    grasp = rd.mapping(top.get("grasp", {}), "grasp", {"position", "angle"})
    execution = rd.mapping(top.get("execution", {}), "execution", {"pace"})
    pace = rd.string(execution.get("pace", "planned"), "execution.pace", PACES)
    robot = load_robot(str(base_path), "robot", base.robot, moving=True)
    ecm_box = None
    if "ecm_joints" in top:
        if base.camera.ecm is None:
            raise rd.fail("ecm_joints",
                          f"the base problem {base_path.name} gives the camera as a fixed pose; "
                                        "random camera poses need a base problem with camera.ecm")
        ecm = load_robot(str(base_path), "camera.ecm", base.camera.ecm)
        ecm_box = _box(rd, top["ecm_joints"], "ecm_joints", ecm)
    acc = rd.mapping(top.get("accept", {}), "accept", {"depth", "image_margin", "min_distance"})
    depth = rd.vector(acc.get("depth", [base.min_depth, 0.25]), "accept.depth", 2)
    if not 0 < depth[0] < depth[1]:
        raise rd.fail("accept.depth",
                      f"expected [low, high] with 0 < low < high, got {depth.tolist()}")
    if depth[0] < base.min_depth:
        raise rd.fail("accept.depth",
                      f"low end {depth[0]:g} m is below the base problem's constraints.min_depth "
                                      f"= {base.min_depth:g} m")
    margin = rd.number(acc.get("image_margin", 0.05), "accept.image_margin", nonneg=True)
    if margin >= 0.5:
        raise rd.fail("accept.image_margin",
                      f"must be < 0.5 (a fraction of the image size), got {margin:g}")
    return EvaluationSpec(
        path=path, base_path=base_path, base=base, horizon=horizon, ecm_joints=ecm_box,
        start_joints=_box(rd, top["start_joints"], "start_joints", robot),
        goal_joints=_box(rd, top["goal_joints"], "goal_joints", robot),
        depth=(float(depth[0]), float(depth[1])), image_margin=margin,
        min_distance=rd.number(acc.get("min_distance", 0.0), "accept.min_distance", nonneg=True),
        max_tries=rd.integer(top.get("max_tries", 10000), "max_tries", minimum=1, maximum=100_000),
        description=rd.string(top.get("description", ""), "description"),
        detection=detection,
        grasp_position=rd.number(grasp.get("position", GRASP_POSITION_M), "grasp.position",
                                 positive=True),
        grasp_angle=rd.number(grasp.get("angle", GRASP_ANGLE_RAD), "grasp.angle", positive=True),
        pace=pace,
    )


def _box(rd: Reader, node: Any, key: str, robot: Robot) -> Box:
    m = rd.mapping(node, key, {"low", "high"}, {"low", "high"})
    lo = rd.vector(m["low"], f"{key}.low", robot.nq)
    hi = rd.vector(m["high"], f"{key}.high", robot.nq)
    for j, name in enumerate(robot.joint_names):
        if lo[j] > hi[j]:
            raise rd.fail(f"{key}.low[{j}]", f"joint '{name}': low {lo[j]:g} > high {hi[j]:g}")
        for side, v in (("low", lo[j]), ("high", hi[j])):
            if not robot.lower[j] - 1e-12 <= v <= robot.upper[j] + 1e-12:
                raise rd.fail(f"{key}.{side}[{j}]", f"joint '{name}' = {v:g} outside its limits "
                                                    f"[{robot.lower[j]:g}, {robot.upper[j]:g}]")
    return Box(lo, hi)


class ConfigurationSampler:
    """Draws accepted configurations of an evaluation spec (robots loaded once)."""

    def __init__(self, spec: EvaluationSpec, base_setup: Setup | None = None):
        self.spec = spec
        self.setup = base_setup or build_setup(spec.base)
        self.intrinsics = spec.base.camera.intrinsics

    def camera_pose(self, ecm_joints: np.ndarray | None) -> np.ndarray:
        if ecm_joints is None:
            return self.setup.camera_pose
        ecm = self.setup.ecm
        return ecm.base_pose @ ecm.frame_pose(ecm_joints)

    def pose(self, T_cam_base: np.ndarray, q: np.ndarray) -> np.ndarray:
        return matrix_to_pose(T_cam_base @ self.setup.robot.frame_pose(q))

    def visible(self, x: np.ndarray) -> bool:
        """In front of the camera, depth in range, inside the image with the margin."""
        lo, hi = self.spec.depth
        if not lo <= x[2] <= hi:
            return False
        intr, m = self.intrinsics, self.spec.image_margin
        u, v = intr.project(x[:3])
        return (m * intr.width <= u <= (1 - m) * intr.width
                and m * intr.height <= v <= (1 - m) * intr.height)

    def sample(self, seed: int, index: int) -> Configuration:
        """Configuration `index` of `seed` (rejection sampling from its own generator)."""
        spec = self.spec
        rng = np.random.default_rng([seed, index])
        for k in range(1, spec.max_tries + 1):
            qe = spec.ecm_joints.sample(rng) if spec.ecm_joints is not None else None
            qs, qg = spec.start_joints.sample(rng), spec.goal_joints.sample(rng)
            T_cb = np.linalg.inv(self.camera_pose(qe)) @ self.setup.robot.base_pose
            xs, xg = self.pose(T_cb, qs), self.pose(T_cb, qg)
            if (self.visible(xs) and self.visible(xg)
                    and np.linalg.norm(xs[:3] - xg[:3]) >= spec.min_distance):
                return Configuration(index, qe, qs, qg, xs, xg, k)
        raise SurestepError(f"{spec.path}: no configuration accepted in max_tries = "
                            f"{spec.max_tries} draws (seed {seed}, configuration {index}); widen "
                            "the joint boxes or the accept ranges")

    def problem(self, cfg: Configuration) -> Problem:
        """The base problem with this configuration's camera, start and goal."""
        base = self.spec.base
        camera = (base.camera if cfg.ecm_joints is None
                  else replace(base.camera, ecm_joints=cfg.ecm_joints))
        return replace(base, name=f"{base.name}#config{cfg.index}", camera=camera,
                       start=EndpointSpec(joints=cfg.q_start, key="start.joints"),
                       goal=EndpointSpec(joints=cfg.q_goal, key="goal.joints"))

    def setup_of(self, cfg: Configuration) -> Setup:
        return build_setup(self.problem(cfg))
