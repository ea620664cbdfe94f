"""The readers of a problem file's model and solver sections, each validating strictly: the noise,
the timing, the motion limits, the objective, the detection, the solver (and its raw IPOPT
options) and the gradient variant.

Each takes the `schema.Reader` of the file and the section's YAML node, and returns its spec
(`sections.py`, `model.belief.NoiseParams`, `model.detection.Detection`) or raises a one-line
`ProblemError` naming the key.
"""

from __future__ import annotations

import re
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import shown
from ..model.belief import (
    COMPONENTS,
    OBJECTIVES,
    OBSERVATION_NOISE_FORMS,
    ORIENTATION_FORMULAS,
    NoiseParams,
)
from ..model.detection import Detection
from ..model.limits.values import urdf_velocity_limits
from .caps import MAX_ANGLE, MAX_FRAMES_PER_STEP
from .ipopt_options import check_ipopt_options
from .schema import Reader
from .sections import (
    GRADIENT_PRESETS,
    GradientSpec,
    LimitsSpec,
    ObjectiveSpec,
    RobotSpec,
    SolverSpec,
    TimingSpec,
)
from .solver_config import SOLVER_NAMES


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
