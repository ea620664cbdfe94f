"""Problem files: YAML -> frozen dataclasses, validated strictly.

See `problems/README.md` for the schema. Relative paths (URDFs) are resolved
against the repository root first (a source checkout), then against the data the
installed package ships (`robots/`, `problems/`), then against the problem file's folder.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..model.belief import COMPONENTS, OBJECTIVES, OBSERVATION_NOISE_FORMS, ORIENTATION_FORMULAS, NoiseParams
from ..model.camera import Intrinsics
from ..errors import ProblemError, shown
from ..model.lie import np_exp, rpy_matrix
from .schema import Reader

REPO_ROOT = Path(__file__).resolve().parents[2]
# robots/ and problems/ as installed with the package (pyproject.toml maps them to surestep_ocp/data/*);
# in a source checkout (editable install) they are at REPO_ROOT instead
PACKAGE_DATA = Path(__file__).resolve().parents[1] / "data"


def data_roots() -> tuple[Path, ...]:
    """Folders that `robots/...` and `problems/...` are resolved against: the checkout, then the package data."""
    roots = [REPO_ROOT] if (REPO_ROOT / "pyproject.toml").is_file() and (REPO_ROOT / "robots").is_dir() else []
    return tuple(roots + ([PACKAGE_DATA] if PACKAGE_DATA.is_dir() else []))


@dataclass(frozen=True)
class PoseSpec:
    """A pose given in a problem file, as a 4x4 matrix (frame stated by the field using it)."""

    matrix: np.ndarray


@dataclass(frozen=True)
class EndpointSpec:
    """Start or goal: joint values, or a tool pose `[p, r]` in the camera frame."""

    joints: np.ndarray | None = None
    pose: np.ndarray | None = None  # [px, py, pz, rx, ry, rz], camera frame
    relative: RelativeGoal | None = None
    key: str = ""


@dataclass(frozen=True)
class RobotSpec:
    urdf: Path  # absolute
    urdf_rel: str  # as written relative to the repository, for the solution file
    frame: str
    base_pose: np.ndarray  # 4x4, URDF root in world
    grasp: np.ndarray | None = None  # 4x4: tracked needle in `frame` (None: the frame itself is tracked)
    needle_radius: float | None = None  # [m]
    joints: np.ndarray | None = None  # fixed joint values (an arm that does not move)


@dataclass(frozen=True)
class RelativeGoal:
    """A goal given in the frame of another arm's tracked object (e.g. the regrasp pose on its needle)."""

    arm: RobotSpec
    pose: np.ndarray  # [px, py, pz, rx, ry, rz] in that object's frame


@dataclass(frozen=True)
class CameraMove:
    """The ECM moves to `ecm_joints` between waypoint `step - 1` and waypoint `step`."""

    step: int
    ecm_joints: np.ndarray


@dataclass(frozen=True)
class CameraSpec:
    intrinsics: Intrinsics
    pose: np.ndarray | None = None  # 4x4 camera in world (given directly)
    ecm: RobotSpec | None = None  # or: the ECM arm whose `frame` is the camera
    ecm_joints: np.ndarray | None = None
    moves: tuple[CameraMove, ...] = ()  # ECM moves during the motion (Types 3 and 4)


@dataclass(frozen=True)
class SolverSpec:
    name: str = "auto"  # auto (newton where it applies, else IPOPT) | ipopt | newton (see ocp.solve_ocp_warm)
    max_iter: int = 3000
    tol: float = 1e-6  # IPOPT tol (scaled NLP error); the constraints separately to min(tol, 1e-8)
    print_level: int = 0
    covariance: str = "auto"  # auto | full | diagonal | condensed (see ocp.py)
    hessian: str = "auto"  # auto | exact | surrogate | gauss-newton (see ocp.py)
    surrogate_max_iter: int = 300  # surrogate iterations before the exact-Hessian polish (hessian: auto)
    # compile the stage-wise derivatives of the surrogate / Gauss-Newton NLP to C (cached, see codegen.py):
    # True, False, or "auto" (when a C compiler is found)
    codegen: bool | str = "auto"
    options: dict = field(default_factory=dict)  # extra raw solver options


@dataclass(frozen=True)
class GradientSpec:
    """The gradient variant's optimiser (see surestep_ocp/solvers/gradient.py and problems/README.md)."""

    optimizer: str = "scipy"  # scipy (L-BFGS-B, `iterations`) | torch (torch.optim.LBFGS's algorithm, lbfgs.py)
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


