"""How the simulated robot runs a plan: at its planned pace, or no faster than the tool's speed
limits.

A plan is one waypoint per step of `timing.step_s`. At the planned pace (`planned`, the paper's
protocol) a rollout executes one plan step per rollout step, however large. A dVRK cannot take the
plans' largest steps in 0.05 s (docs/evaluation.md, "Running the plans at the robot's pace"): its
controller would run them more slowly, and the tracker would keep observing meanwhile. At `limits`
pace each plan step is split into the fewest equal rollout steps of `step_s` each (one observation
each, as every rollout step) for which the tool moves no faster than `MotionLimits.tool_speed` and
turns no faster than `tool_rotation`: the position linearly, the orientation along the geodesic
(`baseline.straight_line` on each step), so the path is the plan's between its waypoints. A step
within both limits is left as it is; a plan within them is rolled out exactly as at the planned
pace.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from ..ocp.straight_line import straight_line

PACES = ("planned", "limits")


def substeps(poses: np.ndarray, step_s: float, tool_speed: float,
             tool_rotation: float) -> np.ndarray:
    """(T,) the number of rollout steps each plan step takes at the tool's limits (>= 1)."""
    P = np.asarray(poses, float)
    R = Rotation.from_rotvec(P[:, 3:])
    move = np.linalg.norm(np.diff(P[:, :3], axis=0), axis=1)
    turn = (R[:-1].inv() * R[1:]).magnitude()
    need = np.maximum(move / (tool_speed * step_s), turn / (tool_rotation * step_s))
    # a step exactly at a limit (to rounding) is not split
    return np.maximum(1, np.ceil(need * (1 - 1e-9))).astype(int)


def paced(poses: np.ndarray, step_s: float, tool_speed: float, tool_rotation: float) -> np.ndarray:
    """(T' + 1, 6) waypoints of the plan run no faster than the tool's limits (`poses` when
    T' = T)."""
    P = np.asarray(poses, float)
    if not (step_s > 0 and tool_speed > 0 and tool_rotation > 0) or not all(map(math.isfinite, (
            step_s, tool_speed, tool_rotation))):
        raise ValueError(f"pacing needs a positive step and tool limits, got step_s={step_s}, "
                         f"tool_speed={tool_speed}, tool_rotation={tool_rotation}")
    k = substeps(P, step_s, tool_speed, tool_rotation)
    if np.all(k == 1):
        return P
    out = [P[:1]]
    # the baseline's interpolation, on each step: position linear, shortest rotation
    for t, kt in enumerate(k):
        seg = straight_line(P[t], P[t + 1], int(kt))[1:]
        # the waypoint itself (the continued rotation vector may be its other-side twin)
        seg[-1] = P[t + 1]
        out.append(seg)
    return np.vstack(out)
