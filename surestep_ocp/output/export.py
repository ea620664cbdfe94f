"""`surestep export SOLUTION.json --format csv|json|ros2|rosbag2 --output F`: a
time-stamped joint trajectory.

The command: the solution read (`export_load.py`), its waypoints timed within its motion limits
(`model/limits/retiming.py`: the planned curve at the planned times when within them, else toppra's
retiming) and written (`export_writers.py`; the bag: `export_rosbag.py`, its options checked by
`export_setpoints.py`) with the joints named for the consumer (`joint_names.py`), and
`<name>_motion.png` beside it (`plots_motion.py`; named after the whole output name, so `bag.1` and
`bag.2` never share one). The files of one export are written all or none
(`files.written_together`).
`time_parametrise` and `within_position_limits` stay importable from here (the benchmarks import
them, in older trees too).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..arguments import real_number
from ..errors import SurestepError, shown
from ..model.limits import JAW, parse_overrides
from .export_setpoints import DEFAULT_ARM, check_arm, check_setpoint_rate
from .export_load import limits_of, load_solution, solution_label, step_of, within_position_limits
from ..model.limits.retiming import DEFAULT_RATE_HZ, TIMINGS, Trajectory, time_parametrise
from .export_writers import FORMATS, channels, jaw_path, timing_text, write
from .joint_names import PRESETS, joint_naming
from .plots_motion import plot_trajectory
from ..model.robot import Robot
from ..problem.paths import resolve_urdf
from ..quiet import quiet_fd
from .files import (MAX_URDF_BYTES, check_new_dir, check_output_file, input_file_problem,
                    named_path, written_together)

if TYPE_CHECKING:
    from .solution import Solution

__all__ = ["export_solution", "summary", "register", "time_parametrise", "within_position_limits",
           "Trajectory"]


def export_solution(solution: str | Path | Solution, fmt: str, output: str | Path, *,
                    rate_hz: float = DEFAULT_RATE_HZ, step_s: float | None = None,
                    velocity: dict | None = None,
                    acceleration: dict | None = None, tool_speed: float | None = None,
                    tool_rotation: float | None = None, plot: bool = True, timing: str = "auto",
                    joint_names: str | None = None,
                    arm: str | None = None) -> tuple[Trajectory, list[Path]]:
    """Export the plan in `solution` (a solution file, or a `Solution` object; module docstring);
    `joint_names`: `--joint-names` (`joint_names.py`); `arm`: the bag's arm name (rosbag2 only,
    default PSM1). Returns the trajectory and the files written."""
    if fmt not in FORMATS:
        raise SurestepError(f"unknown format '{fmt}'; allowed: {', '.join(FORMATS)}")
    rate_hz = real_number(rate_hz, "export: rate_hz")
    step_s, tool_speed, tool_rotation = (
        None if v is None else real_number(v, f"export: {k}")
        for k, v in (("step_s", step_s), ("tool_speed", tool_speed),
                     ("tool_rotation", tool_rotation)))
    if arm is not None and fmt != "rosbag2":
        raise SurestepError("--arm names the bag's topics: it applies to --format rosbag2 only, "
                            f"not {fmt}")
    if fmt == "rosbag2":
        arm = check_arm(DEFAULT_ARM if arm is None else arm)
    sol = load_solution(solution)
    label = solution_label(solution)
    inputs = [] if hasattr(solution, "to_dict") else [solution]  # the files read: never an output
    names = list(sol["joint_names"])
    naming = joint_naming(joint_names, [n for n in names if n != JAW],
                          [n for n in names if n == JAW])
    urdf = resolve_urdf(str(sol["robot"].get("urdf", "")))
    check_urdf_file(urdf, f"{label}: robot.urdf {shown(str(sol['robot'].get('urdf')), 120)}")
    for flag, x in (("--tool-speed", tool_speed), ("--tool-rotation-speed", tool_rotation)):
        if x is not None and not (math.isfinite(x) and x > 0):
            raise SurestepError(f"{flag} must be a positive number, got {x:g}")
    output = named_path(output, "the export", "directory" if fmt == "rosbag2" else "file")
    if output.name in ("", ".", ".."):  # (its side files are named after it)
        raise SurestepError(f"{shown(str(output), 200)}: no name at its end; the export must be "
                            f"a named {'directory' if fmt == 'rosbag2' else 'file'}")
    targets = (([] if fmt == "rosbag2" else [output])
               + ([jaw_path(output)] if fmt == "ros2" else [])
               + ([motion_png(output)] if plot else []))
    if fmt == "rosbag2":  # a new (or empty) directory, written whole
        check_new_dir(output, inputs=[*inputs, urdf], what="the bag")
    for path in targets:
        # before any work: never the solution or the URDF read here, never a folder or a device
        check_output_file(path, inputs=[*inputs, urdf], what="the export")
    frame = str(sol["robot"].get("frame") or "tool")
    try:
        with quiet_fd(2):
            # urdfdom prints parse errors on stderr; the error below says it in one line
            robot = Robot(urdf, frame=frame)
    except (ValueError, RuntimeError, OSError, SurestepError) as exc:
        raise SurestepError(
            f"{label}: robot.urdf {shown(str(urdf), 120)}: cannot load it "
            f"({shown(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, 160)})"
        ) from None
    try:
        limits = limits_of(sol, urdf, velocity, acceleration, tool_speed, tool_rotation)
    except SurestepError as exc:
        raise SurestepError(f"{label}: {exc}") from None
    step, step_source = step_of(sol, step_s)
    if robot.joint_names != list(sol["joint_names"]):
        raise SurestepError(f"{label}: joint_names {', '.join(sol['joint_names'])} are not those "
                            f"of {urdf}")
    q, clipped = within_position_limits(np.array(sol["q"], float), robot)
    traj = time_parametrise(q, step, limits, rate_hz, robot=robot, tool_frame=frame, timing=timing)
    if fmt == "rosbag2":
        check_setpoint_rate(traj, rate_hz, len(q) - 1)
    meta = {"source": label, "method": sol.get("method"), "problem": sol.get("problem"),
            "robot": {"urdf": sol["robot"].get("urdf"), "frame": sol["robot"].get("frame")},
            "step_s_source": step_source,
            "limits_enforced_in_plan": (sol.get("limits") or {}).get("enforce"),
            "waypoints_clipped_by": clipped, "joint_naming": naming.to_dict()}
    bag = {"rate_hz": rate_hz, "arm": arm} if fmt == "rosbag2" else {}
    return traj, _write_all(traj, fmt, output, meta, naming, bag, (sol, urdf) if plot else None)


def motion_png(output: Path) -> Path:
    """The export's figure beside it: `<output's whole name>_motion.png`."""
    return output.with_name(f"{output.name}_motion.png")


def _write_all(traj: Trajectory, fmt: str, output: Path, meta: dict, naming, bag: dict,
               plot: tuple | None) -> list[Path]:
    """The export's files (and its figure when `plot` is (solution, urdf)) written all or none;
    the paths written."""
    jaw = fmt == "ros2" and bool(channels(traj)[1])
    targets = ([output] + ([jaw_path(output)] if jaw else [])
               + ([motion_png(output)] if plot else []))
    with written_together(targets, "the export") as staged:
        write(traj, fmt, staged[output], meta, naming, **bag)
        if plot:
            plot_trajectory(traj, plot[0], plot[1], staged[motion_png(output)])
    return targets


def check_urdf_file(urdf: Path, name: str) -> None:
    """A one-line error unless `urdf` can be read as a URDF (`files.input_file_problem`)."""
    try:
        problem = input_file_problem(urdf, MAX_URDF_BYTES)
    except OSError:
        raise SurestepError(f"{name}: not found ({shown(str(urdf), 120)})") from None
    if problem is not None:
        raise SurestepError(f"{name}: {problem}; a URDF file is read")


def summary(traj: Trajectory) -> str:
    planned = traj.step_s * (len(traj.waypoint_times) - 1)
    jv, ja = int(np.argmax(traj.peak_velocity_ratio)), int(np.argmax(traj.peak_acceleration_ratio))
    lines = [
        f"duration    {traj.duration:.3f} s ({len(traj.times)} samples; planned {planned:.3f} s at "
        f"{traj.step_s:g} s per step)",
        (f"velocity    peak {traj.peak_velocity_ratio[jv]:.3f} of the limit "
         f"({traj.joint_names[jv]})"),
        (f"accel.      peak {traj.peak_acceleration_ratio[ja]:.3f} of the limit "
         f"({traj.joint_names[ja]})"),
    ]
    if traj.peak_tool_ratio is not None:
        lim = traj.limits
        lines.append(f"tool        peak {traj.peak_tool_ratio[0]:.3f} of {1e3 * lim.tool_speed:g} "
                     f"mm/s, {traj.peak_tool_ratio[1]:.3f} of {lim.tool_rotation:.3g} rad/s "
                     f"({traj.tool_frame})")
    lines.append(f"timing      {timing_text(traj)}")
    lines.append(f"limits      {traj.limits.sources.get('recorded', '')}")
    low = {k: v for k, v in traj.scales.items() if v < 1}
    if low:
        scaled = ", ".join(f"{v:.3g} ({k})" for k, v in low.items())
        lines.append(f"note        toppra was given the limits scaled by {scaled} so that the "
                     "samples between its grid points stay within them")
    return "\n".join(lines)


def cmd_export(args) -> int:
    traj, files = export_solution(
        args.solution, args.format, args.output, rate_hz=args.rate, step_s=args.step_s,
        velocity=parse_overrides(args.velocity_limit, "--velocity-limit"),
        acceleration=parse_overrides(args.acceleration_limit, "--acceleration-limit"),
        tool_speed=args.tool_speed, tool_rotation=args.tool_rotation_speed, plot=not args.no_plot,
        timing=args.timing, joint_names=args.joint_names, arm=args.arm)
    print(summary(traj))
    for f in files:
        print(f"wrote       {f}")
    return 0


def register(sub) -> None:
    """The `export` subcommand (surestep_ocp/cli.py)."""
    e = sub.add_parser("export", help="time-parametrise a solution's joint plan within its motion "
                                      "limits and write it as CSV, JSON, a ROS 2 JointTrajectory "
                                      "(YAML) or a ROS 2 bag")
    e.add_argument("solution", metavar="SOLUTION.json", help="a solution file (surestep solve "
                   "--output, or one of surestep compare's <method>.json)")
    e.add_argument("--format", required=True, choices=FORMATS,
                   help="csv, json, ros2 (a trajectory_msgs/JointTrajectory as YAML) or rosbag2 (a "
                        "bag directory for `ros2 bag play`; docs/motion_limits_and_export.md)")
    e.add_argument("--output", "-o", required=True, help="file to write (ros2: the jaw goes to "
                   "<stem>_jaw<suffix>; rosbag2: a new or empty directory)")
    e.add_argument("--rate", type=float, default=DEFAULT_RATE_HZ, help="samples per second "
                   "(default 100; every waypoint's time is a sample too; rosbag2: the servo_jp "
                   "set-points' rate)")
    e.add_argument("--joint-names", metavar="PRESET|NAMES",
                   help=f"the joint names written: {', '.join(PRESETS)} (outer_yaw, ..., "
                        "outer_wrist_yaw: the dVRK's ROS model and older kinematics files) or 6 "
                        "comma-separated names (default: dvrk, the dVRK's current kinematics "
                        "files' yaw, ..., wrist_yaw; other robots: their URDF's names)")
    e.add_argument("--arm", metavar="NAME", help="rosbag2: the arm's name in the topics, "
                   "/NAME/servo_jp ... (default: PSM1)")
    e.add_argument("--step-s", type=float, help="seconds per planned step (default: the solution's "
                   "timing.step_s, else 0.05)")
    e.add_argument("--velocity-limit", action="append", metavar="JOINT=V",
                   help="override a joint's velocity limit [rad/s or m/s] (default: the solution's "
                        "recorded limits, i.e. its problem's limits: section, else the URDF's); "
                        "repeatable")
    e.add_argument("--acceleration-limit", action="append", metavar="JOINT=A",
                   help="override a joint's acceleration limit [rad/s^2 or m/s^2] (default: the "
                        "solution's recorded limits, else the dVRK's move_jp values, "
                        "docs/motion_limits_and_export.md); repeatable")
    e.add_argument("--tool-speed", type=float, metavar="M_S",
                   help="override the tool's translation speed limit [m/s] (default: the recorded "
                        "one, else 0.1)")
    e.add_argument("--tool-rotation-speed", type=float, metavar="RAD_S",
                   help="override the tool's rotation speed limit [rad/s] (default: the recorded "
                        "one, else pi/2)")
    e.add_argument("--timing", choices=TIMINGS, default="auto",
                   help="auto: the planned curve at the planned times when it is within every "
                        "limit (a plan made with limits.enforce: true), else retimed by toppra; "
                        "planned: that curve or an error; toppra: always retimed (default: auto)")
    e.add_argument("--no-plot", action="store_true", help="do not write <name>_motion.png beside "
                   "the output")
    e.set_defaults(func=cmd_export)