# `gradient.preset`: values a preset sets (keys given beside it override them). `paper`: the reading that
# reproduces the paper's Table I (docs/evaluation.md, "Table I"); `literal`: the same optimiser with the loss as written.
GRADIENT_PRESETS = {
    "paper": {"optimizer": "torch", "steps": 50, "max_iter": 20, "line_search": "strong_wolfe", "trace_scale": 1e3},
    "literal": {"optimizer": "torch", "steps": 50, "max_iter": 20, "line_search": "strong_wolfe", "trace_scale": 1.0},
    "scipy": {"optimizer": "scipy", "iterations": 50, "trace_scale": 1.0},
}


@dataclass(frozen=True)
class TimingSpec:
    """How long a step lasts and how fast the tracker runs (problems/README.md, "Time in the model").

    A step spans `frames = step_s * tracker_hz` tracker frames, each an observation at the step's
    waypoint; the model folds them into one with the observation noise divided by `frames`. The
    defaults are the paper's: a 20 Hz tracker and one observation per waypoint.
    """

    step_s: float = 0.05  # [s] duration of one step (waypoint t to t+1)
    tracker_hz: float = 20.0  # [Hz] tracker frame rate

    @property
    def frames(self) -> int:
        """Tracker frames (observations) per step."""
        return int(round(self.step_s * self.tracker_hz))


@dataclass(frozen=True)
class LimitsSpec:
    """`limits:` motion limits of a plan (problems/README.md, "Motion limits"). With `enforce: false` (the
    default) they are only reported; with `true` the OCP honours them as constraints and a plan that breaks
    one is not a success. None: the default (`limits.py`: URDF velocities, the dVRK's accelerations, 0.1 m/s,
    pi/2 rad/s, 45 mm from the RCM)."""

    enforce: bool = False
    joint_velocity: tuple[tuple[str, float], ...] = ()  # per-joint overrides [rad/s or m/s]
    joint_acceleration: tuple[tuple[str, float], ...] = ()  # [rad/s^2 or m/s^2]
    tool_speed: float | None = None  # [m/s]
    tool_rotation_speed: float | None = None  # [rad/s]
    rcm_distance: float | None = None  # [m] (PSM only)


@dataclass(frozen=True)
class ObjectiveSpec:
    smoothness: float = 0.0  # weight on sum_t ||q_t+1 - q_t||^2 [1/rad^2], relative to Tr(Sigma_T) scale


@dataclass(frozen=True)
class Problem:
    """A validated problem file."""

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
    source: Any = field(default=None, repr=False, compare=False)  # the YAML tree it was read from

    # Changed copies (the Python API). Each edits the tree the problem was read from and reads it again with the
    # file's own checks, so a bad value is a ProblemError naming the file and the key (e.g. `goal.pose.position`).
    def with_start(self, *, pose=None, joints=None) -> Problem:
        """Start at a tool `pose` `[px, py, pz, rx, ry, rz]` (camera frame: position [m], axis-angle [rad]) or
        at `joints` [rad; m for the insertion]."""
        return self.with_sections(start=self._endpoint_tree("start", pose, joints))

    def with_goal(self, *, pose=None, joints=None) -> Problem:
        """Goal at a tool `pose` `[px, py, pz, rx, ry, rz]` (camera frame, [m] and [rad]) or at `joints`."""
        return self.with_sections(goal=self._endpoint_tree("goal", pose, joints))

    def with_camera_pose(self, matrix) -> Problem:
        """The camera fixed at `matrix` (4x4, camera in world, position [m]; OpenCV axes: z forward), in place
        of the ECM. A goal given in the camera frame stays there (it moves with the camera)."""
        camera = {k: v for k, v in self._tree().get("camera", {}).items() if k not in ("pose", "ecm")}
        return self.with_sections(camera={**camera, "pose": {"matrix": matrix}})

    def with_noise(self, **values) -> Problem:
        """Noise constants replaced, as the file's `noise:` keys take them: `Sigma0` (scalar or 6x6 [m^2, rad^2]),
        `W_p0`, `W_o0`, `V_d0`, `V_f0`, `V_o0`, `V_min`, `depth_star` [m], `o_star` [rad], `components`, ..."""
        return self.with_sections(noise={**self._tree().get("noise", {}), **values})

    def with_horizon(self, steps: int) -> Problem:
        """`steps` steps (T; T + 1 waypoints, `timing.step_s` [s] each)."""
        return self.with_sections(horizon=steps)

    def with_solver(self, **values) -> Problem:
        """Solver settings replaced (`name`: auto | newton | ipopt, `hessian`, `tol`, `max_iter`, `codegen`, ...)."""
        return self.with_sections(solver={**self._tree().get("solver", {}), **values})

    def with_sections(self, **sections) -> Problem:
        """Top-level sections of the problem file replaced (`name=`, `timing=`, `limits=`, ...), read again."""
        return parse_problem({**self._tree(), **_plain(sections)}, self.path)

    def _tree(self) -> dict:
        if not isinstance(self.source, dict):
            raise ProblemError(str(self.path), None, "this Problem was not read from a file or a dict (load_problem, "
                                                     "problem_from_dict), so it cannot be changed by with_*")
        return self.source

    def _endpoint_tree(self, key: str, pose, joints) -> dict:
        """A `start:` / `goal:` section of a pose [px, py, pz, rx, ry, rz] or joint values."""
        tree = {} if joints is None else {"joints": joints}
        pose = _plain(pose)
        if isinstance(pose, list):
            if len(pose) != 6:
                raise ProblemError(str(self.path), f"{key}.pose", "expected 6 numbers [px, py, pz, rx, ry, rz] "
                                   f"(position [m], axis-angle [rad]), got {len(pose)}")
            tree["pose"] = {"position": pose[:3], "axis_angle": pose[3:]}
        elif pose is not None:
            tree["pose"] = pose  # a mapping {position, axis_angle}, or what the reader says is wrong
        return tree


