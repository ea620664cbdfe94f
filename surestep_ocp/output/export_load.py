"""Reading a solution file for `surestep export`: the plan's waypoints, its seconds per
step and its limits.

Every malformed file is a one-line error naming it and the key; the limits are those the plan was
made with (the solution's recorded `limits`), else the defaults for its URDF, with the command
line's overrides on top.

The reader keeps the problem reader's promises (issue 30): the file is a regular file of at most
MAX_SOLUTION_BYTES; every number read is finite and within the problem file's ranges (joint values
within MAX_JOINT_VALUE, a step within STEP_RANGE, joint limits within LIMIT_RANGE, the tool's within
TOOL_RANGES); at most MAX_WAYPOINTS waypoints. Anything else (a 100000-deep `[`, a 5000-digit
integer) is a one-line error too.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import SurestepError, shown
from ..model.limits import MotionLimits, motion_limits
from .files import MAX_SOLUTION_BYTES, input_file_problem
from .solution import _jsonable

# the paper's pace when a solution file records no timing (timing.step_s default)
DEFAULT_STEP_S = 0.05
# [relative] a waypoint this far beyond a position limit is clipped onto it, further is an error
POSITION_TOL = 1e-6
COMMAND_LINE = "command line"  # the source of a limit given by an export flag
MAX_WAYPOINTS = 10_000  # q's rows (a plan of T steps has T + 1; problem files allow T <= 200)
MAX_JOINTS = 64
MAX_JOINT_VALUE = 1000.0  # [rad or m] any joint value (the problem reader's MAX_ANGLE)
STEP_RANGE = (1e-6, 3600.0)  # [s] seconds per planned step (the problem reader allows at most 3600)
LIMIT_RANGE = (1e-6, 1e6)  # a joint's velocity [rad/s, m/s] or acceleration limit [rad/s^2, m/s^2]
TOOL_RANGES = {"tool_speed_m_s": (1e-6, 100.0), "tool_rotation_rad_s": (1e-6, 1000.0),
               "rcm_min_distance_m": (1e-6, 10.0)}  # the problem reader's highs


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _in_range(v, lo: float, hi: float) -> bool:
    return _real(v) and math.isfinite(v) and lo <= v <= hi


def _range_text(lo: float, hi: float) -> str:
    return f"a number in [{lo:g}, {hi:g}]"


def solution_label(solution) -> str:
    """How errors and the export's metadata name a solution: its file, or
    `<the METHOD Solution>`."""
    if hasattr(solution, "to_dict"):
        return f"<the {shown(getattr(solution, 'method', ''), 60)} Solution>"
    return str(solution)


def load_solution(path) -> dict:
    """The solution JSON as a dict (`path`: its file, or a `Solution` as it would be saved); a
    missing or malformed one is a one-line error naming it."""
    if hasattr(path, "to_dict"):  # a Solution object: its dict as `Solution.save` writes it
        p = solution_label(path)
        d = json.loads(json.dumps(path.to_dict(), default=_jsonable))
        return _checked(d, p)
    p = Path(path)
    try:
        problem = input_file_problem(p, MAX_SOLUTION_BYTES)
    except OSError:
        raise SurestepError(f"{p}: no such solution file") from None
    if problem is not None:
        raise SurestepError(f"{p}: {problem}; a solution file is read")
    try:
        d = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        # JSONDecodeError; an integer of over 4300 digits
        raise SurestepError(f"{p}: not a solution JSON file "
                            f"({shown(str(exc).splitlines()[0], 200)})") from None
    except RecursionError:
        raise SurestepError(f"{p}: not a solution JSON file (nested too deeply)") from None
    return _checked(d, p)


def _checked(d, p) -> dict:
    """`d` if it is a solution's dict (the keys export reads, well-formed), else a one-line
    error naming `p`."""
    missing = [k for k in ("q", "joint_names", "robot") if not isinstance(d, dict) or k not in d]
    if missing:
        raise SurestepError(f"{p}: not a solution file (missing key(s) {', '.join(missing)}; "
                            "written by `surestep solve --output` or `surestep compare`)")
    names, q = d["joint_names"], d["q"]
    if not isinstance(names, list) or not 1 <= len(names) <= MAX_JOINTS or not all(
            isinstance(n, str) and 0 < len(n) <= 200 for n in names) or \
            len(set(names)) != len(names):
        raise SurestepError(f"{p}: key 'joint_names' must list 1 to {MAX_JOINTS} distinct joint "
                            "names (strings)")
    if not isinstance(q, list) or len(q) < 2:
        raise SurestepError(f"{p}: key 'q' must list at least 2 waypoints")
    if len(q) > MAX_WAYPOINTS:
        raise SurestepError(f"{p}: key 'q' lists {len(q)} waypoints; at most {MAX_WAYPOINTS} are "
                            "exported")
    for i, qi in enumerate(q):
        if qi is None:
            raise SurestepError(f"{p}: q[{i}] is null (no IK solution for that waypoint); a plan "
                                "with an unreachable waypoint cannot be exported")
        if not isinstance(qi, list) or len(qi) != len(names) or not all(
                _in_range(v, -MAX_JOINT_VALUE, MAX_JOINT_VALUE) for v in qi):
            raise SurestepError(f"{p}: q[{i}] must be {len(names)} finite numbers within "
                                f"+-{MAX_JOINT_VALUE:g} ({shown(', '.join(names), 200)})")
    robot = d["robot"]
    if not isinstance(robot, dict) or not isinstance(robot.get("urdf"), str) or \
            not robot["urdf"] or \
            not isinstance(robot.get("frame", "tool"), (str, type(None))):
        raise SurestepError(f"{p}: key 'robot' must be a mapping with 'urdf' (a path) and "
                            "optionally 'frame' (a name)")
    for key in ("limits", "timing"):
        if d.get(key) is not None and not isinstance(d[key], dict):
            raise SurestepError(f"{p}: key '{key}' must be a mapping (as `surestep solve` writes "
                                "it)")
    limits = d.get("limits") or {}
    if limits and "velocity" not in limits and "unavailable" not in limits:
        raise SurestepError(f"{p}: key 'limits' is not the recorded form (joint_names, velocity, "
                            "acceleration, tool_speed_m_s, ...; as `surestep solve` writes it)")
    if "velocity" in limits:
        _check_recorded_limits(limits, p)
    step = (d.get("timing") or {}).get("step_s", DEFAULT_STEP_S)
    if not _in_range(step, *STEP_RANGE):
        raise SurestepError(f"{p}: timing.step_s must be a positive number of seconds, "
                            f"{_range_text(*STEP_RANGE)}, got {shown(repr(step), 40)}")
    return d


def _check_recorded_limits(limits: dict, p) -> None:
    """The recorded limits' numbers: finite and within the problem reader's ranges (a one-line
    error naming the key)."""
    names = limits.get("joint_names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise SurestepError(f"{p}: limits.joint_names must be a list of joint names (strings)")
    for key in ("velocity", "acceleration"):
        values = limits.get(key)
        if not isinstance(values, list) or len(values) != len(names):
            raise SurestepError(f"{p}: limits.{key} must list one number per joint of "
                                f"limits.joint_names ({len(names)})")
        for i, v in enumerate(values):
            if not _in_range(v, *LIMIT_RANGE):
                raise SurestepError(f"{p}: limits.{key}[{i}] ({shown(names[i], 40)}) must be "
                                    f"{_range_text(*LIMIT_RANGE)}, got {shown(repr(v), 40)}")
    for key, (lo, hi) in TOOL_RANGES.items():
        if not _in_range(limits.get(key), lo, hi):
            raise SurestepError(f"{p}: limits.{key} must be {_range_text(lo, hi)}, "
                                f"got {shown(repr(limits.get(key)), 40)}")


def step_of(sol: dict, override: float | None) -> tuple[float, str]:
    """Seconds per planned step and where that value came from."""
    if override is not None:
        if not _in_range(override, *STEP_RANGE):
            raise SurestepError("--step-s must be a positive number of "
                                f"seconds, {_range_text(*STEP_RANGE)}, got {override:g}")
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
            raise SurestepError(f"recorded limits are for joints {', '.join(base.joint_names)}, "
                                f"the plan's are {', '.join(names)}")
        base = base.overridden()  # a copy
        base.sources["recorded"] = "solution (the problem's limits: resolved when it was planned)"
    else:
        base = motion_limits(urdf, names)
        base.sources["recorded"] = "none: defaults (the solution records no limits)"
    for flag, over in (("--velocity-limit", velocity), ("--acceleration-limit", acceleration)):
        for n, x in (over or {}).items():
            if not _in_range(x, *LIMIT_RANGE):
                raise SurestepError(f"{flag} {shown(str(n), 40)}={x:g}: must "
                                    f"be {_range_text(*LIMIT_RANGE)}")
    for flag, x, key in (("--tool-speed", tool_speed, "tool_speed_m_s"),
                         ("--tool-rotation-speed", tool_rotation, "tool_rotation_rad_s")):
        if x is not None and not _in_range(x, *TOOL_RANGES[key]):
            raise SurestepError(f"{flag} must be {_range_text(*TOOL_RANGES[key])}, got {x:g}")
    return base.overridden(velocity, acceleration, tool_speed, tool_rotation, label=COMMAND_LINE)


def within_position_limits(q: np.ndarray, robot) -> tuple[np.ndarray, float]:
    """The waypoints clipped into the URDF's position limits, and by how much at most. A solver
    meets its bounds to a tolerance (IPOPT: about 1e-8 relative), a controller refuses a target
    beyond a limit; a waypoint further out than POSITION_TOL is an error."""
    lo, hi = robot.lower, robot.upper
    out = np.clip(q, lo, hi)
    excess = np.abs(out - q)
    tol = POSITION_TOL * np.maximum(1.0, np.abs(np.where(q < lo, lo, hi)))
    bad = np.argwhere(excess > tol)
    if len(bad):
        i, j = bad[0]
        raise SurestepError(f"q[{i}] {robot.joint_names[j]} = {q[i, j]:.6g} is beyond its position "
                            f"limits [{lo[j]:.6g}, {hi[j]:.6g}]")
    return out, float(excess.max())


