"""`surestep export SOLUTION.json --format csv|json|ros2 --output F`: a time-stamped joint trajectory.

First (`--timing auto`, the default) the planned curve is tried: the curve through the waypoints at the planned
times that the OCP's limit rows bound with `limits.enforce: true` (`model/limits/curve.py`: a quintic
Hermite per step with the waypoints' finite-difference velocities and accelerations). It is checked at every
sample written and at CURVE_CHECK_PER_STEP points per step against the joint velocity and acceleration limits and
the tool's speeds (Pinocchio's frame Jacobian); within them (to REL_TOL) it is written as it is, the duration the
planned one (`timing: planned` in the JSON, the ROS 2 header). Otherwise the plan is retimed (`timing: toppra`,
with the planned curve's peak ratios and the reason in `planned_curve`), as follows.

The planned waypoints `q_0..q_T` become a path in joint space, `q(s)` with `q(i * step_s) = q_i`
(piecewise cubic Hermite, shape-preserving: scipy's PCHIP, so between two waypoints every joint
stays between its two values and never leaves its position limits). toppra (time-optimal path
parametrisation, Pham & Pham 2018) then finds the fastest `s(t)` within the joint velocity limits
(the URDF's `<limit velocity=...>`) and acceleration limits (`limits.DEFAULT_ACCELERATION`, the
dVRK's `move_jp` defaults; both overridable per joint) and the tool's translation and rotation
speed, starting and ending at rest, and never faster than the plan's own pace (the model's
observations per step assume it): `s` itself is a last, virtual joint with velocity limit 1, so
each step takes at least `step_s`, longer only where a limit needs it. The tool's speed along the
path is `|J_v(q(s)) q'(s)| s_dot` (Pinocchio's frame Jacobian), so its bound is one on `s_dot`
per grid point (`_ToolSpeedConstraint`).

The limits are those the plan was made with (the solution's recorded `limits`: the problem's
`limits:` section resolved against the URDF and the defaults; older files without it: the
defaults), with the command line's overrides on top; the output says where each value came from.

toppra enforces the limits at its grid points; the trajectory is then checked against the true
limits between them and at every sample written (every 1/rate s and every waypoint's time); if
a family of limits (joint velocities, joint accelerations, tool speeds) is exceeded, toppra runs
again with that family's limits scaled down by the overshoot, and the scales used are reported.
The six arm joints (every joint but `jaw` for other robots) and the jaw are separate channels.
Files are written atomically (temporary file and rename).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import SurestepError, shown
from ..model.limits.curve import CURVE_NAME, evaluate_curve
from ..model.limits.values import JAW, REL_TOL, MotionLimits, motion_limits, parse_overrides
from ..problem.paths import resolve_urdf
from ..quiet import quiet_fd
from .outputs import check_output_file
from .solution import write_json_atomic, write_text_atomic

FORMATS = ("csv", "json", "ros2")
DEFAULT_RATE_HZ = 100.0
DEFAULT_STEP_S = 0.05  # the paper's pace when a solution file records no timing (timing.step_s default)
MAX_TRIES = 12  # toppra runs, each with the limits over which the last one went scaled down
SCALE_MARGIN = 0.995  # a family's next scale: this over its peak ratio to the limit, times its last scale
GRID_PER_STEP = 8  # toppra grid points per planned step (plus both sides of every waypoint)
CHECK_PER_INTERVAL = 6  # samples per toppra grid interval in the limit check
FORMAT_ID = "surestep-joint-trajectory/1"
CLOCK_ACCELERATION = 100.0  # [1/s] bound on s-ddot (not binding in practice: the joints' limits are)
PRE_KNOT = 1e-6  # grid point this fraction of a step before each waypoint
POSITION_TOL = 1e-6  # [relative] a waypoint this far beyond a position limit is clipped onto it, further is an error
COMMAND_LINE = "command line"  # the source of a limit given by an export flag
TIMINGS = ("auto", "planned", "toppra")  # auto: the planned curve when within the limits, else toppra
CURVE_CHECK_PER_STEP = 40  # points per planned step where the planned curve is checked (and every sample)


@dataclass
class Trajectory:
    """A sampled joint trajectory: `times` (N,), `q`, `qd`, `qdd` (N, n) in `joint_names` order."""

    joint_names: list[str]
    times: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    waypoint_times: np.ndarray  # (T+1,) time at which waypoint i is passed
    waypoint_rows: np.ndarray  # (T+1,) row index of waypoint i in the samples
    limits: MotionLimits
    scales: dict[str, float]  # of each family of limits given to toppra (1: the limits themselves)
    step_s: float
    peak_velocity_ratio: np.ndarray  # over the dense check
    peak_acceleration_ratio: np.ndarray
    peak_tool_ratio: tuple[float, float] | None = None  # translation, rotation speed / limit (dense check)
    tool_frame: str | None = None
    timing: str = "toppra"  # "planned": the planned curve at the planned times; "toppra": retimed
    planned_curve: dict | None = None  # the planned curve's peak ratios to the limits (dense check), and why not played

    @property
    def duration(self) -> float:
        return float(self.times[-1])


def load_solution(path: str | Path) -> dict:
    """The solution JSON as a dict; a missing or malformed file is a one-line error naming it."""
    p = Path(path)
    if not p.is_file():
        raise SurestepError(f"{p}: no such solution file")
    try:
        d = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SurestepError(f"{p}: not a solution JSON file ({str(exc).splitlines()[0]})") from None
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


class _PchipPath:
    """A toppra geometric path (toppra's AbstractGeometricPath interface, duck-typed: toppra is imported
    only when exporting): scipy's PCHIP through the waypoints, plus the path parameter as a last joint."""

    def __init__(self, ss: np.ndarray, qs: np.ndarray):
        from scipy.interpolate import PchipInterpolator

        self._ss = np.asarray(ss, float)
        self._f = [PchipInterpolator(self._ss, np.column_stack([qs, self._ss]), axis=0)]
        self._f += [self._f[0].derivative(1), self._f[0].derivative(2)]

    def __call__(self, s, order: int = 0):
        return self._f[order](s)

    @property
    def dof(self) -> int:
        return int(self._f[0].c.shape[-1])

    @property
    def path_interval(self):
        return np.array([self._ss[0], self._ss[-1]])

    @property
    def waypoints(self):
        return self._ss, self._f[0](self._ss)

    def eval(self, s):
        return self(s, 0)

    def evald(self, s):
        return self(s, 1)

    def evaldd(self, s):
        return self(s, 2)