def _plain(value: Any) -> Any:
    """NumPy arrays and scalars as the lists and numbers a YAML file gives."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    return value.item() if isinstance(value, np.generic) else value


def problem_from_dict(tree: dict, path: str | Path = "<python>") -> Problem:
    """A problem built in Python: `tree` as a problem file's YAML would give it (problems/README.md), NumPy
    arrays allowed. Relative URDF paths resolve as for a file in the current folder; errors name `path`."""
    return parse_problem(_plain(tree), Path(path))


# Limits of what a problem (or evaluation) file may be and hold (problems/README.md, "Limits").
MAX_HORIZON = 200  # T (a solve's time and memory grow with T; problems/README.md "Limits")
MAX_FILE_BYTES = 1_000_000
MAX_YAML_DEPTH = 40  # nesting levels
MAX_YAML_NODES = 100_000  # values in the file, with every alias counted as the size of what it names
MAX_POSITION = 100.0  # [m] any position (poses, points)
MAX_ANGLE = 1000.0  # [rad] any angle, axis-angle or joint value
MAX_FOCAL = 1e6  # [px]
MAX_IMAGE = 100_000  # [px] image width and height


try:  # libyaml's scanner and parser (6x faster); the composer below stays in Python (it bounds the tree)
    from yaml._yaml import CParser as _Parser
except ImportError:  # pragma: no cover - PyYAML without libyaml
    from yaml.parser import Parser as _Parser
    from yaml.reader import Reader as _YamlReader
    from yaml.scanner import Scanner as _Scanner

    class _Parser(_YamlReader, _Scanner, _Parser):  # type: ignore[no-redef]
        def __init__(self, stream):
            _YamlReader.__init__(self, stream)
            _Scanner.__init__(self)
            _Parser.__init__(self)


class _StrictLoader(yaml.composer.Composer, _Parser, yaml.constructor.SafeConstructor, yaml.resolver.Resolver):
    """A YAML safe loader that rejects a key given twice in one mapping, bounds nesting and alias expansion,
    and reads no YAML 1.1 base-60 numbers (`1:20` is a string, not 80); `1e-3` is a number."""

    def __init__(self, stream):
        _Parser.__init__(self, stream)
        yaml.composer.Composer.__init__(self)
        yaml.constructor.SafeConstructor.__init__(self)
        yaml.resolver.Resolver.__init__(self)
        self._depth = 0
        self._nodes = 0
        self._sizes: dict[int, int] = {}

    def compose_node(self, parent, index):
        event = self.peek_event()
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels",
                                                  event.start_mark)
            if isinstance(event, yaml.AliasEvent) and event.anchor in self.anchors:
                self._nodes += _yaml_size(self.anchors[event.anchor], self._sizes)
            else:
                self._nodes += 1
            if self._nodes > MAX_YAML_NODES:
                raise yaml.composer.ComposerError(None, None, f"more than {MAX_YAML_NODES} values (aliases "
                                                  "counted expanded)", event.start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _yaml_size(node: yaml.Node, memo: dict[int, int]) -> int:
    """Number of values a node stands for once its aliases are expanded."""
    if id(node) not in memo:
        if isinstance(node, yaml.SequenceNode):
            memo[id(node)] = 1 + sum(_yaml_size(n, memo) for n in node.value)
        elif isinstance(node, yaml.MappingNode):
            memo[id(node)] = 1 + sum(_yaml_size(k, memo) + _yaml_size(v, memo) for k, v in node.value)
        else:
            memo[id(node)] = 1
    return memo[id(node)]


_INT = re.compile(r"""^(?:[-+]?0b[0-1_]+|[-+]?0[0-7_]+|[-+]?(?:0|[1-9][0-9_]*)|[-+]?0x[0-9a-fA-F_]+)$""", re.X)
_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?|[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
                    |[-+]?\.[0-9_]+(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$""", re.X)
