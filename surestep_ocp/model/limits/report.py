"""A plan measured against its motion limits at its planned pace, one step per `timing.step_s`.

- joint velocity `|q_t+1 - q_t| / step_s`;
- joint acceleration `|v_t - v_t-1| / step_s`, the plan starting and ending at rest;
- the tool's Cartesian speed, translation and rotation per step;
- the distance of the end of the shaft from the RCM (PSM only).

`plan_report` gives every violation as a `LimitsReport` (a solution's `motion_limits`, its file's
key of that name: `to_json` / `read_report`); `summary_row` and `markdown_rows` make the compare
table.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ...equality import ArrayEquality
from ...errors import SurestepError
from ...json_records import JsonRecord
from .values import RCM_FRAME, REL_TOL, MotionLimits, is_psm


@dataclass(frozen=True, kw_only=True)
class Violation(JsonRecord):
    """One step and quantity over its limit."""

    kind: str  # joint_velocity | joint_acceleration | tool_speed | tool_rotation | rcm_distance
    # velocities and tool speeds: the step t (t to t+1); accelerations, RCM distance: waypoint t
    step: int
    joint: str | None = None  # the joint (joint kinds only; no key otherwise)
    # signed for the joints; [rad/s or m/s, rad/s^2 or m/s^2, m/s, rad/s, m] by kind
    value: float
    limit: float  # the same unit; a minimum for rcm_distance


@dataclass(frozen=True)
class PlayedCurve(JsonRecord):
    """The peaks of the curve the robot plays through the waypoints at the planned pace
    (model/limits/retiming.py, `planned_curve`; recorded by `surestep compare`)."""

    curve: str  # its name (limits.CURVE_NAME)
    # joint_velocity, joint_acceleration, tool_speed, tool_rotation: peak / limit (None: the tool
    # not checked, the joints over already)
    peak_ratios: dict[str, float | None]
    within: bool  # every peak within its limit (to REL_TOL)


@dataclass(frozen=True, eq=False, kw_only=True)
class LimitsReport(ArrayEquality, JsonRecord):
    """A plan against its motion limits (`plan_report`), as a solution records it."""

    step_s: float  # [s] per step
    duration_s: float | None = None  # [s] step_s * T (None: a report written before it was)
    limits: MotionLimits  # the limits checked
    # per joint (limits.joint_names order): [rad/s or m/s], [rad/s^2 or m/s^2], then / the limit
    peak_joint_velocity: list[float]
    peak_joint_acceleration: list[float]
    velocity_ratio: list[float]
    acceleration_ratio: list[float]
    peak_tool_speed_m_s: float  # [m/s]
    peak_tool_rotation_rad_s: float  # [rad/s]
    min_rcm_distance_m: float | None  # [m]; None: not a PSM (written as null)
    tool_speed_per_step_m_s: list[float]  # [m/s] per step
    tool_rotation_per_step_rad_s: list[float]  # [rad/s] per step
    violations: list[Violation]
    ok: bool  # no violation
    enforced: bool | None = None  # True: made by `enforce` (`limits.enforce: true`)
    played_curve: PlayedCurve | None = None  # `surestep compare`'s

    @staticmethod
    def _readers() -> dict:
        return {"limits": _read_limits, "played_curve": PlayedCurve.from_json,
                "violations": lambda v: [Violation.from_json(x) for x in v]}

    def to_json(self) -> dict:
        d = super().to_json()
        d["limits"] = self.limits.to_dict()  # in its place
        return d


# why a plan with a waypoint without joints has no report
UNREACHABLE = "a waypoint has no IK solution (see reachability)"


@dataclass(frozen=True)
class SkippedReport(JsonRecord):
    """A report that could not be made (a waypoint without joints)."""

    skipped: str  # why
    ok: bool | None = None  # False when the limits are enforced
    enforced: bool | None = None  # True: made by `enforce`


def _read_limits(d: dict) -> MotionLimits:
    """The recorded limits; malformed ones, or other keys than `MotionLimits.to_dict` writes, are a
    ValueError like any record's (nothing of the file dropped unread)."""
    try:
        limits = MotionLimits.from_dict(d)
    except SurestepError as exc:
        raise ValueError(str(exc)) from None
    if set(d) != set(limits.to_dict()):
        raise ValueError(f"recorded limits: keys {sorted(d)}")
    return limits


