"""Motion limits of a plan: what a dVRK would refuse or struggle with; reported, and enforced on request.

A problem's `limits:` section (problems/README.md, "Motion limits") gives overrides; with
`limits.enforce: true` the OCP (IPOPT's condensed transcription) carries them as constraints, and
every method's plan that breaks one is not a success (`enforce`, status `Motion_Limits_Violated`).
This module measures a plan against them at its planned pace, one step per `timing.step_s`:

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

from ..errors import SurestepError

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
INSERTION = "insertion"  # the PSM's prismatic joint along the shaft (through the RCM)
REL_TOL = 1e-6  # a value counts as over its limit beyond limit * (1 + REL_TOL) (IPOPT meets bounds to ~1e-8)
VIOLATED = "Motion_Limits_Violated"
PROBLEM_SOURCE = "problem file"  # the source of a limit set by the problem's `limits:` section


_URDF_VELOCITIES: dict[tuple[str, int], dict[str, float]] = {}  # (path, mtime) -> limits: every solution records them


def urdf_velocity_limits(urdf: str | Path) -> dict[str, float]:
    """`<limit velocity=...>` of every revolute, prismatic or continuous joint of a URDF, by joint name."""
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

    @classmethod
    def from_dict(cls, d: dict) -> MotionLimits:
        """The limits `to_dict` wrote (a solution's recorded `limits`); a malformed one is a SurestepError."""
        try:
            names = tuple(str(n) for n in d["joint_names"])
            v, a = np.array(d["velocity"], float), np.array(d["acceleration"], float)
            tool = [float(d[k]) for k in ("tool_speed_m_s", "tool_rotation_rad_s", "rcm_min_distance_m")]
        except (KeyError, TypeError, ValueError) as exc:
            raise SurestepError(f"malformed recorded limits ({exc.__class__.__name__}: {exc})") from None
        if v.shape != (len(names),) or a.shape != v.shape or not (np.all(v > 0) and np.all(a > 0)) \
                or not all(math.isfinite(x) and x > 0 for x in tool):
            raise SurestepError("malformed recorded limits (one positive velocity and acceleration per joint, "
                                "positive tool speeds and RCM distance)")
        return cls(names, v, a, *tool, sources=dict(d.get("sources") or {}))

    def overridden(self, velocity: dict[str, float] | None = None, acceleration: dict[str, float] | None = None,
                   tool_speed: float | None = None, tool_rotation: float | None = None,
                   label: str = "override") -> MotionLimits:
        """These limits with the given per-joint and tool overrides, their sources marked `label`."""
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
                            out.get("tool_rotation", self.tool_rotation), self.rcm_min_distance, sources=src)


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


def _check_names(names: list[str], velocity: dict | None, acceleration: dict | None) -> None:
    for label, over in (("velocity", velocity), ("acceleration", acceleration)):
        unknown = sorted(set(over or {}) - set(names))
        if unknown:
            raise SurestepError(f"{label} limit for unknown joint(s) {', '.join(unknown)}; "
                                f"allowed: {', '.join(names)}")


def motion_limits(urdf: str | Path, joint_names: list[str], velocity: dict[str, float] | None = None,
                  acceleration: dict[str, float] | None = None, tool_speed: float | None = None,
                  tool_rotation: float | None = None, rcm_min_distance: float | None = None,
                  label: str = "override") -> MotionLimits:
    """The limits for a plan of `joint_names`: the URDF's velocities and the default accelerations,
    with the given overrides (by joint name; their sources marked `label`). Unknown override names are
    an error listing the joints."""
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
            raise SurestepError(f"{urdf}: joint '{n}' has no positive <limit velocity=...>; give one "
                                f"(--velocity-limit {n}=VALUE)")
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
    for key, x in (("tool_speed", tool_speed), ("tool_rotation", tool_rotation), ("rcm_min_distance", rcm_min_distance)):
        src[key] = "default" if x is None else label
    return MotionLimits(tuple(names), np.array(v), np.array(a),
                        TOOL_SPEED_M_S if tool_speed is None else tool_speed,
                        TOOL_ROTATION_RAD_S if tool_rotation is None else tool_rotation,
                        RCM_MIN_DISTANCE_M if rcm_min_distance is None else rcm_min_distance,
                        sources=src)