_StrictLoader.yaml_implicit_resolvers = {
    first: [(tag, _INT if tag.endswith(":int") else _FLOAT if tag.endswith(":float") else rx) for tag, rx in rs]
    for first, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()}


def _no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            hash(key)
        except TypeError:
            raise yaml.constructor.ConstructorError(None, None, "a key must be a name, not a list or a mapping",
                                                    key_node.start_mark) from None
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key '{key}' given twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


_TOP = {"name", "description", "robot", "camera", "start", "goal", "horizon", "noise", "constraints",
        "objective", "solver", "gradient", "timing", "limits"}


def load_problem(path: str | Path) -> Problem:
    """Read and validate a problem file.

    Raises:
        ProblemError: naming the file, the key path and what is allowed.
    """
    path = find_shipped(path)
    return parse_problem(read_yaml(path), path)


def find_shipped(path: str | Path) -> Path:
    """`path` itself when it exists, else a shipped file of that relative name (`problems/needle_regrasp.yaml`
    from any folder once the package is installed), else `path` unchanged (the caller reports it missing)."""
    path = Path(path)
    if path.is_file() or path.is_absolute():
        return path
    for root in data_roots():
        if (root / path).is_file():
            return root / path
    return path


def read_yaml(path: Path) -> Any:
    """Parse a YAML file strictly (duplicate keys rejected); errors are one-line ProblemErrors."""
    try:
        if not path.is_file():
            raise ProblemError(str(path), None, "no such file" if not path.exists() else "not a regular file")
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ProblemError(str(path), None, f"file of {size} bytes; at most {MAX_FILE_BYTES} are read")
        data = path.read_bytes()
    except OSError as exc:
        raise ProblemError(str(path), None, f"cannot read the file ({exc.strerror or exc})") from None
    if b"\0" in data:
        raise ProblemError(str(path), None, f"a binary file (NUL byte at offset {data.index(0)}), not YAML text")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ProblemError(str(path), None, f"not UTF-8 text (invalid byte at offset {exc.start})") from None
    try:
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ProblemError(str(path), None, f"not valid YAML{where}: {shown(what, 200)}") from None
    except RecursionError:
        raise ProblemError(str(path), None, f"not valid YAML: nested too deeply (at most {MAX_YAML_DEPTH} "
                                            "levels)") from None


def parse_problem(tree: Any, path: Path) -> Problem:
    rd = Reader(str(path))
    top = rd.mapping(tree, "", _TOP, {"robot", "camera", "start", "goal", "horizon"})
    robot = _robot(rd, top["robot"], "robot", path, default_frame="tool")
    camera = _camera(rd, top["camera"], path)
    horizon = rd.integer(top["horizon"], "horizon", minimum=1, maximum=MAX_HORIZON)
    timing = _timing(rd, top.get("timing", {}))
    noise = _noise(rd, top.get("noise", {}), frames=timing.frames)
    cons = rd.mapping(top.get("constraints", {}), "constraints", {"min_depth"})
    obj = rd.mapping(top.get("objective", {}), "objective", {"smoothness", "covariance"})
    # which covariance the planners minimise: Sigma_T|T (the paper's) or Sigma_T|T-1, the one that
    # governs the executed error under closed-loop control (section 8)
    noise = replace(noise, objective=rd.string(obj.get("covariance", "posterior"), "objective.covariance",
                                               OBJECTIVES))
    return Problem(
        name=rd.string(top.get("name", path.stem), "name"),
        description=rd.string(top.get("description", ""), "description"),
        path=path,
        robot=robot,
        camera=camera,
        start=_endpoint(rd, top["start"], "start", path),
        goal=_endpoint(rd, top["goal"], "goal", path),
        horizon=horizon,
        noise=noise,
        min_depth=rd.number(cons.get("min_depth", 0.03), "constraints.min_depth", positive=True, low=1e-4,
                            high=10.0),
        objective=ObjectiveSpec(smoothness=rd.number(obj.get("smoothness", 0.0), "objective.smoothness", nonneg=True,
                                                     high=1e6)),
        solver=_solver(rd, top.get("solver", {})),
        gradient=_gradient(rd, top.get("gradient", {})),
        timing=timing,
        limits=_limits(rd, top.get("limits", {}), robot),
        source=tree,
    )


MAX_FRAMES_PER_STEP = 10_000


