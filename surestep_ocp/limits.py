"""Motion limits of a plan: what a dVRK would refuse or struggle with, REPORTED (not enforced).

The planners do not honour these limits (issue 14: the solvers are another piece of work); this
module measures a plan against them at its planned pace, one step per `timing.step_s`:

- joint velocity `|q_t+1 - q_t| / step_s` against the URDF's `<limit velocity=...>`;
- joint acceleration `|v_t - v_t-1| / step_s`, the plan starting and ending at rest, against
  `DEFAULT_ACCELERATION` (the dVRK's own `move_jp` trajectory limits; overridable);
- the tool's Cartesian speed, translation and rotation per step, against `TOOL_SPEED_M_S` and
  `TOOL_ROTATION_RAD_S` (chosen defaults, overridable);
- the distance of the end of the instrument shaft (the wrist-pitch axis, PSM frame `roll_link`)
  from the remote centre of motion (the PSM's URDF root), at least `RCM_MIN_DISTANCE_M` = 45 mm
  (saw `SafeDistanceFromRCM`, ../shared/reference/dvrk_kinematics.md section 1c), for the PSM only.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import SurestepError

# [rad/s^2, m/s^2] the dVRK's move_jp trajectory acceleration limits (sawIntuitiveResearchKit,
# core/components/code/mtsIntuitiveResearchKitPSM.cpp, Init: a_max 90 deg/s^2 for yaw and pitch,
# 0.2 m/s^2 for the insertion, 2 x 360 deg/s^2 for the last four joints). Other robots' joints:
# DEFAULT_ACCEL_PER_VELOCITY times their velocity limit (full speed in 0.5 s).
DEFAULT_ACCELERATION = {"yaw": math.pi / 2, "pitch": math.pi / 2, "insertion": 0.2, "roll": 4 * math.pi,
                        "wrist_pitch": 4 * math.pi, "wrist_yaw": 4 * math.pi, "jaw": 4 * math.pi}
DEFAULT_ACCEL_PER_VELOCITY = 2.0  # [1/s]
TOOL_SPEED_M_S = 0.1  # [m/s] chosen (no public dVRK Cartesian speed limit was found): 10 cm/s
TOOL_ROTATION_RAD_S = math.pi / 2  # [rad/s] chosen: the dVRK's move_jp yaw/pitch velocity, 90 deg/s
RCM_MIN_DISTANCE_M = 0.045  # [m] saw SafeDistanceFromRCM (reference section 1c)
RCM_FRAME = "roll_link"  # PSM DH frame 4: the end of the shaft (wrist-pitch axis)
RCM_ROOT = "psm_rcm"  # the PSM URDF's root link, centred on the RCM
JAW = "jaw"


def urdf_velocity_limits(urdf: str | Path) -> dict[str, float]:
    """`<limit velocity=...>` of every revolute, prismatic or continuous joint of a URDF, by joint name."""
    try:
        root = ET.parse(str(urdf)).getroot()
    except (OSError, ET.ParseError) as exc:
        raise SurestepError(f"{urdf}: cannot read the URDF's velocity limits ({exc})") from None
    out = {}
    for j in root.iter("joint"):
        if j.get("type") in ("revolute", "prismatic", "continuous"):
            lim = j.find("limit")
            if lim is not None and lim.get("velocity") is not None:
                out[j.get("name")] = float(lim.get("velocity"))
    return out


@dataclass(frozen=True)
class MotionLimits:
    """Per-joint velocity and acceleration limits (joint order of the plan) and the tool/RCM limits."""

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
                "tool_rotation_rad_s": self.tool_rotation, "rcm_min_distance_m": self.rcm_min_distance,
                "sources": dict(self.sources)}


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
            raise SurestepError(f"{what} '{item}': expected JOINT=VALUE with a positive number, e.g. yaw=1.0")
        out[name] = v
    return out


def motion_limits(urdf: str | Path, joint_names: list[str], velocity: dict[str, float] | None = None,
                  acceleration: dict[str, float] | None = None, tool_speed: float | None = None,
                  tool_rotation: float | None = None) -> MotionLimits:
    """The limits for a plan of `joint_names`: the URDF's velocities and the default accelerations,
    with the given overrides (by joint name). Unknown override names are an error listing the joints."""
    names = list(joint_names)
    for label, over in (("velocity", velocity), ("acceleration", acceleration)):
        unknown = sorted(set(over or {}) - set(names))
        if unknown:
            raise SurestepError(f"{label} limit for unknown joint(s) {', '.join(unknown)}; "
                                f"allowed: {', '.join(names)}")
    urdf_v = urdf_velocity_limits(urdf)
    dvrk = set(names) <= set(DEFAULT_ACCELERATION)  # the PSM's joints: the dVRK's own defaults
    v, a, src_v, src_a = [], [], {}, {}
    for n in names:
        if velocity and n in velocity:
            v.append(velocity[n])
            src_v[n] = "override"
        elif n in urdf_v and urdf_v[n] > 0:
            v.append(urdf_v[n])
            src_v[n] = "urdf"
        else:
            raise SurestepError(f"{urdf}: joint '{n}' has no positive <limit velocity=...>; give one "
                                f"(--velocity-limit {n}=VALUE)")
        if acceleration and n in acceleration:
            a.append(acceleration[n])
            src_a[n] = "override"
        elif dvrk:
            a.append(DEFAULT_ACCELERATION[n])
            src_a[n] = "dVRK move_jp default"
        else:
            a.append(DEFAULT_ACCEL_PER_VELOCITY * v[-1])
            src_a[n] = f"{DEFAULT_ACCEL_PER_VELOCITY:g}/s x velocity limit"
    return MotionLimits(tuple(names), np.array(v), np.array(a),
                        TOOL_SPEED_M_S if tool_speed is None else tool_speed,
                        TOOL_ROTATION_RAD_S if tool_rotation is None else tool_rotation,
                        sources={"velocity": src_v, "acceleration": src_a})


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle [rad] of Ra^T Rb."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def plan_report(robot, q: np.ndarray, step_s: float, limits: MotionLimits, tool_frame: str | None = None) -> dict:
    """Every limit violation of the joint plan `q` ((T+1, nq), robot joint order) at one step per `step_s`.

    `robot` is a `surestep_ocp.robot.Robot`; the tool is its `tool_frame` (default: its tracked frame,
    without a needle offset). Returns a JSON-ready dict: per-joint peak velocity and acceleration and
    their ratio to the limit, the tool's peak speeds, the minimum RCM distance (PSM only), `violations`
    (one entry per step and quantity over its limit) and `ok`.
    """
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[1] != len(limits.joint_names):
        raise SurestepError(f"plan of shape {q.shape} does not match the {len(limits.joint_names)} joints "
                            f"{', '.join(limits.joint_names)}")
    vel = np.diff(q, axis=0) / step_s  # (T, nq): velocity over step t
    padded = np.vstack([np.zeros((1, q.shape[1])), vel, np.zeros((1, q.shape[1]))])  # at rest before and after
    acc = np.diff(padded, axis=0) / step_s  # (T+1, nq): at waypoint t
    frame = tool_frame or robot.frame
    poses = [robot.frame_pose(qi, frame) for qi in q]
    dp = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(poses, poses[1:])]) / step_s
    dr = np.array([rotation_angle(a[:3, :3], b[:3, :3]) for a, b in zip(poses, poses[1:])]) / step_s
    violations = []
    for kind, values, lim in (("joint_velocity", vel, limits.velocity), ("joint_acceleration", acc,
                                                                       limits.acceleration)):
        over = np.argwhere(np.abs(values) > lim * (1 + 1e-9))
        for t, j in over:
            violations.append({"kind": kind, "step": int(t), "joint": limits.joint_names[j],
                               "value": float(values[t, j]), "limit": float(lim[j])})
    for kind, values, lim in (("tool_speed", dp, limits.tool_speed), ("tool_rotation", dr, limits.tool_rotation)):
        for t in np.flatnonzero(values > lim * (1 + 1e-9)):
            violations.append({"kind": kind, "step": int(t), "value": float(values[t]), "limit": float(lim)})
    rcm = None
    if RCM_FRAME in robot.frame_names and robot.model.frames[1].name == RCM_ROOT:
        dist = np.array([np.linalg.norm(robot.frame_pose(qi, RCM_FRAME)[:3, 3]) for qi in q])
        rcm = float(dist.min())
        for t in np.flatnonzero(dist < limits.rcm_min_distance - 1e-12):
            violations.append({"kind": "rcm_distance", "step": int(t), "value": float(dist[t]),
                               "limit": float(limits.rcm_min_distance)})
    peak_v, peak_a = np.abs(vel).max(axis=0), np.abs(acc).max(axis=0)
    return {
        "step_s": float(step_s),
        "limits": limits.to_dict(),
        "peak_joint_velocity": peak_v.tolist(),
        "peak_joint_acceleration": peak_a.tolist(),
        "velocity_ratio": (peak_v / limits.velocity).tolist(),
        "acceleration_ratio": (peak_a / limits.acceleration).tolist(),
        "peak_tool_speed_m_s": float(dp.max()) if len(dp) else 0.0,
        "peak_tool_rotation_rad_s": float(dr.max()) if len(dr) else 0.0,
        "min_rcm_distance_m": rcm,
        "tool_speed_per_step_m_s": dp.tolist(),
        "tool_rotation_per_step_rad_s": dr.tolist(),
        "violations": violations,
        "ok": not violations,
    }


def summary_row(method: str, report: dict) -> dict:
    """One row of the compare table: worst ratios and their joints, tool speeds, RCM distance, count."""
    names = report["limits"]["joint_names"]
    jv, ja = int(np.argmax(report["velocity_ratio"])), int(np.argmax(report["acceleration_ratio"]))
    rcm = report["min_rcm_distance_m"]
    return {
        "method": method,
        "max velocity / limit": f"{report['velocity_ratio'][jv]:.2f} ({names[jv]})",
        "max accel. / limit": f"{report['acceleration_ratio'][ja]:.1f} ({names[ja]})",
        "tool speed [mm/s]": f"{1e3 * report['peak_tool_speed_m_s']:.0f} / "
                             f"{1e3 * report['limits']['tool_speed_m_s']:.0f}",
        "tool rotation [rad/s]": f"{report['peak_tool_rotation_rad_s']:.2f} / "
                                 f"{report['limits']['tool_rotation_rad_s']:.2f}",
        "min RCM distance [mm]": "-" if rcm is None else
                                 f"{1e3 * rcm:.1f} / {1e3 * report['limits']['rcm_min_distance_m']:.0f}",
        "violations": str(len(report["violations"])),
    }


def markdown_rows(rows: list[dict]) -> str:
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(r[k] for k in keys) + " |" for r in rows]
    return "\n".join(lines)