def is_psm(robot) -> bool:
    """A dVRK PSM: the URDF's root is the RCM and the shaft's end frame exists (the RCM distance applies)."""
    return RCM_FRAME in robot.frame_names and robot.model.frames[1].name == RCM_ROOT


def problem_limits(setup) -> MotionLimits:
    """The limits of a Setup's plan: the defaults with the problem file's `limits:` overrides."""
    spec = setup.problem.limits
    return motion_limits(setup.robot.urdf, setup.robot.joint_names, dict(spec.joint_velocity),
                         dict(spec.joint_acceleration), spec.tool_speed, spec.tool_rotation_speed, spec.rcm_distance,
                         label=PROBLEM_SOURCE)


def recorded_limits(setup) -> dict:
    """What a solution file records of the limits it was planned with (key `limits`, read by `surestep
    export`): `enforce` and the resolved limits with their sources; for a robot without URDF velocity
    limits, `enforce` and the reason instead."""
    try:
        return {"enforce": bool(setup.problem.limits.enforce), **problem_limits(setup).to_dict()}
    except SurestepError as exc:
        return {"enforce": bool(setup.problem.limits.enforce), "unavailable": str(exc)}


def rcm_insertion_bound(robot, rcm_min_distance: float) -> tuple[int, float] | None:
    """(index of the insertion joint, its lower bound) that keeps the end of the shaft `rcm_min_distance` from
    the RCM; None if the robot is not a PSM.

    Derivation: yaw and pitch rotate about the RCM and the insertion joint translates along the shaft, whose
    axis passes through the RCM; roll turns about that axis. So the shaft's end (frame `roll_link`, the wrist
    pitch axis) lies on the axis at the signed distance `s(q) = q_insertion + s_0` from the RCM, whatever the
    other joints (`s_0` = -0.0156 m for the Classic LND, reference section 1c: the wrist-pitch axis is at
    `q3 - 0.0156`), and `|s| >= d` on the branch the insertion limits allow (s > 0) is `q_insertion >= d - s_0`.
    `s_0` is read from the robot's own kinematics (FK at two insertions) and the linearity is checked."""
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
        raise SurestepError(f"{robot.urdf}: the insertion joint does not move the shaft's end along a line "
                            "through the RCM; the RCM distance cannot be a bound on the insertion")
    s0 = float(np.dot(pts[0], axis)) - robot.lower[j]
    return j, rcm_min_distance - s0


