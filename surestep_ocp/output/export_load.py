"""Reading a solution file for `surestep export`: the plan's waypoints, its seconds per step and its limits.

Every malformed file is a one-line error naming it and the key; the limits are those the plan was made with
(the solution's recorded `limits`), else the defaults for its URDF, with the command line's overrides on top.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import SurestepError, shown
from ..model.limits import MotionLimits, motion_limits

DEFAULT_STEP_S = 0.05  # the paper's pace when a solution file records no timing (timing.step_s default)
POSITION_TOL = 1e-6  # [relative] a waypoint this far beyond a position limit is clipped onto it, further is an error
COMMAND_LINE = "command line"  # the source of a limit given by an export flag


def solution_label(solution) -> str:
    """How errors and the export's metadata name a solution: its file, or `<the METHOD Solution>`."""
    if hasattr(solution, "to_dict"):
        return f"<the {shown(getattr(solution, 'method', ''), 60)} Solution>"
    return str(solution)


def load_solution(path) -> dict:
    """The solution JSON as a dict (`path`: its file, or a `Solution` as it would be saved); a missing or
    malformed one is a one-line error naming it."""
    if hasattr(path, "to_dict"):  # a Solution object: its dict as `Solution.save` writes it
        from .solution import _jsonable

        p = solution_label(path)
        d = json.loads(json.dumps(path.to_dict(), default=_jsonable))
        return _checked(d, p)
    p = Path(path)
    if not p.is_file():
        raise SurestepError(f"{p}: no such solution file")
    try:
        d = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SurestepError(f"{p}: not a solution JSON file ({str(exc).splitlines()[0]})") from None
    return _checked(d, p)


def _checked(d, p) -> dict:
    """`d` if it is a solution's dict (the keys export reads, well-formed), else a one-line error naming `p`."""
    missing = [k for k in ("q", "joint_names", "robot") if not isinstance(d, dict) or k not in d]
    if missing:
        raise SurestepError(f"{p}: not a solution file (missing key(s) {', '.join(missing)}; written by "
                            "`surestep solve --output` or `surestep compare`)")
    names, q = d["joint_names"], d["q"]
    if not isinstance(q, list) or len(q) < 2:
        raise SurestepError(f"{p}: key 'q' must list at least 2 waypoints")
    for i, qi in enumerate(q):
        if qi is None:
            raise SurestepError(f"{p}: q[{i}] is null (no IK solution for that waypoint); a plan with an "
                                "unreachable waypoint cannot be exported")
        if not isinstance(qi, list) or len(qi) != len(names) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in qi):
            raise SurestepError(f"{p}: q[{i}] must be {len(names)} finite numbers ({', '.join(names)})")
    robot = d["robot"]
    if not isinstance(robot, dict) or not isinstance(robot.get("urdf"), str) or not robot["urdf"] or \
            not isinstance(robot.get("frame", "tool"), (str, type(None))):
        raise SurestepError(f"{p}: key 'robot' must be a mapping with 'urdf' (a path) and optionally 'frame' (a name)")
    for key in ("limits", "timing"):
        if d.get(key) is not None and not isinstance(d[key], dict):
            raise SurestepError(f"{p}: key '{key}' must be a mapping (as `surestep solve` writes it)")
    limits = d.get("limits") or {}
    if limits and "velocity" not in limits and "unavailable" not in limits:
        raise SurestepError(f"{p}: key 'limits' is not the recorded form (joint_names, velocity, acceleration, "
                            "tool_speed_m_s, ...; as `surestep solve` writes it)")
    step = (d.get("timing") or {}).get("step_s", DEFAULT_STEP_S)
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not (math.isfinite(step) and step > 0):
        raise SurestepError(f"{p}: timing.step_s must be a positive number of seconds, got {shown(repr(step), 40)}")
    return d


def step_of(sol: dict, override: float | None) -> tuple[float, str]:
    """Seconds per planned step and where that value came from."""
    if override is not None:
        if not (math.isfinite(override) and override > 0):
            raise SurestepError(f"--step-s must be a positive number of seconds, got {override:g}")
        return float(override), "command line (--step-s)"
    timing = sol.get("timing") or {}
    if "step_s" in timing:
        return float(timing["step_s"]), "solution (timing.step_s)"
    return DEFAULT_STEP_S, "default (the solution records no timing)"


def limits_of(sol: dict, urdf: Path, velocity: dict | None = None, acceleration: dict | None = None,
              tool_speed: float | None = None, tool_rotation: float | None = None) -> MotionLimits:
    """The limits to export within: those the solution records (its problem's `limits:`), else the
    defaults for its URDF (files written before solutions recorded them); the overrides on top."""
    rec = sol.get("limits")
    names = list(sol["joint_names"])
    if isinstance(rec, dict) and "velocity" in rec:
        base = MotionLimits.from_dict(rec)
        if list(base.joint_names) != names:
            raise SurestepError(f"recorded limits are for joints {', '.join(base.joint_names)}, the plan's are "
                                f"{', '.join(names)}")
        base = base.overridden()  # a copy
        base.sources["recorded"] = "solution (the problem's limits: resolved when it was planned)"
    else:
        base = motion_limits(urdf, names)
        base.sources["recorded"] = "none: defaults (the solution records no limits)"
    return base.overridden(velocity, acceleration, tool_speed, tool_rotation, label=COMMAND_LINE)


def within_position_limits(q: np.ndarray, robot) -> tuple[np.ndarray, float]:
    """The waypoints clipped into the URDF's position limits, and by how much at most. A solver meets its
    bounds to a tolerance (IPOPT: about 1e-8 relative), a controller refuses a target beyond a limit; a
    waypoint further out than POSITION_TOL is an error."""
    lo, hi = robot.lower, robot.upper
    out = np.clip(q, lo, hi)
    excess = np.abs(out - q)
    tol = POSITION_TOL * np.maximum(1.0, np.abs(np.where(q < lo, lo, hi)))
    bad = np.argwhere(excess > tol)
    if len(bad):
        i, j = bad[0]
        raise SurestepError(f"q[{i}] {robot.joint_names[j]} = {q[i, j]:.6g} is beyond its position limits "
                            f"[{lo[j]:.6g}, {hi[j]:.6g}]")
    return out, float(excess.max())


