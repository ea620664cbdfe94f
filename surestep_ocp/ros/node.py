"""`surestep serve`'s node: the DDS endpoints, the node's loop and the fail-safe.

The node is two processes. The servo process (servo.py, its own DDS participant) publishes
`/ARM/servo_jp` and `/ARM/jaw/servo_jp` every 1/servo_hz s, sampled from the played curve
(played.PlayedCurve) at the tick's time and stamped with it; a tick found late by more than a
period is skipped, not sent late. This one, the planner process, has the other topics: its main
thread (loop.py) takes the servo process's report of each set-point sent, reads the arm's (and the
ECM's) measured joints and checks the faults (faults.Watchdog); the re-planning thread
(replanner.Replanner) waits for the tracker and hands each new plan's piece to the servo process.
On a fault the node holds: the servo process sends no more set-points (the arm keeps its last
one), the reason on stderr and on the status topic.
"""

from __future__ import annotations

import bisect
import sys
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.util import duration

from . import messages as m
from .dds import Bus
from .faults import FaultLimits, Watchdog
from .replanner import Replanner, Shared

STATUS_PERIOD_S = 0.5


@dataclass
class Topics:
    """The node's ROS 2 topics (fully qualified)."""

    measured: str
    jaw_measured: str
    ecm_measured: str
    tracker: str
    servo: str
    jaw_servo: str
    plan: str
    trace: str
    planned_trace: str
    confidence: str
    status: str
    goal: str

    @classmethod
    def of(cls, arm: str, tracker: str, namespace: str) -> "Topics":
        ns = namespace.rstrip("/")
        return cls(f"/{arm}/measured_js", f"/{arm}/jaw/measured_js", "/ECM/measured_js", tracker,
                   f"/{arm}/servo_jp", f"/{arm}/jaw/servo_jp", f"{ns}/plan", f"{ns}/trace",
                   f"{ns}/planned_trace", f"{ns}/confidence", f"{ns}/status", f"{ns}/goal")


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


class Endpoints:
    """The node's readers and writers on one participant (nothing is written on creation)."""

    def __init__(self, domain: int, topics: Topics):
        self.bus = bus = Bus(domain)
        self.topics = topics
        self.measured = bus.reader(topics.measured, m.JointState, depth=50)
        self.jaw_measured = bus.reader(topics.jaw_measured, m.JointState, depth=50)
        self.ecm = bus.reader(topics.ecm_measured, m.JointState, depth=5)
        self.tracker = bus.reader(topics.tracker, m.PoseWithCovarianceStamped, depth=10)
        self.goal = bus.reader(topics.goal, m.PoseStamped, depth=5)
        self.plan = bus.writer(topics.plan, m.JointTrajectory)
        self.trace = bus.writer(topics.trace, m.Float64)
        self.planned_trace = bus.writer(topics.planned_trace, m.Float64)
        self.confidence = bus.writer(topics.confidence, m.Float64)
        self.status = bus.writer(topics.status, m.String)
        self._waitset = WaitSet(bus.participant)
        self._waitset.attach(ReadCondition(self.tracker, SampleState.Any | ViewState.Any
                                           | InstanceState.Any))

    def wait_tracker(self, timeout_s: float = 0.1) -> list:
        """The tracker's new samples, waiting up to `timeout_s` for one."""
        self._waitset.wait(duration(milliseconds=int(timeout_s * 1e3)))
        return Bus.take(self.tracker)


class Measured:
    """The arm's measured joints (in the plan's order) as they arrive: the latest, and a short
    history by stamp for the estimate's joints at its image time."""

    def __init__(self, names: list[str], aliases: dict[str, str]):
        self.names, self.aliases = names, aliases
        self.history: deque = deque(maxlen=400)  # (stamp [ns since the epoch], q)
        self.latest: np.ndarray | None = None
        self.arrived = 0.0  # monotonic

    def update(self, msgs) -> None:
        for msg in msgs:
            q = self.order(msg)
            if q is None:
                continue
            self.latest, self.arrived = q, time.monotonic()
            self.history.append((m.stamp_ns(msg.header.stamp), q))

    def order(self, msg) -> np.ndarray | None:
        """The message's positions in `names` order (by name when it names them all, else by
        position); None when too short or not finite."""
        pos = list(msg.position)
        named = {self.aliases.get(n, n): p for n, p in zip(msg.name, pos)}
        if all(n in named for n in self.names):
            q = np.array([named[n] for n in self.names], float)
        elif len(pos) >= len(self.names):
            q = np.array(pos[:len(self.names)], float)
        else:
            return None
        return q if np.all(np.isfinite(q)) else None

    def at(self, t: float, t0_wall_ns: int = 0) -> np.ndarray | None:
        """The joints at stamp time t [s after t0_wall_ns], linearly between the two samples
        around it (None without a sample within 50 ms)."""
        hist = list(self.history)
        if not hist:
            return None

        def ts(j: int) -> float:
            return (hist[j][0] - t0_wall_ns) * 1e-9

        i = bisect.bisect_left(hist, t0_wall_ns + t * 1e9, key=lambda h: h[0])
        if i == 0 or i == len(hist):
            j = min(i, len(hist) - 1)
            return hist[j][1] if abs(ts(j) - t) <= 0.05 else None
        w = (t - ts(i - 1)) / max(ts(i) - ts(i - 1), 1e-9)
        return (1 - w) * hist[i - 1][1] + w * hist[i][1]


def joint_message(stamp_ns: int, names, q, v) -> m.JointState:
    return m.JointState(header=m.Header(stamp=m.stamp(stamp_ns), frame_id=""), name=list(names),
                        position=[float(x) for x in q], velocity=[float(x) for x in v], effort=[])


def plan_message(stamp_ns: int, names, q, v, a, dt: float) -> m.JointTrajectory:
    pts = []
    for i in range(len(q)):
        ns = round(i * dt * 1e9)
        pts.append(m.JointTrajectoryPoint(
            positions=[float(x) for x in q[i]], velocities=[float(x) for x in v[i]],
            accelerations=[float(x) for x in a[i]], effort=[],
            time_from_start=m.Duration(sec=ns // 10**9, nanosec=ns % 10**9)))
    return m.JointTrajectory(header=m.Header(stamp=m.stamp(stamp_ns), frame_id=""),
                             joint_names=list(names), points=pts)


def make_watchdog(limits: FaultLimits, setup) -> Watchdog:
    """A watchdog over the arm joints (the plan's joints less the jaw): prismatic ones in m."""
    names = list(setup.robot.joint_names)
    arm = [n for n in names if n != "jaw"]
    prismatic = np.array([n == "insertion" for n in arm])
    return Watchdog(limits, prismatic)


def build_replanner(planner, played, shared: Shared, ep: Endpoints, measured: Measured,
                    camera_pose, opts, on_plan, on_fail, on_estimate, first,
                    servo) -> Replanner:
    """The re-planning thread over the node's endpoints."""
    arm_n = len(measured.names)

    def measured_at(t_s, q_cmd):
        q = measured.at(t_s, shared.t0_wall_ns)
        if q is None:
            return q_cmd
        out = np.array(q_cmd, float)
        out[:arm_n] = q
        return out

    return Replanner(planner, played, shared, ep.wait_tracker, measured_at, camera_pose,
                     opts.replan_margin_s, 1.0 / opts.servo_hz, on_plan, on_fail, on_estimate,
                     opts.faults.estimate_timeout_s, first, servo)
