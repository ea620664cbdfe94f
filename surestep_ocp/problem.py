"""Problem files: YAML -> frozen dataclasses, validated strictly.

See `problems/README.md` for the schema. Relative paths (URDFs) are resolved
against the repository root first, then against the problem file's folder.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .belief import COMPONENTS, OBJECTIVES, OBSERVATION_NOISE_FORMS, ORIENTATION_FORMULAS, NoiseParams
from .camera import Intrinsics
from .errors import ProblemError
from .lie import np_exp, rpy_matrix
from .schema import Reader

REPO_ROOT = Path(__file__).resolve().parents[1]


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
    iterations: int = 50
    memory: int = 10
    pose_loss_weight: float = 1.0


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


class _StrictLoader(yaml.SafeLoader):
    """YAML SafeLoader that rejects a key given twice in one mapping."""


def _no_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key '{key}' given twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep)


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


_TOP = {"name", "description", "robot", "camera", "start", "goal", "horizon", "noise", "constraints",
        "objective", "solver", "gradient"}


def load_problem(path: str | Path) -> Problem:
    """Read and validate a problem file.

    Raises:
        ProblemError: naming the file, the key path and what is allowed.
    """
    path = Path(path)
    return parse_problem(read_yaml(path), path)


def read_yaml(path: Path) -> Any:
    """Parse a YAML file strictly (duplicate keys rejected); errors are one-line ProblemErrors."""
    if not path.is_file():
        raise ProblemError(str(path), None, "no such file")
    try:
        return yaml.load(path.read_text(), Loader=_StrictLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ProblemError(str(path), None, f"not valid YAML{where}: {what}") from None


def parse_problem(tree: Any, path: Path) -> Problem:
    rd = Reader(str(path))
    top = rd.mapping(tree, "", _TOP, {"robot", "camera", "start", "goal", "horizon"})
    robot = _robot(rd, top["robot"], "robot", path, default_frame="tool")
    camera = _camera(rd, top["camera"], path)
    horizon = rd.integer(top["horizon"], "horizon", minimum=1)
    noise = _noise(rd, top.get("noise", {}))
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
        min_depth=rd.number(cons.get("min_depth", 0.03), "constraints.min_depth", positive=True),
        objective=ObjectiveSpec(smoothness=rd.number(obj.get("smoothness", 0.0), "objective.smoothness", nonneg=True)),
        solver=_solver(rd, top.get("solver", {})),
        gradient=_gradient(rd, top.get("gradient", {})),
    )


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
    return p if p.is_absolute() else REPO_ROOT / p


def resolve_path(rd: Reader, text: Any, key: str, problem_path: Path) -> tuple[Path, str]:
    """Absolute path of a file named in a problem, and its path relative to the repository."""
    text = rd.string(text, key)
    if text.startswith(ERD_PREFIX):
        path = example_robot_data_dir() / text[len(ERD_PREFIX):]
        if not path.is_file():
            raise rd.fail(key, f"'{text}' not found in the example-robot-data package ({example_robot_data_dir()})")
        return path, text
    for base in (REPO_ROOT, problem_path.resolve().parent):
        candidate = (base / text).resolve()
        if candidate.is_file():
            try:
                rel = str(candidate.relative_to(REPO_ROOT))
            except ValueError:
                rel = str(candidate)
            return candidate, rel
    raise rd.fail(key, f"file '{text}' not found (looked in {REPO_ROOT} and {problem_path.resolve().parent})")


def _robot(rd: Reader, node: Any, key: str, path: Path, default_frame: str, joints: bool = False) -> RobotSpec:
    allowed = {"urdf", "frame", "base_pose", "needle"} | ({"joints"} if joints else set())
    m = rd.mapping(node, key, allowed, {"urdf"} | ({"joints"} if joints else set()))
    urdf, rel = resolve_path(rd, m["urdf"], f"{key}.urdf", path)
    base = _pose(rd, m["base_pose"], f"{key}.base_pose") if "base_pose" in m else np.eye(4)
    grasp = radius = None
    if "needle" in m:
        n = rd.mapping(m["needle"], f"{key}.needle", {"radius", "grasp"}, {"radius", "grasp"})
        radius = rd.number(n["radius"], f"{key}.needle.radius", positive=True)
        grasp = _pose(rd, n["grasp"], f"{key}.needle.grasp")
    return RobotSpec(urdf=urdf, urdf_rel=rel, frame=rd.string(m.get("frame", default_frame), f"{key}.frame"),
                     base_pose=base, grasp=grasp, needle_radius=radius,
                     joints=rd.vector(m["joints"], f"{key}.joints") if joints else None)


def _pose(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A pose: `position` plus one of `rpy`, `axis_angle`, `minus_z_toward` (a point), or a 4x4 `matrix`."""
    m = rd.mapping(node, key, {"position", "rpy", "axis_angle", "minus_z_toward", "matrix"})
    if "matrix" in m:
        if len(m) != 1:
            raise rd.fail(key, "a 'matrix' pose takes no other keys")
        T = rd.matrix(m["matrix"], f"{key}.matrix", 4)
        R = T[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0 or not np.allclose(T[3], [0, 0, 0, 1]):
            raise rd.fail(f"{key}.matrix", "not a rigid transform (rotation must be orthonormal, last row 0 0 0 1)")
        return T
    if "position" not in m:
        raise rd.fail(f"{key}.position", "missing required key")
    T = np.eye(4)
    T[:3, 3] = rd.vector(m["position"], f"{key}.position", 3)
    kind = rd.one_of(m, key, ["rpy", "axis_angle", "minus_z_toward"])
    if kind == "rpy":
        T[:3, :3] = rpy_matrix(rd.vector(m["rpy"], f"{key}.rpy", 3))
    elif kind == "axis_angle":
        T[:3, :3] = np_exp(rd.vector(m["axis_angle"], f"{key}.axis_angle", 3))
    else:
        target = rd.vector(m["minus_z_toward"], f"{key}.minus_z_toward", 3)
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
        fx=rd.number(i["fx"], f"{k}.fx", positive=True), fy=rd.number(i["fy"], f"{k}.fy", positive=True),
        cx=rd.number(i["cx"], f"{k}.cx"), cy=rd.number(i["cy"], f"{k}.cy"),
        width=rd.integer(i["width"], f"{k}.width", minimum=1), height=rd.integer(i["height"], f"{k}.height", minimum=1),
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
        step = rd.integer(mv["step"], f"{k}.step", minimum=1)
        if out and step <= out[-1].step:
            raise rd.fail(f"{k}.step", "moves must be listed in increasing step order")
        out.append(CameraMove(step, rd.vector(mv["ecm_joints"], f"{k}.ecm_joints")))
    return tuple(out)


def _endpoint(rd: Reader, node: Any, key: str, path: Path) -> EndpointSpec:
    m = rd.mapping(node, key, {"joints", "pose", "relative"})
    kind = rd.one_of(m, key, ["joints", "pose", "relative"])
    if kind == "joints":
        return EndpointSpec(joints=rd.vector(m["joints"], f"{key}.joints"), key=f"{key}.joints")
    if kind == "relative":
        r = rd.mapping(m["relative"], f"{key}.relative", {"arm", "pose"}, {"arm", "pose"})
        arm = _robot(rd, r["arm"], f"{key}.relative.arm", path, default_frame="tool", joints=True)
        return EndpointSpec(relative=RelativeGoal(arm, _pose6(rd, r["pose"], f"{key}.relative.pose")),
                            key=f"{key}.relative")
    return EndpointSpec(pose=_pose6(rd, m["pose"], f"{key}.pose"), key=f"{key}.pose")


def _pose6(rd: Reader, node: Any, key: str) -> np.ndarray:
    p = rd.mapping(node, key, {"position", "axis_angle"}, {"position", "axis_angle"})
    return np.concatenate([rd.vector(p["position"], f"{key}.position", 3),
                           rd.vector(p["axis_angle"], f"{key}.axis_angle", 3)])


_NOISE_KEYS = {"observation_scale", "camera_W_p0", "camera_W_o0", "W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "Sigma0", "depth_star", "o_star", "components",
               "orientation_formula", "observation_noise"}


def _noise(rd: Reader, node: Any) -> NoiseParams:
    m = rd.mapping(node, "noise", _NOISE_KEYS)
    d = NoiseParams()
    kw: dict[str, Any] = {}
    for name in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "camera_W_p0", "camera_W_o0"):
        kw[name] = rd.covariance(m[name], f"noise.{name}") if name in m else getattr(d, name)
    light = rd.number(m.get("observation_scale", 1.0), "noise.observation_scale", positive=True)
    for name in ("V_d0", "V_f0", "V_o0"):  # dim light: every observation term scaled alike
        kw[name] = light * kw[name]
    kw["Sigma0"] = rd.covariance(m["Sigma0"], "noise.Sigma0", definite=True) if "Sigma0" in m else d.Sigma0
    kw["depth_star"] = rd.number(m.get("depth_star", d.depth_star), "noise.depth_star", positive=True)
    o = rd.vector(m.get("o_star", list(d.o_star)), "noise.o_star", 3)
    if np.linalg.norm(o) == 0:
        raise rd.fail("noise.o_star", "must be a non-zero axis-angle vector (its direction is used)")
    kw["o_star"] = tuple(float(v) for v in o)
    comps = m.get("components", list(COMPONENTS))
    if not isinstance(comps, list):
        raise rd.fail("noise.components", f"expected a list drawn from {', '.join(COMPONENTS)}")
    kw["components"] = tuple(rd.string(c, f"noise.components[{i}]", COMPONENTS) for i, c in enumerate(comps))
    kw["orientation_formula"] = rd.string(m.get("orientation_formula", d.orientation_formula),
                                          "noise.orientation_formula", ORIENTATION_FORMULAS)
    kw["observation_noise"] = rd.string(m.get("observation_noise", d.observation_noise), "noise.observation_noise",
                                        OBSERVATION_NOISE_FORMS)
    return NoiseParams(**kw)


