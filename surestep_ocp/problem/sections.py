"""The sections of a problem file as frozen dataclasses (problems/README.md): the robot, the camera
and its moves, the start and goal, the solver, the gradient variant (and its `GRADIENT_PRESETS`),
the timing, the grasp tolerance, the motion limits and the objective.

They are what the section readers (`parse_scene.py`, `parse_settings.py`) return and what a
`spec.Problem` is made of; `spec.py` exports them too (their home before).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..equality import ArrayEquality
from ..model.camera import Intrinsics


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

