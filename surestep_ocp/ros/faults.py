"""The node's fail-safe: what makes it hold the last set-point (stop publishing motion), each with
its reason. No DDS here; the node feeds it times and joints.

- the tracker silent for longer than `estimate_timeout_s` while moving;
- an estimate that is not finite;
- the arm's measured joints silent for longer than `estimate_timeout_s` while moving, or away from
  every set-point commanded within the last `window_s` by more than the tolerance (revolute joints
  in rad, the insertion in m);
- `max_failures` re-plans in a row that failed (or came too late to be played).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass
class FaultLimits:
    estimate_timeout_s: float = 0.5
    tolerance_rad: float = 0.05
    tolerance_m: float = 0.005
    window_s: float = 0.1  # the robot lags its set-points by up to this
    max_failures: int = 5


class Watchdog:
    """The first fault seen (`reason`, None while all is well) and its time."""

    def __init__(self, limits: FaultLimits, prismatic: np.ndarray):
        self.limits = limits
        tol = np.where(prismatic, limits.tolerance_m, limits.tolerance_rad)
        self._tol = np.asarray(tol, float)
        self._commands: deque = deque()  # (time, arm set-point) within the window
        self.reason: str | None = None
        self.at: float | None = None
        self.failures = 0

    def trip(self, reason: str, now: float) -> bool:
        """Record a fault (the first one stays); True if it is new."""
        if self.reason is None:
            self.reason, self.at = reason, now
            return True
        return False

    def clear(self) -> None:
        """All well again (a resume): no fault, no failures, no set-points in the window."""
        self.reason = self.at = None
        self.failures = 0
        self._commands.clear()

    def commanded(self, now: float, q) -> None:
        self._commands.append((now, np.asarray(q, float)))
        while self._commands and self._commands[0][0] < now - self.limits.window_s:
            self._commands.popleft()

    def check_tracking(self, now: float, measured) -> bool:
        """A fault if the measured arm joints are beyond the tolerance of every recent set-point."""
        if not self._commands:
            return False
        m = np.asarray(measured, float)
        err = np.max(np.abs(np.array([q for _, q in self._commands]) - m) / self._tol, axis=1)
        worst = int(np.argmax(np.abs(m - self._commands[-1][1]) / self._tol))
        if err.min() > 1.0:
            off = m[worst] - self._commands[-1][1][worst]
            return self.trip(f"measured joints left the commanded curve (joint {worst} off by "
                             f"{off:+.4g}, tolerance {self._tol[worst]:g})", now)
        return False

    def check_silence(self, now: float, last_estimate: float, last_measured: float) -> bool:
        lim = self.limits.estimate_timeout_s
        if now - last_estimate > lim:
            return self.trip(f"tracker silent for {now - last_estimate:.3f} s (limit {lim:g} s)",
                             now)
        if now - last_measured > lim:
            return self.trip(f"measured_js silent for {now - last_measured:.3f} s "
                             f"(limit {lim:g} s)", now)
        return False

    def replan_failed(self, why: str, now: float) -> bool:
        self.failures += 1
        if self.failures >= self.limits.max_failures:
            return self.trip(f"{self.failures} re-plans in a row failed (last: {why})", now)
        return False

    def replan_ok(self) -> None:
        self.failures = 0
