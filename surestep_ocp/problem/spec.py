"""What a problem is: `Problem`, the frozen dataclass a problem file is read into
(problems/README.md), and `parse_problem`, which reads one.

A Problem is made of the specs of its sections (`sections.py`: robot, camera, start and goal,
solver, gradient variant, timing, motion limits; noise is `model.belief.NoiseParams`), exported
from here too with `GRADIENT_PRESETS`. Its `with_*` methods make changed copies, read again with
the file's own checks (`parse.problem_fields`), which is why the Problem is built here and the
reading of its sections is there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..equality import ArrayEquality
from ..errors import ProblemError
from ..model.belief import NoiseParams
from ..model.detection import Detection
from .parse import problem_fields
from .sections import (
    GRADIENT_PRESETS,
    CameraMove,
    CameraSpec,
    EndpointSpec,
    GradientSpec,
    GraspSpec,
    LimitsSpec,
    ObjectiveSpec,
    PoseSpec,
    RelativeGoal,
    RobotSpec,
    SolverSpec,
    TimingSpec,
)

__all__ = ["Problem", "parse_problem", "plain_tree", "MAX_TREE_DEPTH", "GRADIENT_PRESETS",
           "CameraMove", "CameraSpec", "EndpointSpec", "GradientSpec", "GraspSpec", "LimitsSpec",
           "ObjectiveSpec", "PoseSpec", "RelativeGoal", "RobotSpec", "SolverSpec", "TimingSpec"]


@dataclass(frozen=True, eq=False)
class Problem(ArrayEquality):
    """A validated problem file (`load_problem`, `problem_from_dict`; changed copies by
    the `with_*` methods).

    Problems compare equal (`==`) when every field does, arrays by value; where it was read from
    (`source`, the YAML tree) is not compared."""

    name: str
    path: Path
    robot: RobotSpec
    camera: CameraSpec
    start: EndpointSpec
    goal: EndpointSpec
    horizon: int
    noise: NoiseParams
    min_depth: float = 0.03  # [m] lower bound on the tool's depth along the path
    objective: ObjectiveSpec = ObjectiveSpec()
    solver: SolverSpec = SolverSpec()
    gradient: GradientSpec = GradientSpec()
    description: str = ""
    timing: TimingSpec = TimingSpec()
    limits: LimitsSpec = LimitsSpec()
    grasp: GraspSpec = GraspSpec()
    detection: Detection | None = None  # where the tracker sees the tool (None: everywhere)
    source: Any = field(default=None, repr=False, compare=False)  # the YAML tree it was read from

    # Changed copies (the Python API). Each edits the tree the problem was read from and reads it
    # again with the file's own checks, so a bad value is a ProblemError naming the file and the key
    # (e.g. `goal.pose.position`).
    def with_start(self, *, pose=None, joints=None, position=None, axis_angle=None,
                   **unknown) -> Problem:
        """Start at a tool pose (camera frame: position [m], axis-angle [rad]) or at `joints` [rad;
        m for the insertion]. The pose in any of the file's forms: `pose=[px, py, pz, rx, ry, rz]`,
        `pose={"position": [...], "axis_angle": [...]}`, or `position=[...], axis_angle=[...]`."""
        return self.with_sections(start=self._endpoint_tree("start", pose, joints, position,
                                                            axis_angle, unknown))

    def with_goal(self, *, pose=None, joints=None, position=None, axis_angle=None,
                  **unknown) -> Problem:
        """Goal at a tool pose (camera frame: position [m], axis-angle [rad]) or at `joints`. The
        pose in any of the file's forms: `pose=[px, py, pz, rx, ry, rz]`,
        `pose={"position": [...], "axis_angle": [...]}`, or `position=[...], axis_angle=[...]`.

            problem.with_goal(pose=[0.035, -0.01, 0.11, 0.6, 0.1, 1.4])
            problem.with_goal(position=[0.035, -0.01, 0.11], axis_angle=[0.6, 0.1, 1.4])
        """
        return self.with_sections(goal=self._endpoint_tree("goal", pose, joints, position,
                                                           axis_angle, unknown))

    def with_camera_pose(self, matrix) -> Problem:
        """The camera fixed at `matrix` (camera in world, position [m]; OpenCV axes: z forward), in
        place of the ECM: a 4x4 matrix, or a pose in the file's forms (`[px, py, pz, rx, ry, rz]`,
        `{position, axis_angle}`, `{position, rpy}`, ...). A goal given in the camera frame stays
        there (it moves with the camera)."""
        camera = {k: v for k, v in self._tree().get("camera", {}).items()
                  if k not in ("pose", "ecm")}
        pose = plain_tree(matrix)
        if isinstance(pose, list) and any(isinstance(row, list) for row in pose):  # rows: a matrix
            pose = {"matrix": pose}
        return self.with_sections(camera={**camera, "pose": pose})

    def with_noise(self, **values) -> Problem:
        """Noise constants replaced, as the file's `noise:` keys take them: `Sigma0` (scalar or 6x6
        [m^2, rad^2]), `W_p0`, `W_o0`, `V_d0`, `V_f0`, `V_o0`, `V_min`, `depth_star` [m], `o_star`
        [rad], `components`, ..."""
        return self.with_sections(noise={**self._tree().get("noise", {}), **values})

    def with_horizon(self, steps: int) -> Problem:
        """`steps` steps (T; T + 1 waypoints, `timing.step_s` [s] each)."""
        return self.with_sections(horizon=steps)

    def with_solver(self, **values) -> Problem:
        """Solver settings replaced (`name`: auto | newton | ipopt, `hessian`, `tol`, `max_iter`,
        `codegen`, ...)."""
        return self.with_sections(solver={**self._tree().get("solver", {}), **values})

    def with_sections(self, **sections) -> Problem:
        """Top-level sections of the problem file replaced (`name=`, `timing=`, `limits=`, ...),
        read again."""
        return parse_problem({**self._tree(), **plain_tree(sections)}, self.path)

    def _tree(self) -> dict:
        if not isinstance(self.source, dict):
            raise ProblemError(str(self.path), None,
                               "this Problem was not read from a file or a dict (load_problem, "
                               "problem_from_dict), so it cannot be changed by with_*")
        return self.source

    def _endpoint_tree(self, key: str, pose, joints, position, axis_angle, unknown: dict) -> dict:
        """A `start:` / `goal:` section: a pose (a list of 6, a mapping, or `position` and
        `axis_angle`) or joint values (the reader checks the values and says what is wrong)."""
        if unknown:
            raise TypeError(f"with_{key}() got an unexpected keyword argument "
                            f"'{sorted(unknown)[0]}'; valid keywords: pose, joints, position, "
                            "axis_angle")
        pose, position, axis_angle = plain_tree(pose), plain_tree(position), plain_tree(axis_angle)
        if position is not None or axis_angle is not None:
            if pose is not None:
                raise TypeError(f"with_{key}(): give pose= or position= and axis_angle=, not both")
            if position is None or axis_angle is None:
                raise TypeError(f"with_{key}(): position= and axis_angle= go together (or "
                                "pose=[px, py, pz, rx, ry, rz])")
            pose = {"position": position, "axis_angle": axis_angle}
        given = [name for name, v in (("pose", pose), ("joints", joints)) if v is not None]
        if len(given) != 1:
            raise TypeError(f"with_{key}(): give exactly one of pose= (or position= and "
                            f"axis_angle=) and joints=, got {' and '.join(given) or 'none'}")
        if isinstance(pose, list) and len(pose) == 6:
            # (as the mapping: an error names goal.pose.position[2])
            pose = {"position": pose[:3], "axis_angle": pose[3:]}
        return {"joints": joints} if joints is not None else {"pose": pose}


def parse_problem(tree: Any, path: Path) -> Problem:
    """`tree` (a problem file's YAML) read into a Problem; every error of the file at once, one
    error a ProblemError, several a `ProblemErrors` (`parse.problem_fields`)."""
    return Problem(**problem_fields(tree, path))


# nesting levels of a value given in Python (as the YAML reader's MAX_YAML_DEPTH)
MAX_TREE_DEPTH = 40


def plain_tree(value: Any, depth: int = 0) -> Any:
    """NumPy arrays and scalars as the lists and numbers a YAML file gives; a value nested deeper
    than MAX_TREE_DEPTH (or one that contains itself) is a ProblemError, not a RecursionError."""
    if depth > MAX_TREE_DEPTH:
        raise ProblemError(None, None, f"a value nested deeper than {MAX_TREE_DEPTH} levels (or "
                                       "one that contains itself); give numbers, lists of numbers "
                                       "or mappings of them")
    if isinstance(value, dict):
        return {k: plain_tree(v, depth + 1) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_tree(v, depth + 1) for v in value]
    if isinstance(value, np.ndarray):
        return plain_tree(value.tolist(), depth)
    return value.item() if isinstance(value, np.generic) else value