def read_report(d: dict) -> LimitsReport | SkippedReport:
    """A solution file's `motion_limits` as its record; a mapping of neither shape is a
    ValueError, TypeError or KeyError."""
    return (SkippedReport if "skipped" in d else LimitsReport).from_json(d)


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle [rad] of Ra^T Rb."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def plan_report(robot, q: np.ndarray, step_s: float, limits: MotionLimits,
                tool_frame: str | None = None) -> LimitsReport:
    """Every limit violation of the joint plan `q` ((T+1, nq), robot joint order) at one step per
    `step_s`.

    `robot` is a `surestep_ocp.model.robot.Robot`; the tool is its `tool_frame` (default: its
    tracked frame, without a needle offset). Returns the `LimitsReport`: per-joint peak velocity
    and acceleration and their ratio to the limit, the tool's peak speeds, the minimum RCM distance
    (PSM only), `violations` (one per step and quantity over its limit) and `ok`.
    """
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[1] != len(limits.joint_names):
        raise SurestepError(f"plan of shape {q.shape} does not match the "
                            f"{len(limits.joint_names)} joints {', '.join(limits.joint_names)}")
    vel = np.diff(q, axis=0) / step_s  # (T, nq): velocity over step t
    # at rest before and after
    padded = np.vstack([np.zeros((1, q.shape[1])), vel, np.zeros((1, q.shape[1]))])
    acc = np.diff(padded, axis=0) / step_s  # (T+1, nq): at waypoint t
    frame = tool_frame or robot.frame
    poses = [robot.frame_pose(qi, frame) for qi in q]
    pairs = list(itertools.pairwise(poses))
    dp = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in pairs]) / step_s
    dr = np.array([rotation_angle(a[:3, :3], b[:3, :3]) for a, b in pairs]) / step_s
    violations = []
    for kind, values, lim in (("joint_velocity", vel, limits.velocity), ("joint_acceleration", acc,
                                                                       limits.acceleration)):
        over = np.argwhere(np.abs(values) > lim * (1 + REL_TOL))
        for t, j in over:
            violations.append(Violation(kind=kind, step=int(t), joint=limits.joint_names[j],
                                        value=float(values[t, j]), limit=float(lim[j])))
    for kind, values, lim in (("tool_speed", dp, limits.tool_speed),
                              ("tool_rotation", dr, limits.tool_rotation)):
        for t in np.flatnonzero(values > lim * (1 + REL_TOL)):
            violations.append(Violation(kind=kind, step=int(t), value=float(values[t]),
                                        limit=float(lim)))
    rcm = None
    if is_psm(robot):
        dist = np.array([np.linalg.norm(robot.frame_pose(qi, RCM_FRAME)[:3, 3]) for qi in q])
        rcm = float(dist.min())
        for t in np.flatnonzero(dist < limits.rcm_min_distance * (1 - REL_TOL)):
            violations.append(Violation(kind="rcm_distance", step=int(t), value=float(dist[t]),
                                        limit=float(limits.rcm_min_distance)))
    peak_v, peak_a = np.abs(vel).max(axis=0), np.abs(acc).max(axis=0)
    return LimitsReport(
        step_s=float(step_s),
        duration_s=float(step_s) * (len(q) - 1),
        limits=limits,
        peak_joint_velocity=peak_v.tolist(),
        peak_joint_acceleration=peak_a.tolist(),
        velocity_ratio=(peak_v / limits.velocity).tolist(),
        acceleration_ratio=(peak_a / limits.acceleration).tolist(),
        peak_tool_speed_m_s=float(dp.max()) if len(dp) else 0.0,
        peak_tool_rotation_rad_s=float(dr.max()) if len(dr) else 0.0,
        min_rcm_distance_m=rcm,
        tool_speed_per_step_m_s=dp.tolist(),
        tool_rotation_per_step_rad_s=dr.tolist(),
        violations=violations,
        ok=not violations,
    )


def summary_row(method: str, report: LimitsReport) -> dict:
    """One row of the compare table: worst ratios and their joints, tool speeds, RCM distance,
    count."""
    names, lim = report.limits.joint_names, report.limits
    jv, ja = int(np.argmax(report.velocity_ratio)), int(np.argmax(report.acceleration_ratio))
    rcm = report.min_rcm_distance_m
    return {
        "method": method,
        "max velocity / limit": f"{report.velocity_ratio[jv]:.2f} ({names[jv]})",
        "max accel. / limit": f"{report.acceleration_ratio[ja]:.1f} ({names[ja]})",
        "tool speed [mm/s]": f"{1e3 * report.peak_tool_speed_m_s:.0f} / "
                             f"{1e3 * lim.tool_speed:.0f}",
        "tool rotation [rad/s]": f"{report.peak_tool_rotation_rad_s:.2f} / "
                                 f"{lim.tool_rotation:.2f}",
        "min RCM distance [mm]": "-" if rcm is None else
                                 f"{1e3 * rcm:.1f} / {1e3 * lim.rcm_min_distance:.0f}",
        "duration [s]": "-" if report.duration_s is None else f"{report.duration_s:.2f}",
        "violations": str(len(report.violations)),
        "played curve: peak / limit": played_peak(report),
    }


def played_peak(report: LimitsReport) -> str:
    """The largest peak ratio of the played curve (`played_curve`, recorded by `surestep compare`)
    and its kind: "3.42 (joint_acceleration)"; "-" when not recorded."""
    played = report.played_curve
    peaks = {k: v for k, v in ({} if played is None else played.peak_ratios).items()
             if v is not None}
    if not peaks:
        return "-"
    kind = max(peaks, key=peaks.get)
    return f"{peaks[kind]:.2f} ({kind})"


def worst_violations(report: LimitsReport | SkippedReport) -> str:
    """Per kind of violation in `report`, how far the worst goes past its limit: "joint_acceleration
    3.1x the limit (yaw, step 0)"; the RCM distance as a fraction of its minimum."""
    if isinstance(report, SkippedReport):
        return f"not checked: {report.skipped}"
    out = []
    violations = report.violations
    for kind in sorted({v.kind for v in violations}):
        vs = [v for v in violations if v.kind == kind]
        if kind == "rcm_distance":
            v = min(vs, key=lambda v: v.value / v.limit)
            out.append(f"{kind} {v.value / v.limit:.2f} of the minimum (step {v.step})")
            continue
        v = max(vs, key=lambda v: abs(v.value) / v.limit)
        where = "" if v.joint is None else f"{v.joint}, "
        out.append(f"{kind} {abs(v.value) / v.limit:.2f}x the limit ({where}step {v.step})")
    if played_peak(report) != "-":
        out.append(f"the played curve's peak {played_peak(report).replace(' (', 'x the limit (')}")
    return "; ".join(out)


def markdown_rows(rows: list[dict]) -> str:
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(r[k] for k in keys) + " |" for r in rows]
    return "\n".join(lines)