def enforce(setup, sol, limits: MotionLimits | None = None) -> dict:
    """With `limits.enforce: true`: check the plan of `sol` (a Solution), record the report in
    `sol.extras["motion_limits"]`, and turn a successful solution that breaks a limit into a failure with
    status `Motion_Limits_Violated` (the solver's own status kept as `extras["solver_status"]`; a failed
    solution keeps its status).
    Returns the report (an empty dict when the limits are not enforced)."""
    if not setup.problem.limits.enforce:
        return {}
    if any(q is None for q in sol.q):
        rep = {"skipped": "a waypoint has no IK solution (see reachability)", "ok": False}
    else:
        rep = plan_report(setup.robot, np.array(sol.q, float), setup.problem.timing.step_s,
                          limits or problem_limits(setup), tool_frame=setup.robot.frame)
    rep["enforced"] = True
    sol.extras["motion_limits"] = rep
    if not rep["ok"] and sol.success:  # a failure keeps its own status (the report says what it breaks)
        sol.extras["solver_status"] = sol.status
        sol.success, sol.status = False, VIOLATED
    return rep


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle [rad] of Ra^T Rb."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def plan_report(robot, q: np.ndarray, step_s: float, limits: MotionLimits, tool_frame: str | None = None) -> dict:
    """Every limit violation of the joint plan `q` ((T+1, nq), robot joint order) at one step per `step_s`.

    `robot` is a `surestep_ocp.model.robot.Robot`; the tool is its `tool_frame` (default: its tracked frame,
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
        over = np.argwhere(np.abs(values) > lim * (1 + REL_TOL))
        for t, j in over:
            violations.append({"kind": kind, "step": int(t), "joint": limits.joint_names[j],
                               "value": float(values[t, j]), "limit": float(lim[j])})
    for kind, values, lim in (("tool_speed", dp, limits.tool_speed), ("tool_rotation", dr, limits.tool_rotation)):
        for t in np.flatnonzero(values > lim * (1 + REL_TOL)):
            violations.append({"kind": kind, "step": int(t), "value": float(values[t]), "limit": float(lim)})
    rcm = None
    if is_psm(robot):
        dist = np.array([np.linalg.norm(robot.frame_pose(qi, RCM_FRAME)[:3, 3]) for qi in q])
        rcm = float(dist.min())
        for t in np.flatnonzero(dist < limits.rcm_min_distance * (1 - REL_TOL)):
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


# ------------------------------------------------------------------------------------------ the played curve
# The curve `surestep export` plays at the planned times when it is within the limits, and the one whose limits
# the OCP's rows bound (`CURVE_ROWS = "curve"`): between waypoints t and t+1 the quintic Hermite polynomial with the
# waypoints' positions and their finite-difference velocities and accelerations at both ends,
#   v_t = (q_t+1 - q_t-1) / (2 dt),  a_t = (q_t+1 - 2 q_t + q_t-1) / dt^2   (interior waypoints),
#   v_0 = v_T = 0,  a_0 = (q_1 - q_0) / dt^2,  a_T = (q_T-1 - q_T) / dt^2      (from and to rest, as plan_report),
# so it is twice continuously differentiable, passes every waypoint at its planned time, and its knot accelerations
# are exactly the finite-difference accelerations `plan_report` checks. Each piece depends on four waypoints
# (t-1 .. t+2), so every row is local. Velocity (a quartic) and acceleration (a cubic) are linear in the waypoints,
# so their Bernstein control points are too, and a polynomial lies between its smallest and largest control point:
# bounding the control points bounds the curve everywhere (a sufficient linear condition). The tool's speed is
# nonlinear: bounded at TOOL_POINTS of every piece (the export checks it densely and says so).
CURVE_ROWS = "curve"  # the OCP's limit rows: "curve" (the played curve's) or "steps" (finite differences, before)
CURVE_PIECES = {"velocity": 1, "acceleration": 3}  # parts of a step for the control-point bounds (tighter with more)
TOOL_POINTS = (0.0, 0.25, 0.5, 0.75)  # fractions of a step where the tool-speed rows bound the curve
TOOL_MARGIN = 0.02  # the rows bound the tool's speeds at those points to (1 - this) of their limits
CURVE_NAME = "quintic Hermite through the waypoints, finite-difference velocities and accelerations at them"


def _quintic_basis() -> np.ndarray:
    """(6, 6): power coefficients c_0..c_5 of p(s), s in [0, 1], from (p0, p0', p0'', p1, p1', p1'') (d/ds)."""
    M = np.zeros((6, 6))
    for row, (s, d) in enumerate(((0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2))):
        for k in range(6):
            if k >= d:
                M[row, k] = math.perm(k, d) * (s ** (k - d) if k > d else 1.0)
    return np.linalg.inv(M)


_QUINTIC = _quintic_basis()


def knot_derivatives(T: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(T+1, T+1) maps of one joint's waypoints to its knot velocities and accelerations (see above)."""
    Dv, Da = np.zeros((T + 1, T + 1)), np.zeros((T + 1, T + 1))
    for i in range(1, T):
        Dv[i, i + 1], Dv[i, i - 1] = 1 / (2 * dt), -1 / (2 * dt)
        Da[i, i - 1], Da[i, i], Da[i, i + 1] = 1 / dt**2, -2 / dt**2, 1 / dt**2
    Da[0, 0], Da[0, 1] = -1 / dt**2, 1 / dt**2
    Da[T, T], Da[T, T - 1] = -1 / dt**2, 1 / dt**2
    return Dv, Da


