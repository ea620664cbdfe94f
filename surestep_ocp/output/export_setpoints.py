"""The set-point stream of `surestep export --format rosbag2` before anything is written: the arm's
name (`--arm`) and its topics, the rate's check against the plan's steps, and the sample of each
tick (`export_rosbag.py` writes the bag; this module is light, so the command checks its options
without loading rosbags).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..errors import SurestepError, shown
from ..model.limits.retiming import Trajectory

DEFAULT_ARM = "PSM1"
ARM_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
# a sample this close to a tick is the tick's (the export samples every tick, `_sample_times`)
SNAP_S = 1e-9


def topics(arm: str) -> dict[str, str]:
    """The bag's topics by role."""
    return {"servo_jp": f"/{arm}/servo_jp", "jaw_servo_jp": f"/{arm}/jaw/servo_jp",
            "trajectory": f"/{arm}/trajectory", "jaw_trajectory": f"/{arm}/jaw/trajectory"}


def check_arm(arm: str) -> str:
    if not ARM_NAME.match(arm):
        raise SurestepError(f"--arm: '{shown(arm)}' is not an arm name (a letter, then letters, "
                            f"digits, _; default {DEFAULT_ARM})")
    return arm


def check_setpoint_rate(traj: Trajectory, rate_hz: float, steps: int) -> None:
    """Refuse a rate too low to represent the plan: fewer set-point intervals over the motion than
    its planned steps (at --rate 0.5 one set-point stood for a whole 1 s motion of 20 steps)."""
    ticks = int(math.ceil(traj.duration * rate_hz - 1e-6))
    if ticks < steps:
        need = steps / traj.duration if traj.duration > 0 else math.inf
        raise SurestepError(f"--rate {rate_hz:g} Hz: the bag's servo_jp stream would hold {ticks} "
                            f"set-point step{'' if ticks == 1 else 's'} over the "
                            f"{traj.duration:.6g} s motion, fewer than its {steps} planned steps; "
                            f"give --rate at least {need:.6g} Hz")


def setpoint_rows(traj: Trajectory, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The set-points' ticks (k = 0..K, at k / rate_hz s) and the sample row of each: the
    exported sample at the tick, the last one from the trajectory's end on (K: the first
    tick at or after it)."""
    K = int(math.ceil(traj.duration * rate_hz - 1e-6))
    ticks = np.arange(K + 1)
    t = ticks / rate_hz
    rows = np.minimum(np.searchsorted(traj.times, t - SNAP_S), len(traj.times) - 1)
    inside = t < traj.duration - SNAP_S
    if np.any(np.abs(traj.times[rows[inside]] - t[inside]) > SNAP_S):
        # never expected: the export samples every tick
        raise SurestepError(f"internal: the exported samples miss a {rate_hz:g} Hz tick")
    rows[~inside] = len(traj.times) - 1
    return ticks, rows
