"""One toppra run (`run_toppra`, behind `retiming.toppra_run`) and the tool-speed bound it is
given (`tool_speed_constraint`): the only module that imports toppra, loaded on first use, since
toppra is slow to import (the CLI starts without it).
"""

from __future__ import annotations

import logging

import numpy as np
import toppra.algorithm as algo
import toppra.constraint as constraint
from toppra.constraint import DiscretizationType, LinearConstraint

from .values import MotionLimits


def run_toppra(path, grid: np.ndarray, limits: MotionLimits, scales: np.ndarray, clock_v: float,
               clock_a: float, tool=None):
    """One toppra run along `path` (an `retiming.PchipPath`, its last joint the path parameter,
    within `clock_v`, `clock_a`) from rest to rest, within `limits` scaled per family by `scales`
    (joint velocity, joint acceleration, tool speed; `tool`: an `retiming.ToolSpeed` or None):
    toppra's trajectory, or None when it finds none."""
    logging.getLogger("toppra").setLevel(logging.ERROR)  # a failed try is retried: noise
    vmax = np.append(scales[0] * limits.velocity, clock_v)
    amax = np.append(scales[1] * limits.acceleration, clock_a)
    cons = [constraint.JointVelocityConstraint(np.column_stack([-vmax, vmax])),
            constraint.JointAccelerationConstraint(np.column_stack([-amax, amax]))]
    if tool is not None:
        cons.append(tool_speed_constraint(tool, path, scales[2]))
    inst = algo.TOPPRA(cons, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
    return inst.compute_trajectory(0.0, 0.0)


def tool_speed_constraint(tool, path, scale: float) -> LinearConstraint:
    """A toppra velocity constraint: `s_dot^2 <= min_i (scale * vmax_i / rate_i(s))^2` at every
    grid point (`ToolSpeed.rates`)."""
    n = tool.robot.nq

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