def _timing(rd: Reader, node: Any) -> TimingSpec:
    """`timing: {step_s, tracker_hz}`; a step must span a whole number (>= 1) of tracker frames."""
    m = rd.mapping(node, "timing", {"step_s", "tracker_hz"})
    d = TimingSpec()
    step = rd.number(m.get("step_s", d.step_s), "timing.step_s", positive=True, high=3600.0)
    hz = rd.number(m.get("tracker_hz", d.tracker_hz), "timing.tracker_hz", positive=True, high=10_000.0)
    k = step * hz
    if abs(k - round(k)) > 1e-9 * max(1.0, k) or round(k) < 1 or round(k) > MAX_FRAMES_PER_STEP:
        raise rd.fail("timing", f"step_s * tracker_hz = {step:g} s * {hz:g} Hz = {k:g} tracker frames per step; "
                                f"it must be a whole number from 1 to {MAX_FRAMES_PER_STEP} (e.g. step_s 0.1 with "
                                "tracker_hz 20: 2 frames)")
    return TimingSpec(step_s=step, tracker_hz=hz)


def _limits(rd: Reader, node: Any, robot: RobotSpec) -> LimitsSpec:
    """`limits: {enforce, joint_velocity: {JOINT: v}, joint_acceleration: {JOINT: a}, tool_speed,
    tool_rotation_speed, rcm_distance}`; joint names are checked against the URDF's moving joints."""
    from ..model.limits import urdf_velocity_limits

    m = rd.mapping(node, "limits", {"enforce", "joint_velocity", "joint_acceleration", "tool_speed",
                                    "tool_rotation_speed", "rcm_distance"})
    joints = None
    per_joint = {}
    for key in ("joint_velocity", "joint_acceleration"):
        sub = rd.mapping(m.get(key, {}), f"limits.{key}", set(m.get(key) or {}) if isinstance(m.get(key), dict)
                         else set())
        if sub and joints is None:
            joints = set(urdf_velocity_limits(robot.urdf))
        for name, value in sub.items():
            if str(name) not in joints:
                raise rd.fail(f"limits.{key}.{name}", f"no moving joint '{shown(str(name))}' in {robot.urdf_rel}; "
                                                      f"allowed: {', '.join(sorted(joints))}")
            sub[name] = rd.number(value, f"limits.{key}.{name}", positive=True, high=1e6)
        per_joint[key] = tuple(sorted((str(k), float(v)) for k, v in sub.items()))
    opt = {k: (None if k not in m else rd.number(m[k], f"limits.{k}", positive=True, high=hi))
           for k, hi in (("tool_speed", 100.0), ("tool_rotation_speed", 1000.0), ("rcm_distance", 10.0))}
    return LimitsSpec(enforce=rd.boolean(m.get("enforce", False), "limits.enforce"), **per_joint, **opt)


ERD_PREFIX = "example-robot-data:"


def example_robot_data_dir() -> Path:
    """Folder of the URDFs shipped by the `example-robot-data` wheel (a cmeel prefix in site-packages)."""
    import sysconfig

    return Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"


def resolve_urdf(text: str) -> Path:
    """Absolute path of a URDF named in a solution file (repository-relative or example-robot-data:)."""
    if text.startswith(ERD_PREFIX):
        return example_robot_data_dir() / text[len(ERD_PREFIX):]
    p = Path(text)
    if p.is_absolute():
        return p
    for root in data_roots():
        if (root / p).is_file():
            return root / p
    return REPO_ROOT / p


def resolve_path(rd: Reader, text: Any, key: str, problem_path: Path) -> tuple[Path, str]:
    """Absolute path of a file named in a problem, and its path relative to the repository."""
    text = rd.string(text, key)
    if text.startswith(ERD_PREFIX):
        path = example_robot_data_dir() / text[len(ERD_PREFIX):]
        if not path.is_file():
            raise rd.fail(key, f"'{text}' not found in the example-robot-data package ({example_robot_data_dir()})")
        return path, text
    bases = (*data_roots(), problem_path.resolve().parent)
    for base in bases:
        candidate = (base / text).resolve()
        if candidate.is_file():
            return candidate, _relative_name(candidate)
    raise rd.fail(key, f"file '{text}' not found (looked in {', '.join(str(b) for b in bases)})")


def _relative_name(path: Path) -> str:
    """`path` relative to the checkout or the package data (as a solution file records it), else absolute."""
    for root in data_roots():
        try:
            return str(path.relative_to(root.resolve()))
        except ValueError:
            pass
    return str(path)


