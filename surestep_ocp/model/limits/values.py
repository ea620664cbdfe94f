"""The motion limits themselves: defaults, `MotionLimits`, the URDF's velocities, overrides.

- joint velocity: the URDF's `<limit velocity=...>`;
- joint acceleration: `DEFAULT_ACCELERATION` (the dVRK's own `move_jp` trajectory limits);
- the tool's Cartesian speed, translation and rotation: `TOOL_SPEED_M_S` and `TOOL_ROTATION_RAD_S`
  (chosen defaults);
- the distance of the end of the instrument shaft (the wrist-pitch axis, PSM frame `roll_link`)
  from the remote centre of motion (the PSM's URDF root), at least `RCM_MIN_DISTANCE_M` = 45 mm
  (saw `SafeDistanceFromRCM`, ../shared/reference/dvrk_kinematics.md section 1c), for the PSM only.

Each is overridable (a problem's `limits:` section, the command line's `NAME=VALUE` pairs); a
`MotionLimits` records where each of its values came from (`sources`).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import SurestepError
from ...status import Status

# [rad/s^2, m/s^2] the dVRK's move_jp trajectory acceleration limits (sawIntuitiveResearchKit,
# core/components/code/mtsIntuitiveResearchKitPSM.cpp, Init: a_max 90 deg/s^2 for yaw and pitch,
# 0.2 m/s^2 for the insertion, 2 x 360 deg/s^2 for the last four joints). Other robots' joints:
# DEFAULT_ACCEL_PER_VELOCITY times their velocity limit (full speed in 0.5 s).
DEFAULT_ACCELERATION = {"yaw": math.pi / 2, "pitch": math.pi / 2, "insertion": 0.2,
                        "roll": 4 * math.pi, "wrist_pitch": 4 * math.pi, "wrist_yaw": 4 * math.pi,
                        "jaw": 4 * math.pi}
DEFAULT_ACCEL_PER_VELOCITY = 2.0  # [1/s]
TOOL_SPEED_M_S = 0.1  # [m/s] chosen (no public dVRK Cartesian speed limit was found): 10 cm/s
TOOL_ROTATION_RAD_S = math.pi / 2  # [rad/s] chosen: the dVRK's move_jp yaw/pitch velocity, 90 deg/s
RCM_MIN_DISTANCE_M = 0.045  # [m] saw SafeDistanceFromRCM (reference section 1c)
RCM_FRAME = "roll_link"  # PSM DH frame 4: the end of the shaft (wrist-pitch axis)
RCM_ROOT = "psm_rcm"  # the PSM URDF's root link, centred on the RCM
JAW = "jaw"
INSERTION = "insertion"  # the PSM's prismatic joint along the shaft (through the RCM)
# a value counts as over its limit beyond limit * (1 + REL_TOL) (IPOPT meets bounds to ~1e-8)
REL_TOL = 1e-6
VIOLATED = Status.MOTION_LIMITS_VIOLATED
PROBLEM_SOURCE = "problem file"  # the source of a limit set by the problem's `limits:` section


# (path, mtime) -> limits: every solution records them
_URDF_VELOCITIES: dict[tuple[str, int], dict[str, float]] = {}


def urdf_velocity_limits(urdf: str | Path) -> dict[str, float]:
    """`<limit velocity=...>` of every revolute, prismatic or continuous joint of a URDF, by joint
    name."""
    try:
        key = (str(Path(urdf).resolve()), Path(urdf).stat().st_mtime_ns)
        if key in _URDF_VELOCITIES:
            return dict(_URDF_VELOCITIES[key])
        root = ET.parse(str(urdf)).getroot()
    except (OSError, ET.ParseError) as exc:
        raise SurestepError(f"{urdf}: cannot read the URDF's velocity limits ({exc})") from None
    out = {}
    for j in root.iter("joint"):
        if j.get("type") in ("revolute", "prismatic", "continuous"):
            lim = j.find("limit")
            if lim is not None and lim.get("velocity") is not None:
                out[j.get("name")] = float(lim.get("velocity"))
    _URDF_VELOCITIES[key] = out
    return dict(out)


@dataclass(frozen=True)
class MotionLimits:
    """Per-joint velocity and acceleration limits (joint order of the plan) and the tool/RCM limits.
    """

    joint_names: tuple[str, ...]
    velocity: np.ndarray  # [rad/s or m/s]
    acceleration: np.ndarray  # [rad/s^2 or m/s^2]
    tool_speed: float = TOOL_SPEED_M_S
    tool_rotation: float = TOOL_ROTATION_RAD_S
    rcm_min_distance: float = RCM_MIN_DISTANCE_M
    sources: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"joint_names": list(self.joint_names), "velocity": self.velocity.tolist(),
                "acceleration": self.acceleration.tolist(), "tool_speed_m_s": self.tool_speed,
                "tool_rotation_rad_s": self.tool_rotation,
                "rcm_min_distance_m": self.rcm_min_distance,
                "sources": dict(self.sources)}

    @classmethod
    def from_dict(cls, d: dict) -> MotionLimits:
        """The limits `to_dict` wrote (a solution's recorded `limits`); a malformed one is a
        SurestepError."""
        try:
            names = tuple(str(n) for n in d["joint_names"])
            v, a = np.array(d["velocity"], float), np.array(d["acceleration"], float)
            tool = [float(d[k])
                    for k in ("tool_speed_m_s", "tool_rotation_rad_s", "rcm_min_distance_m")]
        except (KeyError, TypeError, ValueError) as exc:
            raise SurestepError(f"malformed recorded limits ({exc.__class__.__name__}: {exc})") \
                from None
        if v.shape != (len(names),) or a.shape != v.shape or not (np.all(v > 0) and np.all(a > 0)) \
                or not all(math.isfinite(x) and x > 0 for x in tool):
            raise SurestepError("malformed recorded limits (one positive velocity and acceleration "
                                "per joint, positive tool speeds and RCM distance)")
        return cls(names, v, a, *tool, sources=dict(d.get("sources") or {}))

    def overridden(self, velocity: dict[str, float] | None = None,
                   acceleration: dict[str, float] | None = None, tool_speed: float | None = None,
                   tool_rotation: float | None = None, label: str = "override") -> MotionLimits:
        """These limits with the given per-joint and tool overrides, their sources marked `label`.
        """
        names = list(self.joint_names)
        _check_names(names, velocity, acceleration)
        src = {k: dict(v) if isinstance(v, dict) else v for k, v in self.sources.items()}
        vel, acc = self.velocity.copy(), self.acceleration.copy()
        for key, over, arr in (("velocity", velocity, vel), ("acceleration", acceleration, acc)):
            for n, x in (over or {}).items():
                arr[names.index(n)] = x
                src.setdefault(key, {})[n] = label
        out = {}
        for key, x in (("tool_speed", tool_speed), ("tool_rotation", tool_rotation)):
            if x is not None:
                out[key] = x
                src[key] = label
        return MotionLimits(self.joint_names, vel, acc, out.get("tool_speed", self.tool_speed),
                            out.get("tool_rotation", self.tool_rotation), self.rcm_min_distance,
                            sources=src)


def parse_overrides(items: list[str] | None, what: str) -> dict[str, float]:
    """`NAME=VALUE` pairs from the command line; a bad one is a one-line error naming it."""
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not sep or not name or not np.isfinite(v) or v <= 0:
            raise SurestepError(f"{what} '{item}': expected JOINT=VALUE with a positive number, "
                                "e.g. yaw=1.0")
        out[name] = v
    return out


def _check_names(names: list[str], velocity: dict | None, acceleration: dict | None) -> None:
    for label, over in (("velocity", velocity), ("acceleration", acceleration)):
        unknown = sorted(set(over or {}) - set(names))
        if unknown:
            raise SurestepError(f"{label} limit for unknown joint(s) {', '.join(unknown)}; "
                                f"allowed: {', '.join(names)}")


def motion_limits(urdf: str | Path, joint_names: list[str],
                  velocity: dict[str, float] | None = None,
                  acceleration: dict[str, float] | None = None, tool_speed: float | None = None,
                  tool_rotation: float | None = None, rcm_min_distance: float | None = None,
                  label: str = "override") -> MotionLimits:
    """The limits for a plan of `joint_names`: the URDF's velocities and the default accelerations,
    with the given overrides (by joint name; their sources marked `label`). Unknown override names
    are an error listing the joints."""
    names = list(joint_names)
    _check_names(names, velocity, acceleration)
    urdf_v = urdf_velocity_limits(urdf)
    dvrk = set(names) <= set(DEFAULT_ACCELERATION)  # the PSM's joints: the dVRK's own defaults
    v, a, src_v, src_a = [], [], {}, {}
    for n in names:
        if velocity and n in velocity:
            v.append(velocity[n])
            src_v[n] = label
        elif n in urdf_v and urdf_v[n] > 0:
            v.append(urdf_v[n])
            src_v[n] = "urdf"
        else:
            raise SurestepError(f"{urdf}: joint '{n}' has no positive <limit velocity=...>; "
                                f"give one (--velocity-limit {n}=VALUE)")
        if acceleration and n in acceleration:
            a.append(acceleration[n])
            src_a[n] = label
        elif dvrk:
            a.append(DEFAULT_ACCELERATION[n])
            src_a[n] = "dVRK move_jp default"
        else:
            a.append(DEFAULT_ACCEL_PER_VELOCITY * v[-1])
            src_a[n] = f"{DEFAULT_ACCEL_PER_VELOCITY:g}/s x velocity limit"
    src = {"velocity": src_v, "acceleration": src_a}
    for key, x in (("tool_speed", tool_speed), ("tool_rotation", tool_rotation),
                   ("rcm_min_distance", rcm_min_distance)):
        src[key] = "default" if x is None else label
    return MotionLimits(tuple(names), np.array(v), np.array(a),
                        TOOL_SPEED_M_S if tool_speed is None else tool_speed,
                        TOOL_ROTATION_RAD_S if tool_rotation is None else tool_rotation,
                        RCM_MIN_DISTANCE_M if rcm_min_distance is None else rcm_min_distance,
                        sources=src)


def is_psm(robot) -> bool:
    """A dVRK PSM: the URDF's root is the RCM and the shaft's end frame exists (the RCM distance
    applies)."""
    return RCM_FRAME in robot.frame_names and robot.model.frames[1].name == RCM_ROOT


def problem_limits(setup) -> MotionLimits:
    """The limits of a Setup's plan: the defaults with the problem file's `limits:` overrides."""
    spec = setup.ocp.limits
    return motion_limits(setup.robot.urdf, setup.robot.joint_names, dict(spec.joint_velocity),
                         dict(spec.joint_acceleration), spec.tool_speed, spec.tool_rotation_speed,
                         spec.rcm_distance, label=PROBLEM_SOURCE)


def recorded_limits(setup) -> dict:
    """What a solution file records of the limits it was planned with (key `limits`, read by
    `surestep export`): `enforce` and the resolved limits with their sources; for a robot without
    URDF velocity limits, `enforce` and the reason instead."""
    try:
        return {"enforce": bool(setup.ocp.limits.enforce), **problem_limits(setup).to_dict()}
    except SurestepError as exc:
        return {"enforce": bool(setup.ocp.limits.enforce), "unavailable": str(exc)}


def rcm_insertion_bound(robot, rcm_min_distance: float) -> tuple[int, float] | None:
    """(index of the insertion joint, its lower bound) that keeps the end of the shaft
    `rcm_min_distance` from the RCM; None if the robot is not a PSM.

    Derivation: yaw and pitch rotate about the RCM and the insertion joint translates along the
    shaft, whose axis passes through the RCM; roll turns about that axis. So the shaft's end (frame
    `roll_link`, the wrist pitch axis) lies on the axis at the signed distance `s(q) = q_insertion +
    s_0` from the RCM, whatever the other joints (`s_0` = -0.0156 m for the Classic LND, reference
    section 1c: the wrist-pitch axis is at `q3 - 0.0156`), and `|s| >= d` on the branch the
    insertion limits allow (s > 0) is `q_insertion >= d - s_0`. `s_0` is read from the robot's own
    kinematics (FK at two insertions) and the linearity is checked."""
    if not is_psm(robot) or INSERTION not in robot.joint_names:
        return None
    j = robot.joint_names.index(INSERTION)
    q = np.clip(np.zeros(robot.nq), robot.lower, robot.upper)
    pts = []
    for ins in (robot.lower[j], robot.upper[j]):
        q[j] = ins
        pts.append(robot.frame_pose(q, RCM_FRAME)[:3, 3])
    axis = (pts[1] - pts[0]) / (robot.upper[j] - robot.lower[j])
    if abs(np.linalg.norm(axis) - 1) > 1e-9 or np.linalg.norm(np.cross(pts[0], axis)) > 1e-9:
        raise SurestepError(f"{robot.urdf}: the insertion joint does not move the shaft's end "
                            "along a line through the RCM; the RCM distance cannot be a bound on "
                            "the insertion")
    s0 = float(np.dot(pts[0], axis)) - robot.lower[j]
    return j, rcm_min_distance - s0


def joint_bounds(robot, rcm_min_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of every joint within enforced limits: the URDF's, the PSM's insertion raised
    to `rcm_insertion_bound` (kept within its own range)."""
    lower, upper = np.array(robot.lower, float), np.array(robot.upper, float)
    rcm = rcm_insertion_bound(robot, rcm_min_distance)
    if rcm is not None:
        lower[rcm[0]] = min(max(lower[rcm[0]], rcm[1]), upper[rcm[0]])
    return lower, upper

