"""A problem's YAML tree -> `Problem`: `parse_problem` and one parser per section, each validating
strictly.

Every error is a one-line `ProblemError` naming the file, the key path and what is allowed
(`schema.Reader`); the caps on the values a problem may hold are here (problems/README.md,
"Limits").
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ProblemError, ProblemErrors, shown
from ..model.belief import (
    BeliefModel,
    COMPONENTS,
    OBJECTIVES,
    OBSERVATION_NOISE_FORMS,
    ORIENTATION_FORMULAS,
    NoiseParams,
)
from ..model.camera import Intrinsics
from ..model.detection import Detection
from ..model.lie import np_exp, rpy_matrix
from ..model.limits.values import urdf_velocity_limits
from .ipopt_options import check_ipopt_options
from .paths import resolve_path
from .schema import Reader
from .solver_config import SOLVER_NAMES, resolve
from .spec import (
    GRADIENT_PRESETS,
    CameraMove,
    CameraSpec,
    EndpointSpec,
    GradientSpec,
    GraspSpec,
    LimitsSpec,
    ObjectiveSpec,
    Problem,
    RelativeGoal,
    RobotSpec,
    SolverSpec,
    TimingSpec,
)

# Limits of what a problem (or evaluation) file may hold (problems/README.md, "Limits").
MAX_HORIZON = 200  # T (a solve's time and memory grow with T; problems/README.md "Limits")
MAX_POSITION = 100.0  # [m] any position (poses, points)
MAX_ANGLE = 1000.0  # [rad] any angle, axis-angle or joint value
MAX_FOCAL = 1e6  # [px]
MAX_IMAGE = 100_000  # [px] image width and height
MAX_FRAMES_PER_STEP = 10_000


_TOP = {"name", "description", "robot", "camera", "start", "goal", "horizon", "noise",
        "constraints", "objective", "solver", "gradient", "timing", "limits", "detection"}
_REQUIRED_TOP = {"robot", "camera", "start", "goal", "horizon"}


# errors reported per section (each found by reading it again without the last bad key)
MAX_SECTION_ERRORS = 20


def _key_path(key: str | None, section: str) -> list[str]:
    """The mapping keys inside `section` of an error's key path, up to the first list index:
    `goal.pose.position[2]` in `goal` -> [`pose`, `position`]."""
    if not key or not (key == section or key.startswith(section + ".")
                       or key.startswith(section + "[")):
        return []
    out = []
    for part in key[len(section):].lstrip(".").split("."):
        if not part:
            break
        name = part.split("[")[0]
        if not name:
            break
        out.append(name)
        if "[" in part:
            break
    return out


def _more_errors(section: str, node: Any, read, args: tuple, kwargs: dict,
                 first: ProblemError) -> list[ProblemError]:
    """The section's further errors: it is read again with each bad key removed, until it reads or
    an error repeats (a key that was removed and is then missing is not another error)."""
    if not isinstance(node, Mapping):
        return []
    where = next((i for i, a in enumerate(args) if a is node), None)
    if where is None:
        return []
    copy, exc, found, removed = copy_tree(node), first, [], []
    for _ in range(MAX_SECTION_ERRORS - 1):
        path = _key_path(exc.key, section)
        parent = copy
        for name in path[:-1]:
            parent = parent.get(name) if isinstance(parent, Mapping) else None
        if not path or not isinstance(parent, dict) or path[-1] not in parent:
            break
        del parent[path[-1]]
        removed.append(".".join([section, *path]))
        try:
            read(*args[:where], copy, *args[where + 1:], **kwargs)
            break
        except ProblemError as again:
            if _consequence(again.key, removed, section, node) or any(
                    again.key == e.key for e in [first, *found]):
                break  # caused by a removed key, or the same error again
            found.append(again)
            exc = again
    return found


def _consequence(key: str | None, removed: list[str], section: str, node: Any) -> bool:
    """Whether an error at `key` is caused by removing the keys `removed` from `node` (the
    section's tree): the key itself or an ancestor of one (reported missing, or `give exactly one
    of`), or a sibling of one that `node` does not have, which the removed key stood for
    (`pose.matrix` removed: `pose.position` missing)."""
    key = key or ""
    if any(r == key or r.startswith(key + ".") for r in removed):
        return True
    parent = key.rsplit(".", 1)[0]
    if not any(r.rsplit(".", 1)[0] == parent for r in removed):
        return False
    path = _key_path(key, section)
    for name in path:
        if not isinstance(node, Mapping) or name not in node:
            return True
        node = node[name]
    return False


def copy_tree(node: Any) -> Any:
    """A copy of a YAML tree's mappings and lists (the leaves shared)."""
    if isinstance(node, Mapping):
        return {k: copy_tree(v) for k, v in node.items()}
    if isinstance(node, list):
        return [copy_tree(v) for v in node]
    return node


def parse_problem(tree: Any, path: Path) -> Problem:
    """`tree` (a problem file's YAML) read into a Problem. Each top-level section is read even when
    another has an error, so every error of a file is reported at once: one error is a ProblemError,
    several a `ProblemErrors` (one line each; a section is read again without each bad key until it
    reads, so all its errors are found; `limits`, which needs the robot's joints, is read only when
    the robot is right)."""
    rd = Reader(str(path))
    errors: list[ProblemError] = []
    top = _top(rd, tree, errors)

    def section(key: str, read, *args, required: bool = False, **kwargs):
        if required and key not in top:  # (its error is the top level's)
            return None
        try:
            return read(*args, **kwargs)
        except ProblemError as exc:
            errors.append(exc)
            errors.extend(_more_errors(key, top.get(key), read, args, kwargs, exc))
            return None

    robot = section("robot", _robot, rd, top.get("robot"), "robot", path, default_frame="tool",
                    required=True)
    camera = section("camera", _camera, rd, top.get("camera"), path, required=True)
    start = section("start", _endpoint, rd, top.get("start"), "start", path, required=True)
    goal = section("goal", _endpoint, rd, top.get("goal"), "goal", path, required=True)
    horizon = section("horizon", rd.integer, top.get("horizon"), "horizon", minimum=1,
                      maximum=MAX_HORIZON, required=True)
    timing = section("timing", _timing, rd, top.get("timing", {}))
    detection = section("detection", read_detection, rd, top.get("detection"), enabled=False)
    grasp = section("goal", _grasp, rd, top.get("goal"), required=True)
    if timing is not None and horizon is not None and timing.max_duration is not None \
            and timing.max_duration < horizon * timing.step_s - 1e-9:
        errors.append(rd.fail("timing.max_duration", f"must be at least the problem's duration "
                              f"(horizon x timing.step_s = {horizon * timing.step_s:g} s), got "
                              f"{timing.max_duration:g}"))
    # (a wrong timing: the noise read with one frame per step, so that its own
    # errors are still found)
    noise = section("noise", _noise, rd, top.get("noise", {}),
                    frames=(timing or TimingSpec()).frames)
    cons = section("constraints", rd.mapping, top.get("constraints", {}), "constraints",
                   {"min_depth"})
    min_depth = None if cons is None else section(
        "constraints", rd.number, cons.get("min_depth", 0.03), "constraints.min_depth",
        positive=True, low=1e-4, high=10.0)
    objective, covariance = (section("objective", _objective, rd, top.get("objective", {}))
                             or (None, None))
    solver = section("solver", _solver, rd, top.get("solver", {}))
    gradient = section("gradient", _gradient, rd, top.get("gradient", {}))
    limits = None if robot is None else section("limits", _limits, rd, top.get("limits", {}), robot)
    name = section("name", rd.string, top.get("name", path.stem), "name")
    description = section("description", rd.string, top.get("description", ""), "description")
    if errors:
        order = {str(k): i for i, k in enumerate(tree)}  # the file's order of its sections
        errors.sort(key=lambda e: order.get(re.split(r"[.\[]", e.key or "")[0], len(order)))
        raise errors[0] if len(errors) == 1 else ProblemErrors(errors)
    # which covariance the planners minimise: Sigma_T|T (the paper's) or Sigma_T|T-1, the one that
    # governs the executed error under closed-loop control (section 8)
    noise = replace(noise, objective=covariance)
    problem = Problem(
        name=name,
        description=description,
        path=path,
        robot=robot,
        camera=camera,
        start=start,
        goal=goal,
        horizon=horizon,
        noise=noise,
        min_depth=min_depth,
        objective=objective,
        solver=solver,
        gradient=gradient,
        timing=timing,
        limits=limits,
        grasp=grasp,
        detection=detection,
        source=tree,
    )
    # the solver choices against the noise model, when the file is read (the robot's
    # rule: build_setup)
    resolve(problem.solver, BeliefModel(problem.noise, problem.camera.intrinsics), None,
            file=str(path), limited=problem.limits.enforce)
    return problem


def _top(rd: Reader, tree: Any, errors: list[ProblemError]) -> dict:
    """The top-level mapping's known keys; each unknown and each missing required key an error in
    `errors` (not a mapping at all: raised, nothing else can be read)."""
    if not isinstance(tree, Mapping):
        rd.mapping(tree, "", _TOP)  # raises, naming what is expected
    unknown = sorted(set(tree) - _TOP, key=str)
    missing = sorted(_REQUIRED_TOP - set(tree))
    # a misspelt required key is one error, naming the key it stands for
    meant = {k: next(iter(difflib.get_close_matches(str(k), missing, 1)), None) for k in unknown}
    errors += [rd.fail(str(k), f"unknown key; allowed keys here: {', '.join(sorted(_TOP))}"
                       + (f"; missing here: {meant[k]}" if meant[k] else "")) for k in unknown]
    errors += [rd.fail(k, "missing required key") for k in missing if k not in meant.values()]
    return {k: v for k, v in tree.items() if k in _TOP}


def _objective(rd: Reader, node: Any) -> tuple[ObjectiveSpec, str]:
    obj = rd.mapping(node, "objective", {"smoothness", "covariance"})
    return (ObjectiveSpec(smoothness=rd.number(obj.get("smoothness", 0.0), "objective.smoothness",
                                               nonneg=True, high=1e6)),
            rd.string(obj.get("covariance", "posterior"), "objective.covariance", OBJECTIVES))


def _timing(rd: Reader, node: Any) -> TimingSpec:
    """`timing: {step_s, tracker_hz}`; a step must span a whole number (>= 1) of tracker frames."""
    m = rd.mapping(node, "timing", {"step_s", "tracker_hz", "max_duration"})
    d = TimingSpec()
    step = rd.number(m.get("step_s", d.step_s), "timing.step_s", positive=True, high=3600.0)
    hz = rd.number(m.get("tracker_hz", d.tracker_hz), "timing.tracker_hz", positive=True,
                   high=10_000.0)
    k = step * hz
    if abs(k - round(k)) > 1e-9 * max(1.0, k) or round(k) < 1 or round(k) > MAX_FRAMES_PER_STEP:
        raise rd.fail("timing", f"step_s * tracker_hz = {step:g} s * {hz:g} Hz = {k:g} tracker "
                                "frames per step; it must be a whole number from 1 to "
                                f"{MAX_FRAMES_PER_STEP} (e.g. step_s 0.1 with tracker_hz 20: "
                                "2 frames)")
    cap = m.get("max_duration")
    cap = None if cap is None else rd.number(cap, "timing.max_duration", positive=True,
                                             high=3600.0)
    return TimingSpec(step_s=step, tracker_hz=hz, max_duration=cap)


def _limits(rd: Reader, node: Any, robot: RobotSpec) -> LimitsSpec:
    """`limits: {enforce, joint_velocity: {JOINT: v}, joint_acceleration: {JOINT: a}, tool_speed,
    tool_rotation_speed, rcm_distance}`; joint names are checked against the URDF's moving joints.
    """
    m = rd.mapping(node, "limits", {"enforce", "joint_velocity", "joint_acceleration", "tool_speed",
                                    "tool_rotation_speed", "rcm_distance"})
    joints = None
    per_joint = {}
    for key in ("joint_velocity", "joint_acceleration"):
        sub = rd.mapping(m.get(key, {}), f"limits.{key}",
                         set(m.get(key) or {}) if isinstance(m.get(key), dict) else set())
        if sub and joints is None:
            joints = set(urdf_velocity_limits(robot.urdf))
        for name, value in sub.items():
            if str(name) not in joints:
                raise rd.fail(f"limits.{key}.{name}",
                              f"no moving joint '{shown(str(name))}' in {robot.urdf_rel}; "
                              f"allowed: {', '.join(sorted(joints))}")
            sub[name] = rd.number(value, f"limits.{key}.{name}", positive=True, high=1e6)
        per_joint[key] = tuple(sorted((str(k), float(v)) for k, v in sub.items()))
    opt = {k: (None if k not in m else rd.number(m[k], f"limits.{k}", positive=True, high=hi))
           for k, hi in (("tool_speed", 100.0), ("tool_rotation_speed", 1000.0),
                         ("rcm_distance", 10.0))}
    return LimitsSpec(enforce=rd.boolean(m.get("enforce", False), "limits.enforce"), **per_joint,
                      **opt)


def _robot(rd: Reader, node: Any, key: str, path: Path, default_frame: str,
           joints: bool = False) -> RobotSpec:
    allowed = {"urdf", "frame", "base_pose", "needle"} | ({"joints"} if joints else set())
    m = rd.mapping(node, key, allowed, {"urdf"} | ({"joints"} if joints else set()))
    urdf, rel = resolve_path(rd, m["urdf"], f"{key}.urdf", path)
    base = _pose(rd, m["base_pose"], f"{key}.base_pose") if "base_pose" in m else np.eye(4)
    grasp = radius = None
    if "needle" in m:
        n = rd.mapping(m["needle"], f"{key}.needle", {"radius", "grasp"}, {"radius", "grasp"})
        radius = rd.number(n["radius"], f"{key}.needle.radius", positive=True, low=1e-4, high=1.0)
        grasp = _pose(rd, n["grasp"], f"{key}.needle.grasp")
    return RobotSpec(urdf=urdf, urdf_rel=rel,
                     frame=rd.string(m.get("frame", default_frame), f"{key}.frame"),
                     base_pose=base, grasp=grasp, needle_radius=radius,
                     joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE) if joints
                     else None)


def _pose(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A pose: `position` plus one of `rpy`, `axis_angle`, `minus_z_toward` (a point), or a 4x4
    `matrix`; or the list of 6 `[px, py, pz, rx, ry, rz]` (position, axis-angle) the
    start and goal take."""
    if isinstance(node, (list, tuple)):
        p = _pose6(rd, node, key)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = np_exp(p[3:]), p[:3]
        return T
    m = rd.mapping(node, key, {"position", "rpy", "axis_angle", "minus_z_toward", "matrix"})
    if "matrix" in m:
        if len(m) != 1:
            raise rd.fail(key, "a 'matrix' pose takes no other keys")
        T = rd.matrix(m["matrix"], f"{key}.matrix", 4, limit=MAX_POSITION)
        R = T[:3, :3]
        if (not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0
                or not np.allclose(T[3], [0, 0, 0, 1])):
            raise rd.fail(f"{key}.matrix", "not a rigid transform (rotation must be orthonormal, "
                                           "last row 0 0 0 1)")
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
    i = rd.mapping(m["intrinsics"], "camera.intrinsics",
                   {"fx", "fy", "cx", "cy", "width", "height"},
                   {"fx", "fy", "cx", "cy", "width", "height"})
    k = "camera.intrinsics"
    intr = Intrinsics(
        fx=rd.number(i["fx"], f"{k}.fx", low=1.0, high=MAX_FOCAL),
        fy=rd.number(i["fy"], f"{k}.fy", low=1.0, high=MAX_FOCAL),
        cx=rd.number(i["cx"], f"{k}.cx", limit=MAX_FOCAL),
        cy=rd.number(i["cy"], f"{k}.cy", limit=MAX_FOCAL),
        width=rd.integer(i["width"], f"{k}.width", minimum=1, maximum=MAX_IMAGE),
        height=rd.integer(i["height"], f"{k}.height", minimum=1, maximum=MAX_IMAGE),
    )
    kind = rd.one_of(m, "camera", ["pose", "ecm"])
    if kind == "pose":
        if "moves" in m:
            raise rd.fail("camera.moves",
                          "camera moves need the camera given as camera.ecm (joint values)")
        return CameraSpec(intrinsics=intr, pose=_pose(rd, m["pose"], "camera.pose"))
    ecm = _robot(rd, m["ecm"], "camera.ecm", path, default_frame="camera", joints=True)
    return CameraSpec(intrinsics=intr, ecm=ecm, ecm_joints=ecm.joints,
                      moves=_moves(rd, m.get("moves", [])))


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
        out.append(CameraMove(step, rd.vector(mv["ecm_joints"], f"{k}.ecm_joints",
                                              limit=MAX_ANGLE)))
    return tuple(out)


def _endpoint(rd: Reader, node: Any, key: str, path: Path) -> EndpointSpec:
    grasp = _GRASP_KEYS if key == "goal" else ()  # (read by _grasp)
    m = rd.mapping(node, key, {"joints", "pose", "relative", *grasp})
    kind = rd.one_of(m, key, ["joints", "pose", "relative"])
    if kind == "joints":
        return EndpointSpec(joints=rd.vector(m["joints"], f"{key}.joints", limit=MAX_ANGLE),
                            key=f"{key}.joints")
    if kind == "relative":
        r = rd.mapping(m["relative"], f"{key}.relative", {"arm", "pose"}, {"arm", "pose"})
        arm = _robot(rd, r["arm"], f"{key}.relative.arm", path, default_frame="tool", joints=True)
        pose = _pose6(rd, r["pose"], f"{key}.relative.pose")
        return EndpointSpec(relative=RelativeGoal(arm, pose), key=f"{key}.relative")
    return EndpointSpec(pose=_pose6(rd, m["pose"], f"{key}.pose"), key=f"{key}.pose")


def read_detection(rd: Reader, node: Any, enabled: bool = True) -> Detection | None:
    """`detection: {enabled, margin, min_depth, max_depth, falloff}` (`model.detection.Detection`;
    None when disabled; absent: `enabled`'s default with the detector's defaults)."""
    det = rd.mapping({} if node is None else node, "detection",
                     {"enabled", "margin", "min_depth", "max_depth", "falloff"})
    if not rd.boolean(det.get("enabled", enabled or node is not None), "detection.enabled"):
        return None
    d0 = Detection()
    detection = Detection(
        margin=rd.number(det.get("margin", d0.margin), "detection.margin", nonneg=True),
        min_depth=rd.number(det.get("min_depth", d0.min_depth), "detection.min_depth",
                            nonneg=True),
        max_depth=rd.number(det.get("max_depth", d0.max_depth), "detection.max_depth",
                            positive=True),
        falloff=rd.number(det.get("falloff", d0.falloff), "detection.falloff", nonneg=True))
    if detection.max_depth <= detection.min_depth:
        raise rd.fail("detection.max_depth",
                      f"must exceed detection.min_depth ({detection.min_depth:g} m)")
    if detection.margin + detection.falloff >= 0.5:
        raise rd.fail("detection.falloff", f"margin + falloff must be < 0.5 (fractions of the "
                                           f"image size), got {detection.margin:g} + "
                                           f"{detection.falloff:g}")
    return detection


_GRASP_KEYS = ("tolerance", "confidence")


def _grasp(rd: Reader, node: Any) -> GraspSpec:
    """`goal.tolerance: {position, angle}` ([m], [rad]; default 5 mm, 0.2 rad) and
    `goal.confidence` (in (0, 1); default none): the grasp's success and how sure to be of it."""
    m = node if isinstance(node, Mapping) else {}  # (a goal that is no mapping: _endpoint's error)
    d = GraspSpec()
    tol = rd.mapping(m.get("tolerance", {}), "goal.tolerance", {"position", "angle"})
    position = rd.number(tol.get("position", d.position), "goal.tolerance.position",
                         positive=True, high=1.0)
    angle = rd.number(tol.get("angle", d.angle), "goal.tolerance.angle", positive=True,
                      high=np.pi)
    confidence = m.get("confidence")
    if confidence is not None:
        confidence = rd.number(confidence, "goal.confidence")
        if not 0.0 < confidence < 1.0:
            raise rd.fail("goal.confidence", f"must be strictly between 0 and 1 (e.g. 0.95), got "
                                             f"{confidence:g}")
    return GraspSpec(position=position, angle=angle, confidence=confidence)


def _pose6(rd: Reader, node: Any, key: str) -> np.ndarray:
    """A tool pose `{position: [x, y, z], axis_angle: [rx, ry, rz]}` or the same as one
    list of 6 numbers."""
    if isinstance(node, (list, tuple)):
        if len(node) != 6:
            raise rd.fail(key, "expected 6 numbers [px, py, pz, rx, ry, rz] (position [m], "
                               "axis-angle [rad]) or {position, axis_angle}, got a list "
                               f"of {len(node)}")
        return np.array([rd.number(v, f"{key}[{i}]", limit=MAX_POSITION if i < 3 else MAX_ANGLE)
                         for i, v in enumerate(node)])
    p = rd.mapping(node, key, {"position", "axis_angle"}, {"position", "axis_angle"})
    return np.concatenate([rd.vector(p["position"], f"{key}.position", 3, limit=MAX_POSITION),
                           rd.vector(p["axis_angle"], f"{key}.axis_angle", 3, limit=MAX_ANGLE)])


_NOISE_KEYS = {"observation_scale", "camera_W_p0", "camera_W_o0", "W_p0", "W_o0", "V_d0", "V_f0",
               "V_o0", "Sigma0", "depth_star", "o_star", "components", "orientation_formula",
               "observation_noise", "V_min", "cosine_guard", "cut_band", "joint_motion_sigma"}


def _noise(rd: Reader, node: Any, frames: int = 1) -> NoiseParams:
    m = rd.mapping(node, "noise", _NOISE_KEYS)
    d = NoiseParams()
    kw: dict[str, Any] = {}
    for name in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "camera_W_p0", "camera_W_o0"):
        kw[name] = rd.covariance(m[name], f"noise.{name}") if name in m else getattr(d, name)
    light = rd.number(m.get("observation_scale", 1.0), "noise.observation_scale", positive=True,
                      low=1e-6, high=1e6)
    # `frames` tracker observations per step (timing), each with covariance V, are one with V /
    # frames (problems/README.md, "Time in the model"): applied with the light scale, to every
    # observation term
    light = light / frames
    # the observation noise floor (no detector is perfect): PSD, scalar or 6x6, scaled like the
    # terms
    kw["V_min"] = rd.covariance(m["V_min"], "noise.V_min") if "V_min" in m else d.V_min
    for name in ("V_d0", "V_f0", "V_o0", "V_min"):  # dim light: every observation term scaled alike
        kw[name] = light * kw[name]
    kw["Sigma0"] = (rd.covariance(m["Sigma0"], "noise.Sigma0", definite=True) if "Sigma0" in m
                    else d.Sigma0)
    kw["depth_star"] = rd.number(m.get("depth_star", d.depth_star), "noise.depth_star",
                                 positive=True, low=1e-4, high=10.0)
    o = rd.vector(m.get("o_star", list(d.o_star)), "noise.o_star", 3, limit=MAX_ANGLE)
    if np.linalg.norm(o) < 1e-6:
        raise rd.fail("noise.o_star",
                      "must be a non-zero axis-angle vector (its direction is used)")
    kw["o_star"] = tuple(float(v) for v in o)
    comps = m.get("components", list(COMPONENTS))
    if not isinstance(comps, list):
        raise rd.fail("noise.components", f"expected a list drawn from {', '.join(COMPONENTS)}")
    kw["components"] = tuple(rd.string(c, f"noise.components[{i}]", COMPONENTS)
                             for i, c in enumerate(comps))
    if not kw["components"]:
        raise rd.fail("noise.components", f"empty; give at least one of {', '.join(COMPONENTS)}")
    if len(set(kw["components"])) != len(kw["components"]):
        raise rd.fail("noise.components", "a component is listed twice")
    kw["orientation_formula"] = rd.string(m.get("orientation_formula", d.orientation_formula),
                                          "noise.orientation_formula", ORIENTATION_FORMULAS)
    kw["observation_noise"] = rd.string(m.get("observation_noise", d.observation_noise),
                                        "noise.observation_noise", OBSERVATION_NOISE_FORMS)
    kw["cosine_guard"] = rd.number(m.get("cosine_guard", d.cosine_guard), "noise.cosine_guard",
                                   low=0.0, high=1.0)
    kw["cut_band"] = rd.number(m.get("cut_band", d.cut_band), "noise.cut_band", low=0.0, high=1.0)
    # one number for every joint, or one per joint (its length is checked on setup)
    if "joint_motion_sigma" in m:
        node, key = m["joint_motion_sigma"], "noise.joint_motion_sigma"
        nodes = node if isinstance(node, list) else [node]
        if not nodes:
            raise rd.fail(key, "empty; give one number for every joint or one per joint")
        kw["joint_sigma"] = tuple(rd.number(v, key if not isinstance(node, list) else f"{key}[{i}]",
                                            low=0.0, high=1.0) for i, v in enumerate(nodes))
    return NoiseParams(**kw)


def _codegen(rd: Reader, node: Any) -> bool | str:
    if node == "auto" or isinstance(node, bool):
        return node
    raise rd.fail("solver.codegen", f"expected true, false or auto, got {shown(node)}")


def _solver(rd: Reader, node: Any) -> SolverSpec:
    m = rd.mapping(node, "solver", {"name", "max_iter", "tol", "print_level", "covariance",
                                    "hessian", "surrogate_max_iter", "codegen", "options"})
    d = SolverSpec()
    opts = m.get("options", {})
    if not isinstance(opts, dict):
        raise rd.fail("solver.options", "expected a mapping of raw solver options")
    return SolverSpec(
        name=rd.string(m.get("name", d.name), "solver.name", SOLVER_NAMES),
        max_iter=rd.integer(m.get("max_iter", d.max_iter), "solver.max_iter", minimum=1,
                            maximum=1_000_000),
        tol=rd.number(m.get("tol", d.tol), "solver.tol", positive=True, low=1e-14, high=1.0),
        print_level=rd.integer(m.get("print_level", d.print_level), "solver.print_level",
                               minimum=0, maximum=12),
        covariance=rd.string(m.get("covariance", d.covariance), "solver.covariance",
                             ("auto", "full", "diagonal", "condensed")),
        hessian=rd.string(m.get("hessian", d.hessian), "solver.hessian",
                          ("auto", "exact", "surrogate", "gauss-newton")),
        surrogate_max_iter=rd.integer(m.get("surrogate_max_iter", d.surrogate_max_iter),
                                      "solver.surrogate_max_iter", minimum=1, maximum=1_000_000),
        codegen=_codegen(rd, m.get("codegen", d.codegen)),
        options=_ipopt_options(rd, opts),
    )


def _gradient(rd: Reader, node: Any, key: str = "gradient") -> GradientSpec:
    m = rd.mapping(node, key, set(GradientSpec.__dataclass_fields__))
    preset = (rd.string(m["preset"], f"{key}.preset", tuple(GRADIENT_PRESETS)) if "preset" in m
              else "")
    d = replace(GradientSpec(), **GRADIENT_PRESETS.get(preset, {}))
    g = lambda k: m.get(k, getattr(d, k))
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
    """Raw IPOPT options: names IPOPT knows, values of the type it expects (checked by IPOPT
    itself)."""
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
    if problem:  # the option IPOPT refuses alone, named (else the set as a whole)
        for name, value in out.items():
            alone = check_ipopt_options({name: value})
            if alone:
                raise rd.fail(f"solver.options.{name}", _ipopt_reason(name, value, alone))
        raise rd.fail("solver.options", problem)
    return out


def _ipopt_reason(name: str, value: Any, reason: str) -> str:
    """IPOPT's refusal of one option; a value of the wrong type says the type the option takes."""
    if "type mismatch" not in reason:
        return reason.replace("refused them", "refused it", 1)
    takes = [kind for kind, sample in (("a string", "x"), ("a number", 1.5))
             if "type mismatch" not in (check_ipopt_options({name: sample}) or "")]
    given = f"'{shown(value)}'" if isinstance(value, str) else shown(value)
    return f"IPOPT refused {given}: the option takes {' or '.join(takes) or 'another type'}"