def _codegen(rd: Reader, node: Any) -> bool | str:
    if node == "auto" or isinstance(node, bool):
        return node
    raise rd.fail("solver.codegen", f"expected true, false or auto, got {node!r}")


def _solver(rd: Reader, node: Any) -> SolverSpec:
    m = rd.mapping(node, "solver", {"name", "max_iter", "tol", "print_level", "covariance", "hessian",
                                    "surrogate_max_iter", "codegen", "options"})
    d = SolverSpec()
    opts = m.get("options", {})
    if not isinstance(opts, dict):
        raise rd.fail("solver.options", "expected a mapping of raw solver options")
    return SolverSpec(
        name=rd.string(m.get("name", d.name), "solver.name", ("auto", "ipopt", "newton")),
        max_iter=rd.integer(m.get("max_iter", d.max_iter), "solver.max_iter", minimum=1),
        tol=rd.number(m.get("tol", d.tol), "solver.tol", positive=True),
        print_level=rd.integer(m.get("print_level", d.print_level), "solver.print_level", minimum=0),
        covariance=rd.string(m.get("covariance", d.covariance), "solver.covariance",
                             ("auto", "full", "diagonal", "condensed")),
        hessian=rd.string(m.get("hessian", d.hessian), "solver.hessian", ("auto", "exact", "surrogate", "gauss-newton")),
        surrogate_max_iter=rd.integer(m.get("surrogate_max_iter", d.surrogate_max_iter),
                                         "solver.surrogate_max_iter", minimum=1),
        codegen=_codegen(rd, m.get("codegen", d.codegen)),
        options=dict(opts),
    )


def _gradient(rd: Reader, node: Any) -> GradientSpec:
    m = rd.mapping(node, "gradient", {"iterations", "memory", "pose_loss_weight"})
    d = GradientSpec()
    return GradientSpec(
        iterations=rd.integer(m.get("iterations", d.iterations), "gradient.iterations", minimum=1),
        memory=rd.integer(m.get("memory", d.memory), "gradient.memory", minimum=1),
        pose_loss_weight=rd.number(m.get("pose_loss_weight", d.pose_loss_weight), "gradient.pose_loss_weight",
                                   nonneg=True),
    )
