"""The problem `surestep serve` and `sim-robot` run, checked: re-planned within enforced limits on a
dVRK PSM (loaded by ros/commands.py once the options are checked)."""

from __future__ import annotations

from ..errors import SurestepError
from ..methods.registry import closed_loop_unavailable
from ..output.joint_names import PSM_ARM
from ..problem.load import load_problem
from ..problem.setup import build_setup


def served_problem(path: str):
    """The problem and its setup, if the node can re-plan it (within enforced limits, a PSM)."""
    prob = load_problem(path)
    setup = build_setup(prob)
    why = closed_loop_unavailable(setup)
    if why:
        raise SurestepError(f"{path}: cannot be served: {why}")
    names = [n for n in setup.robot.joint_names if n != "jaw"]
    if tuple(names) != PSM_ARM:
        raise SurestepError(f"{path}: cannot be served: the robot's joints ({', '.join(names)}) "
                            "are not a dVRK PSM's")
    return prob, setup