def curve_coefficients(T: int, dt: float) -> np.ndarray:
    """(T, 6, T+1): for piece t, the power coefficients in s = (time - t dt) / dt of the curve, as a linear map
    of one joint's waypoints (the same for every joint)."""
    Dv, Da = knot_derivatives(T, dt)
    E = np.eye(T + 1)
    out = np.zeros((T, 6, T + 1))
    for t in range(T):
        data = np.vstack([E[t], dt * Dv[t], dt**2 * Da[t], E[t + 1], dt * Dv[t + 1], dt**2 * Da[t + 1]])
        out[t] = _QUINTIC @ data
    out[np.abs(out) < 1e-12 * np.abs(out).max()] = 0.0  # rounding of exact zeros
    return out


def _to_bernstein(n: int) -> np.ndarray:
    """(n+1, n+1): Bernstein control points of a degree-n polynomial on [0, 1] from its power coefficients."""
    B = np.zeros((n + 1, n + 1))
    for j in range(n + 1):
        for k in range(j + 1):
            B[j, k] = math.comb(j, k) / math.comb(n, k)
    return B


def derivative_power(order: int, dt: float) -> np.ndarray:
    """(6 - order, 6): power coefficients of the order-th time derivative of a quintic in s = time / dt."""
    D = np.zeros((6 - order, 6))
    for k in range(order, 6):
        D[k - order, k] = math.perm(k, order) / dt**order
    return D


def _reparametrise(n: int, lo: float, hi: float) -> np.ndarray:
    """(n+1, n+1): power coefficients in sigma of p(lo + (hi - lo) sigma) from those of p(s)."""
    R = np.zeros((n + 1, n + 1))
    for j in range(n + 1):
        for k in range(j, n + 1):
            R[j, k] = math.comb(k, j) * lo ** (k - j) * (hi - lo) ** j
    return R


def curve_control_rows(T: int, dt: float, pieces: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rows (linear maps of one joint's waypoints) whose absolute values bound the curve's |velocity| and
    |acceleration| everywhere: the knot values once, and the interior Bernstein control points of each step split
    in `pieces[kind]` equal parts (default CURVE_PIECES; more parts, tighter bounds: the control points converge to
    the curve's values, measured in docs/motion_limits_and_export.md)."""
    pieces = {**CURVE_PIECES, **(pieces or {})}
    C = curve_coefficients(T, dt)
    out = []
    for order, kind in ((1, "velocity"), (2, "acceleration")):
        m = int(pieces[kind])
        n = 5 - order
        D = derivative_power(order, dt)
        B = _to_bernstein(n)
        rows = [(B @ D)[0] @ C[0]]
        for t in range(T):
            for k in range(m):
                ctrl = B @ _reparametrise(n, k / m, (k + 1) / m) @ D @ C[t]  # (n+1, T+1)
                rows += list(ctrl[1:])  # its first is the last one of the part before
        out.append(np.array(rows))
    return out[0], out[1]


def curve_point_weights(T: int, dt: float, t: int, s: float) -> tuple[np.ndarray, np.ndarray]:
    """(T+1,) weights of one joint's waypoints giving the curve's position and velocity in piece t at fraction s."""
    C = curve_coefficients(T, dt)[t]
    powers = np.array([s**k for k in range(6)])
    dpow = np.array([k * s ** (k - 1) if k else 0.0 for k in range(6)]) / dt
    return powers @ C, dpow @ C


def evaluate_curve(q: np.ndarray, dt: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The curve through the waypoints `q` ((T+1, n)) at the planned pace: positions, velocities and accelerations
    at `times` ([0, T dt]), each (len(times), n)."""
    q = np.asarray(q, float)
    T = len(q) - 1
    coef = np.einsum("tkm,mj->tkj", curve_coefficients(T, dt), q)  # (T, 6, n)
    x = np.asarray(times, float) / dt
    piece = np.clip(np.floor(x).astype(int), 0, T - 1)
    s = x - piece
    out = []
    for order in range(3):
        D = derivative_power(order, dt) if order else np.eye(6)
        c = np.einsum("ik,tkj->tij", D, coef)[piece]  # (N, 6 - order, n)
        p = np.stack([s**k for k in range(6 - order)], axis=1)  # (N, 6 - order)
        out.append(np.einsum("nk,nkj->nj", p, c))
    return out[0], out[1], out[2]
