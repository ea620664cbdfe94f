"""What a problem is: the frozen dataclasses a problem file is read into (problems/README.md).

`Problem` and the specs of its sections (robot, camera, start and goal, noise is
`model.belief.NoiseParams`, solver, gradient variant, timing, motion limits), `GRADIENT_PRESETS`,
and `Problem`'s `with_*` methods (changed copies, read again with the file's own checks by
`parse.parse_problem`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..equality import ArrayEquality
from ..errors import ProblemError
from ..model.belief import NoiseParams
from ..model.camera import Intrinsics
from ..model.detection import Detection


@dataclass(frozen=True, eq=False)
class PoseSpec(ArrayEquality):
    """A pose given in a problem file, as a 4x4 matrix (frame stated by the field using it)."""

    matrix: np.ndarray


@dataclass(frozen=True, eq=False)
class EndpointSpec(ArrayEquality):
    """Start or goal: joint values, or a tool pose `[p, r]` in the camera frame."""

    joints: np.ndarray | None = None
    pose: np.ndarray | None = None  # [px, py, pz, rx, ry, rz], camera frame
    relative: RelativeGoal | None = None
    key: str = ""


@dataclass(frozen=True, eq=False)
class RobotSpec(ArrayEquality):
    urdf: Path  # absolute
    urdf_rel: str  # as written relative to the repository, for the solution file
    frame: str
    base_pose: np.ndarray  # 4x4, URDF root in world
    # 4x4: tracked needle in `frame` (None: the frame itself is tracked)
    grasp: np.ndarray | None = None
    needle_radius: float | None = None  # [m]
    joints: np.ndarray | None = None  # fixed joint values (an arm that does not move)


@dataclass(frozen=True, eq=False)
class RelativeGoal(ArrayEquality):
    """A goal given in the frame of another arm's tracked object (e.g. the regrasp pose on its
    needle)."""

    arm: RobotSpec
    pose: np.ndarray  # [px, py, pz, rx, ry, rz] in that object's frame


@dataclass(frozen=True, eq=False)
class CameraMove(ArrayEquality):
    """The ECM moves to `ecm_joints` between waypoint `step - 1` and waypoint `step`."""

    step: int
    ecm_joints: np.ndarray


@dataclass(frozen=True, eq=False)
class CameraSpec(ArrayEquality):
    intrinsics: Intrinsics
    pose: np.ndarray | None = None  # 4x4 camera in world (given directly)
    ecm: RobotSpec | None = None  # or: the ECM arm whose `frame` is the camera
    ecm_joints: np.ndarray | None = None
    moves: tuple[CameraMove, ...] = ()  # ECM moves during the motion (Types 3 and 4)


@dataclass(frozen=True)
class SolverSpec:
    # auto (newton where it applies, else IPOPT) | ipopt | newton (see ocp.solve_ocp_warm)
    name: str = "auto"
    max_iter: int = 3000
    tol: float = 1e-6  # IPOPT tol (scaled NLP error); the constraints separately to min(tol, 1e-8)
    print_level: int = 0
    covariance: str = "auto"  # auto | full | diagonal | condensed (see ocp.py)
    hessian: str = "auto"  # auto | exact | surrogate | gauss-newton (see ocp.py)
    # surrogate iterations before the exact-Hessian polish (hessian: auto)
    surrogate_max_iter: int = 300
    # compile the stage-wise derivatives of the surrogate / Gauss-Newton NLP to C (cached, see
    # codegen.py): True, False, or "auto" (when a C compiler is found)
    codegen: bool | str = "auto"
    options: dict = field(default_factory=dict)  # extra raw solver options


@dataclass(frozen=True)
class GradientSpec:
    """The gradient variant's optimiser (see surestep_ocp/methods/gradient.py and
    problems/README.md)."""

    # scipy (L-BFGS-B, `iterations`) | torch (torch.optim.LBFGS's algorithm, lbfgs.py)
    optimizer: str = "scipy"
    iterations: int = 50  # scipy: L-BFGS-B iterations
    memory: int = 10  # scipy: L-BFGS-B memory
    pose_loss_weight: float = 1.0
    trace_scale: float = 1.0  # loss = trace_scale * Tr(Sigma_T) + pose_loss_weight * pose loss
    steps: int = 50  # torch: outer step() calls
    max_iter: int = 20  # torch: inner iterations per step()
    max_eval: int | None = None  # torch: evaluations per step() (None: max_iter * 5 // 4)
    line_search: str = "strong_wolfe"  # torch: strong_wolfe | none (torch's own default is none)
    lr: float = 1.0
    tolerance_grad: float = 1e-7
    tolerance_change: float = 1e-9
    history_size: int = 100
    preset: str = ""


# `gradient.preset`: values a preset sets (keys given beside it override them). `paper`: the reading
# that reproduces the paper's Table I (docs/evaluation.md, "Table I"); `literal`: the same optimiser
# with the loss as written.
GRADIENT_PRESETS = {
    "paper": {"optimizer": "torch", "steps": 50, "max_iter": 20, "line_search": "strong_wolfe",
              "trace_scale": 1e3},
    "literal": {"optimizer": "torch", "steps": 50, "max_iter": 20, "line_search": "strong_wolfe",
                "trace_scale": 1.0},
    "scipy": {"optimizer": "scipy", "iterations": 50, "trace_scale": 1.0},
}


@dataclass(frozen=True)
class TimingSpec:
    """How long a step lasts and how fast the tracker runs (problems/README.md, "Time in the
    model").

    A step spans `frames = step_s * tracker_hz` tracker frames, each an observation at the step's
    waypoint; the model folds them into one with the observation noise divided by `frames`. The
    defaults are the paper's: a 20 Hz tracker and one observation per waypoint.
    """

    step_s: float = 0.05  # [s] duration of one step (waypoint t to t+1)
    tracker_hz: float = 20.0  # [Hz] tracker frame rate
    # [s] the longest a motion may take, a dwell at the goal included (planning to a confidence,
    # grasping when sure); None: twice the problem's duration (`max_steps`)
    max_duration: float | None = None

    def max_steps(self, horizon: int) -> int:
        """The most steps a motion of nominal `horizon` steps may take (`max_duration`)."""
        if self.max_duration is None:
            return 2 * int(horizon)
        return max(int(horizon), int(np.floor(self.max_duration / self.step_s + 1e-9)))

    @property
    def frames(self) -> int:
        """Tracker frames (observations) per step."""
        # int(): step_s may be a NumPy float, whose round() is not an int
        return int(round(self.step_s * self.tracker_hz))  # noqa: RUF046


@dataclass(frozen=True)
class GraspSpec:
    """`goal.tolerance` and `goal.confidence` (problems/README.md, "Grasp confidence"): the grasp
    succeeds when the tool is within `position` [m] and `angle` [rad] of the goal; with
    `confidence` set, plans are made to reach that probability (`model.grasp`) and the closed
    loop grasps once its belief does."""

    position: float = 0.005  # [m]
    angle: float = 0.2  # [rad]
    confidence: float | None = None  # in (0, 1); None: plan for the horizon as given


@dataclass(frozen=True)
class LimitsSpec:
    """`limits:` motion limits of a plan (problems/README.md, "Motion limits"). With `enforce:
    false` (the default) they are only reported; with `true` the OCP honours them as constraints and
    a plan that breaks one is not a success. None: the default (`model/limits/values.py`: URDF
    velocities, the dVRK's accelerations, 0.1 m/s, pi/2 rad/s, 45 mm from the RCM)."""

    enforce: bool = False
    joint_velocity: tuple[tuple[str, float], ...] = ()  # per-joint overrides [rad/s or m/s]
    joint_acceleration: tuple[tuple[str, float], ...] = ()  # [rad/s^2 or m/s^2]
    tool_speed: float | None = None  # [m/s]
    tool_rotation_speed: float | None = None  # [rad/s]
    rcm_distance: float | None = None  # [m] (PSM only)


@dataclass(frozen=True)
class ObjectiveSpec:
    # weight on sum_t ||q_t+1 - q_t||^2 [1/rad^2], relative to Tr(Sigma_T) scale
    smoothness: float = 0.0


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
        # imported here: parse builds Problems (a module-level import would be a cycle)
        from .parse import parse_problem

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