def _robot(rd: Reader, node: Any, key: str, path: Path, default_frame: str, joints: bool = False) -> RobotSpec:
    allowed = {"urdf", "frame", "base_pose", "needle"} | ({"joints"} if joints else set())
    m = rd.mapping(node, key, allowed, {"urdf"} | ({"joints"} if joints else set()))
    urdf, rel = resolve_path(rd, m["urdf"], f"{key}.urdf", path)
    base = _pose(rd, m["base_pose"], f"{key}.base_pose") if "base_pose" in m else np.eye(4)
    grasp = radius = None
    if "needle" in m:
        n = rd.mapping(m["needle"], f"{key}.needle", {"radius", "grasp"}, {"radius", "grasp"})
        radius = rd.number(n["radius"], f"{key}.needle.radius", positive=True, low=1e-4, high=1.0)
        grasp = _pose(rd, n["grasp"], f"{key}.needle.grasp")
    return RobotSpec(urdf=urdf, urdf_rel=rel, frame=rd.string(m.get("frame", default_frame), f"{key}.frame"),
                     base_pose=base, grasp=grasp, needle_radius=radius,
                     joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE) if joints else None)


def _pose(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A pose: `position` plus one of `rpy`, `axis_angle`, `minus_z_toward` (a point), or a 4x4 `matrix`."""
    m = rd.mapping(node, key, {"position", "rpy", "axis_angle", "minus_z_toward", "matrix"})
    if "matrix" in m:
        if len(m) != 1:
            raise rd.fail(key, "a 'matrix' pose takes no other keys")
        T = rd.matrix(m["matrix"], f"{key}.matrix", 4, limit=MAX_POSITION)
        R = T[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0 or not np.allclose(T[3], [0, 0, 0, 1]):
            raise rd.fail(f"{key}.matrix", "not a rigid transform (rotation must be orthonormal, last row 0 0 0 1)")
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
    i = rd.mapping(m["intrinsics"], "camera.intrinsics", {"fx", "fy", "cx", "cy", "width", "height"},
                   {"fx", "fy", "cx", "cy", "width", "height"})
    k = "camera.intrinsics"
    intr = Intrinsics(
        fx=rd.number(i["fx"], f"{k}.fx", low=1.0, high=MAX_FOCAL), fy=rd.number(i["fy"], f"{k}.fy", low=1.0, high=MAX_FOCAL),
        cx=rd.number(i["cx"], f"{k}.cx", limit=MAX_FOCAL), cy=rd.number(i["cy"], f"{k}.cy", limit=MAX_FOCAL),
        width=rd.integer(i["width"], f"{k}.width", minimum=1, maximum=MAX_IMAGE),
        height=rd.integer(i["height"], f"{k}.height", minimum=1, maximum=MAX_IMAGE),
    )
    kind = rd.one_of(m, "camera", ["pose", "ecm"])
    if kind == "pose":
        if "moves" in m:
            raise rd.fail("camera.moves", "camera moves need the camera given as camera.ecm (joint values)")
        return CameraSpec(intrinsics=intr, pose=_pose(rd, m["pose"], "camera.pose"))
    ecm = _robot(rd, m["ecm"], "camera.ecm", path, default_frame="camera", joints=True)
    return CameraSpec(intrinsics=intr, ecm=ecm, ecm_joints=ecm.joints, moves=_moves(rd, m.get("moves", [])))


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
        out.append(CameraMove(step, rd.vector(mv["ecm_joints"], f"{k}.ecm_joints", limit=MAX_ANGLE)))
    return tuple(out)


def _endpoint(rd: Reader, node: Any, key: str, path: Path) -> EndpointSpec:
    m = rd.mapping(node, key, {"joints", "pose", "relative"})
    kind = rd.one_of(m, key, ["joints", "pose", "relative"])
    if kind == "joints":
        return EndpointSpec(joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE), key=f"{key}.joints")
    if kind == "relative":
        r = rd.mapping(m["relative"], f"{key}.relative", {"arm", "pose"}, {"arm", "pose"})
        arm = _robot(rd, r["arm"], f"{key}.relative.arm", path, default_frame="tool", joints=True)
        return EndpointSpec(relative=RelativeGoal(arm, _pose6(rd, r["pose"], f"{key}.relative.pose")),
                            key=f"{key}.relative")
    return EndpointSpec(pose=_pose6(rd, m["pose"], f"{key}.pose"), key=f"{key}.pose")


def _pose6(rd: Reader, node: Any, key: str) -> np.ndarray:
    p = rd.mapping(node, key, {"position", "axis_angle"}, {"position", "axis_angle"})
    return np.concatenate([rd.vector(p["position"], f"{key}.position", 3, limit=MAX_POSITION),
                           rd.vector(p["axis_angle"], f"{key}.axis_angle", 3, limit=MAX_ANGLE)])


_NOISE_KEYS = {"observation_scale", "camera_W_p0", "camera_W_o0", "W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "Sigma0", "depth_star", "o_star", "components",
               "orientation_formula", "observation_noise", "V_min", "cosine_guard", "cut_band", "joint_motion_sigma"}


def _noise(rd: Reader, node: Any, frames: int = 1) -> NoiseParams:
    m = rd.mapping(node, "noise", _NOISE_KEYS)
    d = NoiseParams()
    kw: dict[str, Any] = {}
    for name in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "camera_W_p0", "camera_W_o0"):
        kw[name] = rd.covariance(m[name], f"noise.{name}") if name in m else getattr(d, name)
    light = rd.number(m.get("observation_scale", 1.0), "noise.observation_scale", positive=True, low=1e-6, high=1e6)
    # `frames` tracker observations per step (timing), each with covariance V, are one with V / frames
    # (problems/README.md, "Time in the model"): applied with the light scale, to every observation term
    light = light / frames
    # the observation noise floor (no detector is perfect): PSD, scalar or 6x6, scaled like the terms
    kw["V_min"] = rd.covariance(m["V_min"], "noise.V_min") if "V_min" in m else d.V_min
    for name in ("V_d0", "V_f0", "V_o0", "V_min"):  # dim light: every observation term scaled alike
        kw[name] = light * kw[name]
    kw["Sigma0"] = rd.covariance(m["Sigma0"], "noise.Sigma0", definite=True) if "Sigma0" in m else d.Sigma0
    kw["depth_star"] = rd.number(m.get("depth_star", d.depth_star), "noise.depth_star", positive=True, low=1e-4,
                                 high=10.0)
    o = rd.vector(m.get("o_star", list(d.o_star)), "noise.o_star", 3, limit=MAX_ANGLE)
    if np.linalg.norm(o) < 1e-6:
        raise rd.fail("noise.o_star", "must be a non-zero axis-angle vector (its direction is used)")
    kw["o_star"] = tuple(float(v) for v in o)
    comps = m.get("components", list(COMPONENTS))
    if not isinstance(comps, list):
        raise rd.fail("noise.components", f"expected a list drawn from {', '.join(COMPONENTS)}")
    kw["components"] = tuple(rd.string(c, f"noise.components[{i}]", COMPONENTS) for i, c in enumerate(comps))
    if not kw["components"]:
        raise rd.fail("noise.components", f"empty; give at least one of {', '.join(COMPONENTS)}")
    if len(set(kw["components"])) != len(kw["components"]):
        raise rd.fail("noise.components", "a component is listed twice")
    kw["orientation_formula"] = rd.string(m.get("orientation_formula", d.orientation_formula),
                                          "noise.orientation_formula", ORIENTATION_FORMULAS)
    kw["observation_noise"] = rd.string(m.get("observation_noise", d.observation_noise), "noise.observation_noise",
                                        OBSERVATION_NOISE_FORMS)
    kw["cosine_guard"] = rd.number(m.get("cosine_guard", d.cosine_guard), "noise.cosine_guard", low=0.0, high=1.0)
    kw["cut_band"] = rd.number(m.get("cut_band", d.cut_band), "noise.cut_band", low=0.0, high=1.0)
    if "joint_motion_sigma" in m:  # one number for every joint, or one per joint (its length is checked on setup)
        node, key = m["joint_motion_sigma"], "noise.joint_motion_sigma"
        nodes = node if isinstance(node, list) else [node]
        if not nodes:
            raise rd.fail(key, "empty; give one number for every joint or one per joint")
        kw["joint_sigma"] = tuple(rd.number(v, key if not isinstance(node, list) else f"{key}[{i}]", low=0.0,
                                            high=1.0) for i, v in enumerate(nodes))
    return NoiseParams(**kw)


def _codegen(rd: Reader, node: Any) -> bool | str:
    if node == "auto" or isinstance(node, bool):
        return node
    raise rd.fail("solver.codegen", f"expected true, false or auto, got {shown(node)}")


def _solver(rd: Reader, node: Any) -> SolverSpec:
    m = rd.mapping(node, "solver", {"name", "max_iter", "tol", "print_level", "covariance", "hessian",
                                    "surrogate_max_iter", "codegen", "options"})
    d = SolverSpec()
    opts = m.get("options", {})
    if not isinstance(opts, dict):
        raise rd.fail("solver.options", "expected a mapping of raw solver options")
    return SolverSpec(
        name=rd.string(m.get("name", d.name), "solver.name", ("auto", "ipopt", "newton")),
        max_iter=rd.integer(m.get("max_iter", d.max_iter), "solver.max_iter", minimum=1, maximum=1_000_000),
        tol=rd.number(m.get("tol", d.tol), "solver.tol", positive=True, low=1e-14, high=1.0),
        print_level=rd.integer(m.get("print_level", d.print_level), "solver.print_level", minimum=0, maximum=12),
        covariance=rd.string(m.get("covariance", d.covariance), "solver.covariance",
                             ("auto", "full", "diagonal", "condensed")),
        hessian=rd.string(m.get("hessian", d.hessian), "solver.hessian", ("auto", "exact", "surrogate", "gauss-newton")),
        surrogate_max_iter=rd.integer(m.get("surrogate_max_iter", d.surrogate_max_iter),
                                         "solver.surrogate_max_iter", minimum=1, maximum=1_000_000),
        codegen=_codegen(rd, m.get("codegen", d.codegen)),
        options=_ipopt_options(rd, opts),
    )


def _gradient(rd: Reader, node: Any, key: str = "gradient") -> GradientSpec:
    m = rd.mapping(node, key, set(GradientSpec.__dataclass_fields__))
    preset = rd.string(m["preset"], f"{key}.preset", tuple(GRADIENT_PRESETS)) if "preset" in m else ""
    d = replace(GradientSpec(), **GRADIENT_PRESETS.get(preset, {}))
    g = lambda k: m.get(k, getattr(d, k))  # noqa: E731
    max_eval = g("max_eval")
    return GradientSpec(
        optimizer=rd.string(g("optimizer"), f"{key}.optimizer", ("scipy", "torch")),
        iterations=rd.integer(g("iterations"), f"{key}.iterations", minimum=1),
        memory=rd.integer(g("memory"), f"{key}.memory", minimum=1),
        pose_loss_weight=rd.number(g("pose_loss_weight"), f"{key}.pose_loss_weight", nonneg=True),
        trace_scale=rd.number(g("trace_scale"), f"{key}.trace_scale", positive=True),
        steps=rd.integer(g("steps"), f"{key}.steps", minimum=1),
        max_iter=rd.integer(g("max_iter"), f"{key}.max_iter", minimum=1),
        max_eval=None if max_eval is None else rd.integer(max_eval, f"{key}.max_eval", minimum=1),
        line_search=rd.string(g("line_search"), f"{key}.line_search", ("strong_wolfe", "none")),
        lr=rd.number(g("lr"), f"{key}.lr", positive=True),
        tolerance_grad=rd.number(g("tolerance_grad"), f"{key}.tolerance_grad", nonneg=True),
        tolerance_change=rd.number(g("tolerance_change"), f"{key}.tolerance_change", nonneg=True),
        history_size=rd.integer(g("history_size"), f"{key}.history_size", minimum=1),
        preset=preset,
    )


def _ipopt_options(rd: Reader, opts: dict) -> dict:
    """Raw IPOPT options: names IPOPT knows, values of the type it expects (checked by IPOPT itself)."""
    out = {}
    for name, value in opts.items():
        key = f"solver.options.{shown(name)}"
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise rd.fail(key, "an IPOPT option name (letters, digits, _) is expected")
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            raise rd.fail(key, f"expected a number or a string, got {shown(value)}")
        if isinstance(value, int):
            out[name] = rd.integer(value, key, minimum=-2**31, maximum=2**31 - 1)
        elif isinstance(value, float):
            out[name] = rd.number(value, key, limit=1e20)
        else:
            out[name] = value
    problem = check_ipopt_options(out)
    if problem:
        raise rd.fail("solver.options", problem)
    return out


def check_ipopt_options(options: dict) -> str | None:
    """None if IPOPT accepts `options` (names and value types), else a one-line reason."""
    if not options:
        return None
    import casadi as ca

    import os
    import sys
    import tempfile

    x = ca.MX.sym("x")
    import io

    sys.stdout.flush()
    saved, python_out, caught = os.dup(1), sys.stdout, io.StringIO()
    # IPOPT says why a setting is invalid on stdout: CasADi's (Python's sys.stdout) or the C one
    with tempfile.TemporaryFile() as printed:
        os.dup2(printed.fileno(), 1)
        sys.stdout = caught
        try:
            ca.nlpsol("check_options", "ipopt", {"x": x, "f": x**2},
                      {"ipopt": dict(options, print_level=0, sb="yes"), "print_time": False})
            return None
        except RuntimeError as exc:
            error = str(exc)
        finally:
            sys.stdout = python_out
            os.dup2(saved, 1)
            os.close(saved)
        printed.seek(0)
        said = caught.getvalue()[:4000] + "\n" + printed.read(4000).decode("utf-8", "replace")
    reason = next((ln for ln in said.splitlines() if "valid setting" in ln or "Option" in ln), "") or error
    reason = re.sub(r"^.*?\.cpp:\d+:\s*", "", reason.strip().splitlines()[-1] if reason.strip() else error)
    return f"IPOPT refused them: {shown(reason.strip(), 200)}"
