"""The motion a node commands: each plan's played curve from its start waypoint until the next
plan's start, then held at the last plan's goal.

A re-plan from waypoint k starts from the executed curve's state at k (joints, velocity,
acceleration: `Planner.replan` within the limits), so switching plans exactly at k keeps the
commanded motion twice continuously differentiable and within every limit each plan keeps; the
servo stream samples this, never a blend. No DDS here.
"""

from __future__ import annotations

import threading

import numpy as np

from ..model.limits import evaluate_curve


class PlayedCurve:
    """Pieces (start waypoint, waypoints (n+1, nq), start (velocity, acceleration) or None at rest)
    at a step of `dt` seconds; `sample(t)` is the commanded (position, velocity) at time t [s] from
    waypoint 0. Thread-safe: the planner adds, the servo loop samples."""

    def __init__(self, dt: float, q, start=None):
        self.dt = float(dt)
        self._lock = threading.Lock()
        self._pieces = [(0, np.array(q, float), start)]
        self._sampled = -np.inf  # the latest time `sample` was asked for with `commit`
        self.version = 0  # counts the changes (add, reset): what was sampled before is stale

    def add(self, step: int, q, start) -> bool:
        """A plan from waypoint `step` (it replaces any piece starting there or later); False
        (not added) when a time after that waypoint was sampled already: the switch would not be
        at the waypoint. (A sample at the waypoint itself is the same from either plan.)"""
        piece = (int(step), np.array(q, float),
                 None if start is None else (np.asarray(start[0], float),
                                             np.asarray(start[1], float)))
        with self._lock:
            if self._sampled > piece[0] * self.dt + 1e-9:
                return False
            self._pieces = [p for p in self._pieces if p[0] < piece[0]] + [piece]
            self.version += 1
            return True

    def reset(self, q) -> None:
        """A new motion from rest (`Planner.restart`): `q` alone, from waypoint 0 of a new time
        origin (the caller's), nothing sampled on it yet."""
        with self._lock:
            self._pieces = [(0, np.array(q, float), None)]
            self._sampled = -np.inf
            self.version += 1

    def pieces(self) -> list:
        with self._lock:
            return list(self._pieces)

    def piece_at(self, t: float) -> tuple:
        """The piece playing at time t (the last one started at or before it)."""
        with self._lock:
            return self._piece_at(t)

    def _piece_at(self, t: float) -> tuple:
        pieces = self._pieces
        for p in reversed(pieces):
            if p[0] * self.dt <= t + 1e-9:
                return p
        return pieces[0]

    @property
    def end_time(self) -> float:
        """[s] when the last plan reaches its goal."""
        step, q, _ = self.pieces()[-1]
        return (step + len(q) - 1) * self.dt

    def sample(self, t: float, commit: bool = False) -> tuple[np.ndarray, np.ndarray, int]:
        """(position, velocity, the playing piece's start waypoint) at time t; after the goal, the
        goal at rest. `commit`: the sample is sent (no plan is added before t from now on)."""
        if commit:
            with self._lock:
                self._sampled = max(self._sampled, t)
                step, q, start = self._piece_at(t)
        else:
            step, q, start = self.piece_at(t)
        tau = t - step * self.dt
        if tau >= (len(q) - 1) * self.dt:
            return q[-1].copy(), np.zeros(q.shape[1]), step
        p, v, _ = evaluate_curve(q, self.dt, np.array([max(tau, 0.0)]), start=start)
        return p[0], v[0], step

    def knots(self, step: int, q, start) -> tuple[np.ndarray, np.ndarray]:
        """(velocities, accelerations) of a piece at its waypoints (for the plan message)."""
        times = np.arange(len(q)) * self.dt
        _, v, a = evaluate_curve(np.asarray(q, float), self.dt, times, start=start)
        return v, a
