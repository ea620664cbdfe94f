"""Time parametrisation for `surestep export`: the planned curve at the planned times, or toppra's
retiming.

First (`--timing auto`, the default) the planned curve is tried: the curve through the waypoints at
the planned times that the OCP's limit rows bound with `limits.enforce: true`
(`model/limits/curve.py`: a quintic Hermite per step with the waypoints' finite-difference
velocities and accelerations). It is checked at every sample written and at CURVE_CHECK_PER_STEP
points per step against the joint velocity and acceleration limits and the tool's speeds
(Pinocchio's frame Jacobian); within them (to REL_TOL) it is written as it is, the duration the
planned one (`timing: planned` in the JSON, the ROS 2 header). Otherwise the plan is retimed
(`timing: toppra`, with the planned curve's peak ratios and the reason in `planned_curve`), as
follows.

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
per grid point (`ToolSpeed`; the constraint: `retiming_toppra.tool_speed_constraint`).

The limits are those the plan was made with (the solution's recorded `limits`: the problem's
`limits:` section resolved against the URDF and the defaults; older files without it: the
defaults), with the command line's overrides on top; the output says where each value came from.

toppra enforces the limits at its grid points; the trajectory is then checked against the true
limits between them and at every sample written (every 1/rate s and every waypoint's time); if
a family of limits (joint velocities, joint accelerations, tool speeds) is exceeded, toppra runs
again with that family's limits scaled down by the overshoot, and the scales used are reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from ...errors import SurestepError
from .curve import CURVE_NAME, evaluate_curve
from .values import REL_TOL, MotionLimits

DEFAULT_RATE_HZ = 100.0
MAX_TRIES = 12  # toppra runs, each with the limits over which the last one went scaled down
# a family's next scale: this over its peak ratio to the limit, times its last scale
SCALE_MARGIN = 0.995
GRID_PER_STEP = 8  # toppra grid points per planned step (plus both sides of every waypoint)
CHECK_PER_INTERVAL = 6  # samples per toppra grid interval in the limit check
# [1/s] bound on s-ddot (not binding in practice: the joints' limits are)
CLOCK_ACCELERATION = 100.0
PRE_KNOT = 1e-6  # grid point this fraction of a step before each waypoint
# auto: the planned curve when within the limits, else toppra
TIMINGS = ("auto", "planned", "toppra")
# points per planned step where the planned curve is checked (and every sample)
CURVE_CHECK_PER_STEP = 40
MAX_SAMPLES = 1_000_000  # rows written (duration x rate): more is refused before they are made


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
    # translation, rotation speed / limit (dense check)
    peak_tool_ratio: tuple[float, float] | None = None
    tool_frame: str | None = None
    timing: str = "toppra"  # "planned": the planned curve at the planned times; "toppra": retimed
    # the planned curve's peak ratios to the limits (dense check), and why not played
    planned_curve: dict | None = None

    @property
    def duration(self) -> float:
        return float(self.times[-1])


class PchipPath:
    """A toppra geometric path (toppra's AbstractGeometricPath interface, duck-typed: toppra is
    imported only when exporting): scipy's PCHIP through the waypoints, plus the path parameter as a
    last joint."""

    def __init__(self, ss: np.ndarray, qs: np.ndarray):
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


class ToolSpeed:
    """The tool's translation and rotation speed per unit path speed along a path:
    `|J_v(q(s)) q'(s)|` and `|J_w(q(s)) q'(s)|` (Pinocchio's frame Jacobian); the bound they put on
    `s_dot` is `retiming_toppra.tool_speed_constraint`."""

    def __init__(self, robot, frame: str, limits: MotionLimits):
        self.robot, self.frame = robot, frame
        self.vmax = np.array([limits.tool_speed, limits.tool_rotation])

    def rates(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(N, 2): translation [m/s] and rotation [rad/s] speed of the tool at joints q (N, n)
        moving at qd."""
        twist = np.einsum("kij,kj->ki",
                          np.array([self.robot.frame_jacobian(qk, self.frame) for qk in q]), qd)
        return np.column_stack([np.linalg.norm(twist[:, :3], axis=1),
                                np.linalg.norm(twist[:, 3:], axis=1)])


def toppra_grid(ss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def toppra_run(path: PchipPath, grid: np.ndarray, limits: MotionLimits, scales: np.ndarray,
               clock_v: float, clock_a: float, tool: ToolSpeed | None = None):
    """One toppra run along `path` (its last joint the path parameter, within `clock_v`, `clock_a`)
    from rest to rest, within `limits` scaled per family by `scales` (joint velocity, joint
    acceleration, tool speed): toppra's trajectory, or None when it finds none
    (`retiming_toppra`)."""
    from .retiming_toppra import run_toppra  # loaded on use: toppra is slow to import

    return run_toppra(path, grid, limits, scales, clock_v, clock_a, tool)


def _sample_times(duration: float, wp_t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Every 1/rate_hz s and every waypoint's time (exactly; a uniform sample on one: one row); at
    most MAX_SAMPLES."""
    if not duration * rate_hz <= MAX_SAMPLES:
        raise SurestepError(f"the trajectory would take {duration:.6g} s, {duration * rate_hz:.6g} "
                            f"samples at {rate_hz:g} Hz; at most {MAX_SAMPLES} samples are written "
                            "(lower --rate, --step-s or raise the limits)")
    times = np.union1d(np.arange(0.0, duration, 1.0 / rate_hz), wp_t)
    times = times[np.concatenate([[True], np.diff(times) > 1e-9])]
    for t in wp_t:
        times[np.argmin(np.abs(times - t))] = t
    return times


def planned_curve(q: np.ndarray, step_s: float, limits: MotionLimits,
                  rate_hz: float = DEFAULT_RATE_HZ, robot=None,
                  tool_frame: str | None = None) -> tuple[Trajectory | None, dict]:
    """The planned curve (`model/limits/curve.py`: the curve the OCP's rows bound with
    `limits.enforce`) through the waypoints `q` at the planned times, sampled every 1/rate_hz s and
    at every waypoint; checked against the joint velocity and acceleration limits and the tool's
    speeds at those samples and at CURVE_CHECK_PER_STEP points per step. Returns (the trajectory, or
    None when a limit is exceeded by more than REL_TOL; the check:
    peak ratios per family and `within`)."""
    q = np.asarray(q, float)
    T = len(q) - 1
    wp_t = step_s * np.arange(T + 1)
    times = _sample_times(float(wp_t[-1]), wp_t, rate_hz)
    check = np.union1d(times, np.linspace(0.0, wp_t[-1], CURVE_CHECK_PER_STEP * T + 1))
    Q, QD, QDD = evaluate_curve(q, step_s, check)
    vr = np.max(np.abs(QD) / limits.velocity, axis=0)
    ar = np.max(np.abs(QDD) / limits.acceleration, axis=0)
    tool = None if robot is None else ToolSpeed(robot, tool_frame or robot.frame, limits)
    tool_ratio = None
    # (not worth the Jacobians when over already)
    if tool is not None and max(vr.max(), ar.max()) <= 1 + REL_TOL:
        tool_ratio = tuple(float(x) for x in np.max(tool.rates(Q, QD) / tool.vmax, axis=0))
    peaks = {"joint_velocity": float(vr.max()), "joint_acceleration": float(ar.max()),
             "tool_speed": None if tool_ratio is None else tool_ratio[0],
             "tool_rotation": None if tool_ratio is None else tool_ratio[1]}
    within = (all(v is None or v <= 1 + REL_TOL for v in peaks.values())
              and (tool is None or tool_ratio is not None))
    info = {"curve": CURVE_NAME, "peak_ratios": peaks, "within": within}
    if not within:
        return None, info
    Q, QD, QDD = evaluate_curve(q, step_s, times)
    QD[0] = QD[-1] = 0.0  # at rest (zero by construction; removes rounding)
    rows = np.searchsorted(times, wp_t)
    Q[rows] = q  # the waypoints themselves (the curve passes them to rounding)
    traj = Trajectory(list(limits.joint_names), times, Q, QD, QDD, wp_t, rows, limits,
                      {"joint_velocity": 1.0, "joint_acceleration": 1.0, "tool_speed": 1.0}, step_s,
                      vr, ar, tool_ratio, None if tool is None else tool.frame, timing="planned",
                      planned_curve=info)
    return traj, info


def time_parametrise(q: np.ndarray, step_s: float, limits: MotionLimits,
                     rate_hz: float = DEFAULT_RATE_HZ, robot=None, tool_frame: str | None = None,
                     timing: str = "auto") -> Trajectory:
    """The trajectory through the waypoints `q` ((T+1, n)) within `limits`: with `timing` "auto" the
    planned curve at the planned times when it is within every limit (`planned_curve`), else (and
    with "toppra") the time-optimal one (module docstring); with `robot` (a
    `surestep_ocp.model.robot.Robot` of the plan's joints) and `tool_frame`, within the tool's
    translation and rotation speed limits too."""
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
        over = ", ".join(f"{k} {v:.3f}" for k, v in curve_info["peak_ratios"].items()
                         if v is not None and v > 1)
        if timing == "planned":
            raise SurestepError("--timing planned: the planned curve exceeds its limits at the "
                                f"planned pace (peak / limit: {over}); use --timing auto or "
                                "toppra to retime it")
        curve_info["not_played"] = f"over a limit at the planned pace ({over}): retimed by toppra"
    return _toppra_trajectory(q, step_s, limits, rate_hz, robot, tool_frame, curve_info)


def _toppra_trajectory(q: np.ndarray, step_s: float, limits: MotionLimits, rate_hz: float, robot,
                       tool_frame: str | None, curve_info: dict | None) -> Trajectory:
    """toppra's time-optimal trajectory through the waypoints `q` within `limits` (module
    docstring), sampled every 1/rate_hz s and at every waypoint, which it passes exactly;
    `curve_info`: why the planned curve is not played (None: not tried)."""
    ss = step_s * np.arange(len(q))
    path = PchipPath(ss, q)
    grid, wp_idx = toppra_grid(ss)
    tool = None if robot is None else ToolSpeed(robot, tool_frame or robot.frame, limits)
    traj, scales, times, wp_t, vr, ar, tool_ratio = _toppra_within_limits(
        q, path, grid, wp_idx, limits, rate_hz, tool)
    rows = np.searchsorted(times, wp_t)
    n = q.shape[1]
    Q, QD, QDD = traj(times, 0)[:, :n], traj(times, 1)[:, :n], traj(times, 2)[:, :n]
    QD[0] = QD[-1] = 0.0  # at rest (toppra's sd = 0 there; removes rounding)
    err = np.max(np.abs(Q[rows] - q))
    if err > 1e-9 * max(1.0, float(np.max(np.abs(q)))):
        # never expected
        raise SurestepError(f"internal: the trajectory misses a waypoint by {err:.2e}")
    # the waypoints themselves (differ from toppra's evaluation by rounding only, checked above)
    Q[rows] = q
    return Trajectory(list(limits.joint_names), times, Q, QD, QDD, wp_t, rows, limits,
                      dict(zip(("joint_velocity", "joint_acceleration", "tool_speed"),
                               scales.tolist())),
                      step_s, vr, ar,
                      None if tool_ratio is None else (float(tool_ratio[0]), float(tool_ratio[1])),
                      None if tool is None else tool.frame, timing="toppra",
                      planned_curve=curve_info)


def _toppra_within_limits(q: np.ndarray, path: PchipPath, grid: np.ndarray, wp_idx: np.ndarray,
                          limits: MotionLimits, rate_hz: float, tool: ToolSpeed | None) -> tuple:
    """toppra run (`toppra_run`) until its trajectory is within every limit between the grid points
    and at the samples too, each family over its limit scaled down for the next run (at most
    MAX_TRIES runs): (trajectory, scales, sample times, waypoint times, peak velocity and
    acceleration ratios, peak tool ratios)."""
    clock_v = 1.0  # [path s per s]: the path parameter's own limit, the planned pace
    clock_a = CLOCK_ACCELERATION
    tool_ratio = None
    # of the joint velocity, joint acceleration and tool speed limits handed to toppra
    scales = np.ones(3)
    for _ in range(MAX_TRIES):
        traj = toppra_run(path, grid, limits, scales, clock_v, clock_a, tool)
        if traj is None:
            scales *= 0.9
            continue
        ts_grid = np.asarray(traj._ts, float)  # time of each grid point (ParametrizeConstAccel)
        wp_t = ts_grid[wp_idx]
        # the dense check: CHECK_PER_INTERVAL samples inside every grid interval, both ends from
        # inside
        u = np.linspace(0.0, 1.0, CHECK_PER_INTERVAL + 1)
        u[0], u[-1] = 1e-9, 1 - 1e-9
        times = _sample_times(float(ts_grid[-1]), wp_t, rate_hz)  # and the samples written
        tc = np.concatenate([(ts_grid[:-1, None] + np.diff(ts_grid)[:, None] * u[None, :]).ravel(),
                             times])
        n = q.shape[1]
        vr = np.max(np.abs(traj(tc, 1)[:, :n]) / limits.velocity, axis=0)
        ar = np.max(np.abs(traj(tc, 2)[:, :n]) / limits.acceleration, axis=0)
        if tool is not None:
            tool_ratio = tuple(np.max(tool.rates(traj(tc, 0)[:, :n], traj(tc, 1)[:, :n])
                                      / tool.vmax, axis=0))
        peaks = np.array([vr.max(), ar.max(), 0.0 if tool_ratio is None else max(tool_ratio)])
        if np.all(peaks <= 1.0):
            break
        # those families over their limit between the grid points: their scale down
        over = peaks > 1.0
        scales[over] *= np.minimum(0.99, SCALE_MARGIN / peaks[over])
    else:
        raise SurestepError(f"toppra found no trajectory within the limits in {MAX_TRIES} tries "
                            "(the limits handed to it scaled down to "
                            f"{', '.join(f'{x:.3g}' for x in scales)})")
    return traj, scales, times, wp_t, vr, ar, tool_ratio