class _ToolSpeed:
    """The tool's translation and rotation speed per unit path speed along a path: `|J_v(q(s)) q'(s)|`
    and `|J_w(q(s)) q'(s)|` (Pinocchio's frame Jacobian), and the bound they put on `s_dot`."""

    def __init__(self, robot, frame: str, limits: MotionLimits):
        self.robot, self.frame = robot, frame
        self.vmax = np.array([limits.tool_speed, limits.tool_rotation])

    def rates(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(N, 2): translation [m/s] and rotation [rad/s] speed of the tool at joints q (N, n) moving at qd."""
        twist = np.einsum("kij,kj->ki", np.array([self.robot.frame_jacobian(qk, self.frame) for qk in q]), qd)
        return np.column_stack([np.linalg.norm(twist[:, :3], axis=1), np.linalg.norm(twist[:, 3:], axis=1)])

    def constraint(self, path, scale: float):
        """A toppra velocity constraint: `s_dot^2 <= min_i (scale * vmax_i / rate_i(s))^2` at every grid point."""
        from toppra.constraint import DiscretizationType, LinearConstraint

        tool, n = self, self.robot.nq

        class _ToolSpeedConstraint(LinearConstraint):
            def __init__(self):
                super().__init__()
                self.dof = path.dof
                self.discretization_type = DiscretizationType.Collocation
                self._format_string = f"    Tool speed limit: {tool.vmax} x {scale:g}\n"

            def compute_constraint_params(self, path_, gridpoints):
                r = tool.rates(path_(gridpoints, 0)[:, :n], path_(gridpoints, 1)[:, :n])
                with np.errstate(divide="ignore"):
                    x_max = np.min((scale * tool.vmax / r) ** 2, axis=1)
                xbound = np.column_stack([np.zeros(len(gridpoints)), np.minimum(x_max, 1e12)])
                return None, None, None, None, None, None, xbound

        return _ToolSpeedConstraint()


def _grid(ss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """toppra grid points: each step split in GRID_PER_STEP, plus a point just before every interior
    waypoint (PCHIP's second derivative jumps there); and the index of each waypoint in the grid."""
    pts = [ss[0]]
    for a, b in zip(ss[:-1], ss[1:]):
        inner = np.linspace(a, b, GRID_PER_STEP + 1)[1:]
        pts.extend(inner[:-1])
        pts.extend([b - PRE_KNOT * (b - a), b])
    grid = np.array(pts)
    idx = np.searchsorted(grid, ss)
    assert np.allclose(grid[idx], ss, rtol=0, atol=0)
    return grid, idx


def _sample_times(duration: float, wp_t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Every 1/rate_hz s and every waypoint's time (exactly; a uniform sample on one: one row)."""
    times = np.union1d(np.arange(0.0, duration, 1.0 / rate_hz), wp_t)
    times = times[np.concatenate([[True], np.diff(times) > 1e-9])]
    for t in wp_t:
        times[np.argmin(np.abs(times - t))] = t
    return times


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


def planned_curve(q: np.ndarray, step_s: float, limits: MotionLimits, rate_hz: float = DEFAULT_RATE_HZ,
                  robot=None, tool_frame: str | None = None) -> tuple[Trajectory | None, dict]:
    """The planned curve (`model/limits/curve.py`: the curve the OCP's rows bound with `limits.enforce`)
    through the waypoints `q` at the planned times, sampled every 1/rate_hz s and at every waypoint; checked against
    the joint velocity and acceleration limits and the tool's speeds at those samples and at CURVE_CHECK_PER_STEP
    points per step. Returns (the trajectory, or None when a limit is exceeded by more than REL_TOL; the check:
    peak ratios per family and `within`)."""
    q = np.asarray(q, float)
    T, n = len(q) - 1, q.shape[1]
    wp_t = step_s * np.arange(T + 1)
    times = _sample_times(float(wp_t[-1]), wp_t, rate_hz)
    check = np.union1d(times, np.linspace(0.0, wp_t[-1], CURVE_CHECK_PER_STEP * T + 1))
    Q, QD, QDD = evaluate_curve(q, step_s, check)
    vr = np.max(np.abs(QD) / limits.velocity, axis=0)
    ar = np.max(np.abs(QDD) / limits.acceleration, axis=0)
    tool = None if robot is None else _ToolSpeed(robot, tool_frame or robot.frame, limits)
    tool_ratio = None
    if tool is not None and max(vr.max(), ar.max()) <= 1 + REL_TOL:  # (not worth the Jacobians when over already)
        tool_ratio = tuple(float(x) for x in np.max(tool.rates(Q, QD) / tool.vmax, axis=0))
    peaks = {"joint_velocity": float(vr.max()), "joint_acceleration": float(ar.max()),
             "tool_speed": None if tool_ratio is None else tool_ratio[0],
             "tool_rotation": None if tool_ratio is None else tool_ratio[1]}
    within = all(v is None or v <= 1 + REL_TOL for v in peaks.values()) and (tool is None or tool_ratio is not None)
    info = {"curve": CURVE_NAME, "peak_ratios": peaks, "within": within}
    if not within:
        return None, info
    Q, QD, QDD = evaluate_curve(q, step_s, times)
    QD[0] = QD[-1] = 0.0  # at rest (zero by construction; removes rounding)
    rows = np.searchsorted(times, wp_t)
    Q[rows] = q  # the waypoints themselves (the curve passes them to rounding)
    traj = Trajectory(list(limits.joint_names), times, Q, QD, QDD, wp_t, rows, limits,
                      {"joint_velocity": 1.0, "joint_acceleration": 1.0, "tool_speed": 1.0}, step_s, vr, ar,
                      tool_ratio, None if tool is None else tool.frame, timing="planned", planned_curve=info)
    return traj, info


def time_parametrise(q: np.ndarray, step_s: float, limits: MotionLimits, rate_hz: float = DEFAULT_RATE_HZ,
                     robot=None, tool_frame: str | None = None, timing: str = "auto") -> Trajectory:
    """The trajectory through the waypoints `q` ((T+1, n)) within `limits`: with `timing` "auto" the planned
    curve at the planned times when it is within every limit (`planned_curve`), else (and with "toppra") the
    time-optimal one (module docstring); with `robot` (a `surestep_ocp.model.robot.Robot` of the plan's joints) and
    `tool_frame`, within the tool's translation and rotation speed limits too."""
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    q = np.asarray(q, float)
    if not (math.isfinite(rate_hz) and 0 < rate_hz <= 10_000):
        raise SurestepError(f"--rate must be in (0, 10000] Hz, got {rate_hz:g}")
    if timing not in TIMINGS:
        raise SurestepError(f"--timing must be one of {', '.join(TIMINGS)}, got {timing!r}")
    curve_info = None
    if timing in ("auto", "planned"):
        played, curve_info = planned_curve(q, step_s, limits, rate_hz, robot, tool_frame)
        if played is not None:
            return played
        over = ", ".join(f"{k} {v:.3f}" for k, v in curve_info["peak_ratios"].items() if v is not None and v > 1)
        if timing == "planned":
            raise SurestepError(f"--timing planned: the planned curve exceeds its limits at the planned pace "
                                f"(peak / limit: {over}); use --timing auto or toppra to retime it")
        curve_info["not_played"] = f"over a limit at the planned pace ({over}): retimed by toppra"
    logging.getLogger("toppra").setLevel(logging.ERROR)  # a failed try is retried; its warnings are noise
    ss = step_s * np.arange(len(q))
    path = _PchipPath(ss, q)
    grid, wp_idx = _grid(ss)
    clock_v = 1.0  # [path s per s]: the path parameter's own limit, the planned pace
    clock_a = CLOCK_ACCELERATION
    tool = None if robot is None else _ToolSpeed(robot, tool_frame or robot.frame, limits)
    tool_ratio = None
    scales = np.ones(3)  # of the joint velocity, joint acceleration and tool speed limits handed to toppra
    for _ in range(MAX_TRIES):
        vmax = np.append(scales[0] * limits.velocity, clock_v)
        amax = np.append(scales[1] * limits.acceleration, clock_a)
        cons = [constraint.JointVelocityConstraint(np.column_stack([-vmax, vmax])),
                constraint.JointAccelerationConstraint(np.column_stack([-amax, amax]))]
        if tool is not None:
            cons.append(tool.constraint(path, scales[2]))
        inst = algo.TOPPRA(cons, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
        traj = inst.compute_trajectory(0.0, 0.0)
        if traj is None:
            scales *= 0.9
            continue
        ts_grid = np.asarray(traj._ts, float)  # time of each grid point (ParametrizeConstAccel)
        wp_t = ts_grid[wp_idx]
        # the dense check: CHECK_PER_INTERVAL samples inside every grid interval, both ends from inside
        u = np.linspace(0.0, 1.0, CHECK_PER_INTERVAL + 1)
        u[0], u[-1] = 1e-9, 1 - 1e-9
        times = _sample_times(float(ts_grid[-1]), wp_t, rate_hz)  # and the samples written
        tc = np.concatenate([(ts_grid[:-1, None] + np.diff(ts_grid)[:, None] * u[None, :]).ravel(), times])
        n = q.shape[1]
        vr = np.max(np.abs(traj(tc, 1)[:, :n]) / limits.velocity, axis=0)
        ar = np.max(np.abs(traj(tc, 2)[:, :n]) / limits.acceleration, axis=0)
        if tool is not None:
            tool_ratio = tuple(np.max(tool.rates(traj(tc, 0)[:, :n], traj(tc, 1)[:, :n]) / tool.vmax, axis=0))
        peaks = np.array([vr.max(), ar.max(), 0.0 if tool_ratio is None else max(tool_ratio)])
        if np.all(peaks <= 1.0):
            break
        over = peaks > 1.0  # those families over their limit between the grid points: their scale down
        scales[over] *= np.minimum(0.99, SCALE_MARGIN / peaks[over])
    else:
        raise SurestepError(f"toppra found no trajectory within the limits in {MAX_TRIES} tries (the limits "
                            f"handed to it scaled down to {', '.join(f'{x:.3g}' for x in scales)})")
    rows = np.searchsorted(times, wp_t)
    n = q.shape[1]
    Q, QD, QDD = traj(times, 0)[:, :n], traj(times, 1)[:, :n], traj(times, 2)[:, :n]
    QD[0] = QD[-1] = 0.0  # at rest (toppra's sd = 0 there; removes rounding)
    err = np.max(np.abs(Q[rows] - q))
    if err > 1e-9 * max(1.0, float(np.max(np.abs(q)))):
        raise SurestepError(f"internal: the trajectory misses a waypoint by {err:.2e}")  # never expected
    Q[rows] = q  # the waypoints themselves (differ from toppra's evaluation by rounding only, checked above)
    return Trajectory(list(limits.joint_names), times, Q, QD, QDD, wp_t, rows, limits,
                      dict(zip(("joint_velocity", "joint_acceleration", "tool_speed"), scales.tolist())), step_s, vr,
                      ar, None if tool_ratio is None else (float(tool_ratio[0]), float(tool_ratio[1])),
                      None if tool is None else tool.frame, timing="toppra", planned_curve=curve_info)


# ------------------------------------------------------------------------------------------ writers
def _channels(traj: Trajectory) -> tuple[list[int], list[int]]:
    arm = [i for i, n in enumerate(traj.joint_names) if n != JAW]
    jaw = [i for i, n in enumerate(traj.joint_names) if n == JAW]
    return arm, jaw


def to_json(traj: Trajectory, meta: dict) -> dict:
    arm, jaw = _channels(traj)
    out = {
        "format": FORMAT_ID,
        **meta,
        "step_s": traj.step_s,
        "duration_s": traj.duration,
        "planned_duration_s": traj.step_s * (len(traj.waypoint_times) - 1),
        "limits": traj.limits.to_dict(),
        "timing": traj.timing,  # "planned": the planned curve at the planned times; "toppra": retimed
        "planned_curve": traj.planned_curve,
        "limit_scales": traj.scales,
        "peak_velocity_ratio": dict(zip(traj.joint_names, traj.peak_velocity_ratio.tolist())),
        "peak_acceleration_ratio": dict(zip(traj.joint_names, traj.peak_acceleration_ratio.tolist())),
        "tool_frame": traj.tool_frame,
        "peak_tool_speed_ratio": None if traj.peak_tool_ratio is None else traj.peak_tool_ratio[0],
        "peak_tool_rotation_ratio": None if traj.peak_tool_ratio is None else traj.peak_tool_ratio[1],
        "waypoints": [{"index": i, "time_s": float(t), "planned_time_s": i * traj.step_s, "row": int(r)}
                      for i, (t, r) in enumerate(zip(traj.waypoint_times, traj.waypoint_rows))],
        "joint_names": [traj.joint_names[i] for i in arm],
        "time_s": traj.times.tolist(),
        "positions": traj.q[:, arm].tolist(),
        "velocities": traj.qd[:, arm].tolist(),
        "accelerations": traj.qdd[:, arm].tolist(),
    }
    if jaw:
        j = jaw[0]
        out["jaw"] = {"name": JAW, "positions": traj.q[:, j].tolist(), "velocities": traj.qd[:, j].tolist(),
                      "accelerations": traj.qdd[:, j].tolist()}
    return out


def to_csv(traj: Trajectory) -> str:
    arm, jaw = _channels(traj)
    names = [traj.joint_names[i] for i in arm]
    jn = [JAW] if jaw else []
    header = (["time_s", "waypoint"] + names + [f"{n}_vel" for n in names] + [f"{n}_acc" for n in names]
              + [f"{n}{s}" for n in jn for s in ("", "_vel", "_acc")])
    wp = {int(r): i for i, r in enumerate(traj.waypoint_rows)}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for k, t in enumerate(traj.times):
        row = [repr(float(t)), str(wp[k]) if k in wp else ""]
        for M in (traj.q, traj.qd, traj.qdd):
            row += [repr(float(v)) for v in M[k, arm]]
        for j in jaw:
            row += [repr(float(traj.q[k, j])), repr(float(traj.qd[k, j])), repr(float(traj.qdd[k, j]))]
        w.writerow(row)
    return buf.getvalue()


def _duration_msg(t: float) -> dict:
    """builtin_interfaces/Duration of `t` seconds."""
    sec = int(math.floor(t))
    nanosec = int(round((t - sec) * 1e9))
    if nanosec >= 1_000_000_000:
        sec, nanosec = sec + 1, nanosec - 1_000_000_000
    return {"sec": sec, "nanosec": nanosec}


def to_joint_trajectory(traj: Trajectory, idx: list[int]) -> dict:
    """trajectory_msgs/JointTrajectory (ROS 2) of the joints `idx`, as a plain mapping."""
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""},
        "joint_names": [traj.joint_names[i] for i in idx],
        "points": [{"positions": [float(v) for v in traj.q[k, idx]],
                    "velocities": [float(v) for v in traj.qd[k, idx]],
                    "accelerations": [float(v) for v in traj.qdd[k, idx]],
                    "effort": [],
                    "time_from_start": _duration_msg(float(t))} for k, t in enumerate(traj.times)],
    }


def _ros2_text(traj: Trajectory, idx: list[int], what: str) -> str:
    import yaml

    times = ", ".join(f"{t:.6f}" for t in traj.waypoint_times)
    head = (f"# trajectory_msgs/JointTrajectory ({what}), written by surestep export\n"
            f"# planned waypoints 0..{len(traj.waypoint_times) - 1} at time_from_start [s]: {times}\n"
            f"# timing: {_timing_text(traj)}\n")
    return head + yaml.safe_dump(to_joint_trajectory(traj, idx), sort_keys=False, default_flow_style=None)


def _timing_text(traj: Trajectory) -> str:
    if traj.timing == "planned":
        return f"planned ({CURVE_NAME}, at the planned times)"
    why = (traj.planned_curve or {}).get("not_played", "--timing toppra")
    return f"toppra (time-optimal within the limits; the planned curve: {why})"


def jaw_path(output: Path) -> Path:
    """Where the ros2 form puts the jaw's own JointTrajectory: beside the arm's, `<stem>_jaw<suffix>`."""
    return output.with_name(f"{output.stem}_jaw{output.suffix}")


def write(traj: Trajectory, fmt: str, output: Path, meta: dict) -> list[Path]:
    """Write the trajectory in `fmt` (atomically); returns the files written."""
    if fmt == "json":
        return [write_json_atomic(output, to_json(traj, meta))]
    if fmt == "csv":
        return [write_text_atomic(output, to_csv(traj))]
    if fmt == "ros2":
        arm, jaw = _channels(traj)
        files = [write_text_atomic(output, _ros2_text(traj, arm, "arm joints"))]
        if jaw:
            files.append(write_text_atomic(jaw_path(output), _ros2_text(traj, jaw, "jaw")))
        return files
    raise SurestepError(f"unknown format '{fmt}'; allowed: {', '.join(FORMATS)}")


# ------------------------------------------------------------------------------------------ command
def export_solution(solution: str | Path, fmt: str, output: str | Path, *, rate_hz: float = DEFAULT_RATE_HZ,
                    step_s: float | None = None, velocity: dict | None = None,
                    acceleration: dict | None = None, tool_speed: float | None = None,
                    tool_rotation: float | None = None, plot: bool = True,
                    timing: str = "auto") -> tuple[Trajectory, list[Path]]:
    from ..model.robot import Robot

    if fmt not in FORMATS:
        raise SurestepError(f"unknown format '{fmt}'; allowed: {', '.join(FORMATS)}")
    sol = load_solution(solution)
    urdf = resolve_urdf(str(sol["robot"].get("urdf", "")))
    if not urdf.is_file():
        raise SurestepError(f"{solution}: robot.urdf '{sol['robot'].get('urdf')}' not found ({urdf})")
    for flag, x in (("--tool-speed", tool_speed), ("--tool-rotation-speed", tool_rotation)):
        if x is not None and not (math.isfinite(x) and x > 0):
            raise SurestepError(f"{flag} must be a positive number, got {x:g}")
    output = Path(output)
    targets = [output] + ([jaw_path(output)] if fmt == "ros2" else []) + (
        [output.with_name(f"{output.stem}_motion.png")] if plot else [])
    for path in targets:  # before any work: never the solution or the URDF read here, never a folder or a device
        check_output_file(path, inputs=[solution, urdf], what="the export")
    frame = str(sol["robot"].get("frame") or "tool")
    try:
        with quiet_fd(2):  # urdfdom prints parse errors on stderr; the error below says it in one line
            robot = Robot(urdf, frame=frame)
    except (ValueError, RuntimeError, OSError, SurestepError) as exc:
        raise SurestepError(f"{solution}: robot.urdf {shown(str(urdf), 120)}: cannot load it "
                            f"({shown(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 160)})") from None
    try:
        limits = limits_of(sol, urdf, velocity, acceleration, tool_speed, tool_rotation)
    except SurestepError as exc:
        raise SurestepError(f"{solution}: {exc}") from None
    step, step_source = step_of(sol, step_s)
    if robot.joint_names != list(sol["joint_names"]):
        raise SurestepError(f"{solution}: joint_names {', '.join(sol['joint_names'])} are not those of {urdf}")
    q, clipped = within_position_limits(np.array(sol["q"], float), robot)
    traj = time_parametrise(q, step, limits, rate_hz, robot=robot, tool_frame=frame, timing=timing)
    meta = {"source": str(solution), "method": sol.get("method"), "problem": sol.get("problem"),
            "robot": {"urdf": sol["robot"].get("urdf"), "frame": sol["robot"].get("frame")},
            "step_s_source": step_source, "limits_enforced_in_plan": (sol.get("limits") or {}).get("enforce"),
            "waypoints_clipped_by": clipped}
    files = write(traj, fmt, output, meta)
    if plot:
        from .plots_motion import plot_trajectory

        files.append(plot_trajectory(traj, sol, urdf, output.with_name(f"{output.stem}_motion.png")))
    return traj, files


def summary(traj: Trajectory) -> str:
    planned = traj.step_s * (len(traj.waypoint_times) - 1)
    jv, ja = int(np.argmax(traj.peak_velocity_ratio)), int(np.argmax(traj.peak_acceleration_ratio))
    lines = [
        f"duration    {traj.duration:.3f} s ({len(traj.times)} samples; planned {planned:.3f} s at "
        f"{traj.step_s:g} s per step)",
        f"velocity    peak {traj.peak_velocity_ratio[jv]:.3f} of the limit ({traj.joint_names[jv]})",
        f"accel.      peak {traj.peak_acceleration_ratio[ja]:.3f} of the limit ({traj.joint_names[ja]})",
    ]
    if traj.peak_tool_ratio is not None:
        lim = traj.limits
        lines.append(f"tool        peak {traj.peak_tool_ratio[0]:.3f} of {1e3 * lim.tool_speed:g} mm/s, "
                     f"{traj.peak_tool_ratio[1]:.3f} of {lim.tool_rotation:.3g} rad/s ({traj.tool_frame})")
    lines.append(f"timing      {_timing_text(traj)}")
    lines.append(f"limits      {traj.limits.sources.get('recorded', '')}")
    low = {k: v for k, v in traj.scales.items() if v < 1}
    if low:
        scaled = ", ".join(f"{v:.3g} ({k})" for k, v in low.items())
        lines.append(f"note        toppra was given the limits scaled by {scaled} so that the samples between its "
                     "grid points stay within them")
    return "\n".join(lines)


def cmd_export(args) -> int:
    traj, files = export_solution(
        args.solution, args.format, args.output, rate_hz=args.rate, step_s=args.step_s,
        velocity=parse_overrides(args.velocity_limit, "--velocity-limit"),
        acceleration=parse_overrides(args.acceleration_limit, "--acceleration-limit"),
        tool_speed=args.tool_speed, tool_rotation=args.tool_rotation_speed, plot=not args.no_plot,
        timing=args.timing)
    print(summary(traj))
    for f in files:
        print(f"wrote       {f}")
    return 0


def register(sub) -> None:
    """The `export` subcommand (surestep_ocp/cli.py)."""
    e = sub.add_parser("export", help="time-parametrise a solution's joint plan within its motion limits "
                                      "and write it as CSV, JSON or a ROS 2 JointTrajectory (YAML)")
    e.add_argument("solution", metavar="SOLUTION.json")
    e.add_argument("--format", required=True, choices=FORMATS)
    e.add_argument("--output", "-o", required=True, help="file to write (ros2: the jaw goes to <stem>_jaw<suffix>)")
    e.add_argument("--rate", type=float, default=DEFAULT_RATE_HZ, help="samples per second (default 100; "
                   "every waypoint's time is a sample too)")
    e.add_argument("--step-s", type=float, help="seconds per planned step (default: the solution's "
                   "timing.step_s, else 0.05)")
    e.add_argument("--velocity-limit", action="append", metavar="JOINT=V",
                   help="override a joint's velocity limit [rad/s or m/s] (default: the solution's recorded "
                        "limits, i.e. its problem's limits: section, else the URDF's); repeatable")
    e.add_argument("--acceleration-limit", action="append", metavar="JOINT=A",
                   help="override a joint's acceleration limit [rad/s^2 or m/s^2] (default: the solution's "
                        "recorded limits, else the dVRK's move_jp values, docs/motion_limits_and_export.md); repeatable")
    e.add_argument("--tool-speed", type=float, metavar="M_S",
                   help="override the tool's translation speed limit [m/s] (default: the recorded one, else 0.1)")
    e.add_argument("--tool-rotation-speed", type=float, metavar="RAD_S",
                   help="override the tool's rotation speed limit [rad/s] (default: the recorded one, else pi/2)")
    e.add_argument("--timing", choices=TIMINGS, default="auto",
                   help="auto: the planned curve at the planned times when it is within every limit (a plan "
                        "made with limits.enforce: true), else retimed by toppra; planned: that curve or an error; "
                        "toppra: always retimed (default: auto)")
    e.add_argument("--no-plot", action="store_true", help="do not write <stem>_motion.png beside the output")
    e.set_defaults(func=cmd_export)
