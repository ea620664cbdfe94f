"""The Python API's entry points beside `Problem`, `Solution` and `Planner`: load or
build, solve, export.

    import surestep_ocp as ss
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_goal(
        pose=[0.035, -0.01, 0.11, 0.6, 0.1, 1.4])
    sol = ss.solve(problem, method="ocp")
    # (T+1, nq) [rad, m], (T+1, 3) [m], (T+1, 6, 6) [m^2, rad^2]
    sol.joints, sol.positions, sol.covariances
    traj, files = ss.export(sol, "ros2", "out/plan.yaml")   # as `surestep export`
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from .errors import SurestepError
from .method_grammar import grammar
from .problem.spec import Problem
from .output.solution import Solution

if TYPE_CHECKING:
    from .model.limits.retiming import Trajectory


def solve(problem: Problem, method: str = "ocp") -> Solution:
    """Plan `problem` with a method: `baseline`, `gradient`, `gradient-no-pose-loss`, `ocp`,
    `ocp-from-gradient` (optionally `-no-depth`, `-no-fov`, `-no-orientation`, then `-expected`,
    then `-predicted`; docs/method.md, "The methods").

    The OCP's solver settings are the problem's (`problem.with_solver(name="ipopt")`). Check
    `sol.success`: a solver failure returns a Solution with its `status`. Raises
    ProblemError (naming the key) when the problem cannot be set up (an unreachable goal,
    joints outside their limits).
    """
    if not isinstance(method, str):
        raise SurestepError("solve: method must be a method name (a string), "
                            f"got {type(method).__name__}; {grammar()}")
    from .methods.registry import run_method
    from .problem.setup import build_setup

    return run_method(build_setup(problem), method)


def export(solution: Solution | str | Path, format: str, output: str | Path, *,
           rate_hz: float = 100.0,
           joint_names: str | None = None, timing: str = "auto", step_s: float | None = None,
           velocity: dict[str, float] | None = None, acceleration: dict[str, float] | None = None,
           tool_speed: float | None = None, tool_rotation_speed: float | None = None,
           arm: str | None = None, plot: bool = False) -> tuple[Trajectory, list[Path]]:
    """Write a plan as a time-stamped joint trajectory, as `surestep export` does
    (docs/motion_limits_and_export.md).

    Args:
        solution: a `Solution` (from `solve` or a `Planner`) or a solution file.
        format: `csv`, `json`, `ros2` (a JointTrajectory as YAML, the jaw beside it) or `rosbag2` (a
            bag directory for `ros2 bag play`: `/PSM1/servo_jp`).
        output: the file to write (rosbag2: a new or empty directory).
        rate_hz: samples per second [Hz] (rosbag2: the servo_jp set-points' rate).
        joint_names: `dvrk` (the default for the PSM), `dvrk-ros-model`, or 6 comma-separated names.
        timing: `auto` (the planned curve when within every limit, else toppra's retiming),
            `planned` or `toppra`.
        step_s: seconds per planned step (default: the solution's `timing.step_s`).
        velocity, acceleration: per-joint limit overrides {joint name: [rad/s or m/s],
            [rad/s^2 or m/s^2]}.
        tool_speed, tool_rotation_speed: the tool's limits [m/s], [rad/s]
            (default: the recorded ones).
        arm: the bag's arm name in its topics (rosbag2 only; default PSM1).
        plot: also write `<output name>_motion.png` beside the output (the command
            line's default; here off).

    Returns:
        The trajectory (`times` [s], `q`, `qd`, `qdd` [rad or m, per s, per s^2], `joint_names`,
        ...) and the files written. Raises SurestepError (one line) on a bad value or an output
        that cannot be written.
    """
    from .output.export import export_solution

    return export_solution(solution, format, output, rate_hz=rate_hz, step_s=step_s,
                           velocity=velocity, acceleration=acceleration, tool_speed=tool_speed,
                           tool_rotation=tool_rotation_speed, plot=plot, timing=timing,
                           joint_names=joint_names, arm=arm)
