"""The node's re-planning thread: each tracker estimate, as it arrives, becomes a re-plan from the
waypoint the robot reaches next, played from that waypoint on.

An estimate arriving at time t_a (since waypoint 0) is of the tool when its image was taken (its
stamp). The re-plan starts at the first waypoint k at or after t_a + lead (the waypoints are
phase-locked to the tracker's frames, `--replan-budget` after each arrival: loop.py), where the
lead is the recent re-plans' lower quartile time (at least `--replan-margin`): where most re-plans
would be late (a loaded machine) they aim at the waypoint after; a late one costs a frame, aiming
later always costs one. From the
played curve's state at k, with the estimate moved along the commanded motion from the stamp's
joints (the arm's measured ones) to k (estimate.moved). It runs on a copy of the Planner (as
closed_loop does); a plan that succeeded is handed to the servo process (servo.py), which plays it
from k only if no set-point after k was sent yet (played.PlayedCurve.add, decided where the
set-points are sent), else the plan before runs on (a failed one is counted by faults.Watchdog, a
late one is not: the plan it would have replaced is within the limits all the same). The trace
and the confidence of the estimate are published after the hand-over: nothing but the re-plan
stands between an estimate's arrival and its plan reaching the servo process.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..errors import SurestepError
from .estimate import from_message, moved


LEAD_WINDOW = 10  # re-plans whose times set the lead


@dataclass
class ReplanLog:
    """One re-plan: arrival and ready times [s since waypoint 0], its waypoint, its own time [s],
    and when its first set-point was published (filled in by the node's loop from the servo
    process's report). The stages between: `image` the estimate's stamp, `start` the re-plan's
    start (the estimate decoded and moved to waypoint `step`), `ready` the plan solved,
    `received` when the servo process had it, `handed` when its answer was back here."""

    arrival: float
    ready: float
    step: int
    replan_s: float
    ok: bool
    why: str = ""
    first_command: float | None = None
    epoch: int = 0  # the motion it belongs to (a restart begins a new one: loop.py)
    image: float | None = None
    start: float | None = None
    received: float | None = None
    handed: float | None = None
    # the Planner's real-time iteration: "feedback" or "full: <why>", its feedback phase's time
    # [s] (from the call until the joints were known), prepared between frames or in the call
    rti: str | None = None
    feedback_s: float | None = None
    prepared_ahead: bool | None = None
    prepare_s: float | None = None  # the preparation for the next frame, after this one [s]


@dataclass
class Shared:
    """What the re-planning thread and the servo loop share (each field written by one side)."""

    t0: float = 0.0  # monotonic time of waypoint 0
    t0_wall_ns: int = 0
    last_estimate: float = 0.0  # monotonic
    estimate: tuple | None = None  # (mean, covariance) of the last finite estimate
    fault: str | None = None  # set by the thread: a non-finite estimate
    fault_at: float | None = None  # monotonic: its arrival
    holding: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)
    logs: list = field(default_factory=list)
    estimates: int = 0
    skipped: int = 0  # estimates superseded by a newer one before their re-plan started
    # finite estimates arriving again (a resume's condition): the first arrival of the current
    # run of finite ones without a gap over the timeout (None after a non-finite one), the last
    finite_since: float | None = None
    last_finite: float = 0.0
    epoch: int = 0  # the current motion (its waypoint 0 at t0)
    # a restart (a new motion from rest, loop.py): (joints, goal or None, why) asked by the servo
    # loop; (solution or None, error, seconds, the request) back; `applied` once the loop took it
    restart_request: tuple | None = None
    restart_result: tuple | None = None
    applied: threading.Event = field(default_factory=threading.Event)


class Replanner(threading.Thread):
    """Waits for tracker estimates (`wait`, a callable returning the new samples), re-plans, hands
    each kept plan to `on_plan(step, solution)` and each failure to `on_fail(why)`."""

    def __init__(self, planner, played, shared: Shared, wait, measured_at, camera_pose,
                 margin_s: float, servo_period: float, on_plan, on_fail, on_estimate,
                 stale_s: float = 0.5, first=None, servo=None):
        super().__init__(name="surestep-replanner", daemon=True)
        self.planner, self.played, self.shared = planner, played, shared
        self.wait, self.measured_at, self.camera_pose = wait, measured_at, camera_pose
        self.margin_s, self.servo_period = margin_s, servo_period
        self.on_plan, self.on_fail, self.on_estimate = on_plan, on_fail, on_estimate
        self.stale_s, self.first = stale_s, first  # first: (samples, arrival) taken already
        self.servo = servo  # servo.ServoProcess (None: the played curve here is the one played)
        self.recent: deque = deque(maxlen=LEAD_WINDOW)  # the last re-plans' arrival-to-ready [s]
        self._ahead = None  # (epoch, played version, k, joints, pose) made ahead for waypoint k
        self._lead = None  # lead() until the next re-plan
        self.busy = threading.Event()  # a re-plan runs (from the frame's decoding to its hand-over)
        self.idle = threading.Event()  # the opposite: the node's loop waits for it (a while)
        self.idle.set()

    def run(self) -> None:
        sh = self.shared
        while not sh.stop.is_set():
            if sh.restart_request is not None:
                self._restart()
                continue
            if self.first is not None:
                (samples, arrival), self.first = self.first, None
            else:
                samples = self.wait()
                arrival = time.monotonic()
            if not samples or sh.stop.is_set():
                continue
            sh.estimates += len(samples)
            sh.skipped += len(samples) - 1
            msg = samples[-1]
            mean, cov, finite = from_message(msg)
            gap = arrival - sh.last_finite
            sh.last_estimate = arrival
            if not finite:
                sh.finite_since = None
                if sh.fault is None:
                    sh.fault, sh.fault_at = "tracker estimate not finite", arrival
                    if self.servo is not None and not sh.holding.is_set():
                        # held at once; the node's loop records the hold (its next look)
                        self.servo.send(("hold", sh.fault))
                continue
            if sh.finite_since is None or gap > self.stale_s:
                sh.finite_since = arrival
            sh.last_finite = arrival
            sh.estimate = (mean, cov)
            k = None
            if not sh.holding.is_set():
                self.busy.set()
                self.idle.clear()
                try:
                    k = self._replan(msg, mean, cov, arrival - sh.t0)
                finally:
                    self.busy.clear()
                    self.idle.set()
            self.on_estimate(mean, cov)  # after the hand-over: not in the latency
            if k is not None and not sh.holding.is_set():
                self._prepare(k + 1)

    def _prepare(self, k: int) -> None:
        """The real-time iteration's preparation (`Planner.prepare`) of the next frame's re-plan,
        at waypoint k (the one after this frame's: the frames are a step apart), between frames:
        that re-plan is then its feedback phase alone. A frame that aims elsewhere (a frame
        missed, a late lead) prepares within its re-plan (the Planner's own fall-back)."""
        pl = self.planner
        if not pl.step <= k < pl.horizon:
            return
        # what that re-plan needs before its estimate: its waypoint's joints and pose, the lead
        q_k = self.played.sample(k * self.played.dt)[0]
        self._ahead = (self.shared.epoch, self.played.version, k, q_k, pl.setup.pose_of(q_k))
        self._lead = None
        if not hasattr(pl, "prepare"):
            return
        try:
            took = pl.prepare(k)
        except SurestepError:
            return
        if self.shared.logs:
            self.shared.logs[-1].prepare_s = took

    def _at(self, k: int, setup) -> tuple:
        """(joints, pose) of the played curve at waypoint k (made ahead by `_prepare`)."""
        ahead = self._ahead
        if ahead is not None and ahead[:3] == (self.shared.epoch, self.played.version, k):
            return ahead[3], ahead[4]
        q_k = self.played.sample(k * self.played.dt)[0]
        return q_k, setup.pose_of(q_k)

    def _restart(self) -> None:
        """`Planner.restart` for the servo loop's request; waits until the loop applied it (the
        new motion's waypoint 0 and epoch are the loop's to set)."""
        sh = self.shared
        req, sh.restart_request = sh.restart_request, None
        q, goal, _ = req
        t = time.monotonic()
        try:
            sol, err = self.planner.restart(q, goal), None  # unchanged when it raises
        except SurestepError as exc:
            sol, err = None, str(exc).removeprefix("restart: ")
        sh.applied.clear()
        sh.restart_result = (sol, err, time.monotonic() - t, req)
        while not sh.applied.wait(0.05) and not sh.stop.is_set():
            pass
        self.recent.clear()
        self._lead = self._ahead = None

    def _hand_over(self, k: int, q, start, log: ReplanLog) -> bool:
        """The plan from waypoint k to the servo process (kept there if no set-point after k was
        sent), and to the played curve here if kept."""
        if self.servo is None:
            return self.played.add(k, q, start)
        answer = self.servo.add(self.shared.epoch, k, q, start, self.shared.stop)
        log.handed = time.monotonic() - self.shared.t0
        if answer is None:  # the servo process is gone (the node's loop says so) or stopping
            return False
        log.received = answer[4] - self.shared.t0
        if answer[2]:
            self.played.add(k, q, start)  # never refused: nothing is sampled on this copy
        return bool(answer[2])

    def lead(self) -> float:
        """[s] the least time from an estimate's arrival to the waypoint its re-plan starts at."""
        if self._lead is None:
            # (the hand-over included: `recent` is from the arrival to the servo process's
            # receipt). Its lower quartile: a waypoint aimed past costs a step (50 ms) of
            # latency, and a re-plan late for the waypoint its frame is phase-locked to loses
            # nothing the next frame's (there a step later, with a newer estimate) does not
            # bring; so a step later only where most re-plans are late (a loaded machine)
            self._lead = (self.margin_s if len(self.recent) < LEAD_WINDOW // 2 else
                          max(self.margin_s, float(np.percentile(self.recent, 25))))
        return self._lead

    def _replan(self, msg, mean, cov, t_a: float) -> int | None:
        """The re-plan of one estimate; its waypoint, or None when none was tried."""
        pl, dt = self.planner, self.played.dt
        k = max(int(math.ceil((t_a + self.lead()) / dt - 1e-9)), pl.step)
        if k >= pl.horizon:
            return None  # the last step to the goal: played as planned
        stamp = msg.header.stamp
        t_s = (int(stamp.sec) * 10**9 + int(stamp.nanosec) - self.shared.t0_wall_ns) * 1e-9
        if t_s < -dt or t_a - t_s > self.stale_s:
            return None  # an image from before the motion started, or older than the fault limit
        q_cmd_s = self.played.sample(min(max(t_s, 0.0), t_a))[0]
        q_s = self.measured_at(t_s, q_cmd_s)
        setup = pl.setup
        mean_k = moved(mean, setup.pose_of(q_s), self._at(k, setup)[1])
        trial = copy.copy(pl)
        t_start = time.monotonic()
        try:
            sol = trial.replan(mean_k, cov, camera_pose=self.camera_pose(), step=k)
            ok, why = bool(sol.success), str(sol.status)
        except SurestepError as exc:
            sol, ok, why = None, False, str(exc)
        t0 = self.shared.t0
        ready = time.monotonic() - t0
        took = time.monotonic() - t_start
        late = False
        log = ReplanLog(t_a, ready, k, took, ok, epoch=self.shared.epoch, image=t_s,
                        start=t_start - t0)
        record = getattr(sol, "replan", None)
        if record is not None:
            log.rti, log.feedback_s = record.rti, record.feedback_s
            log.prepared_ahead = record.prepared_ahead
        if ok:
            st = sol.run.start_state
            start = None if st is None else (np.array(st.velocity), np.array(st.acceleration))
            if not self._hand_over(k, np.asarray(sol.q, float), start, log):
                ok, late = False, True  # a set-point after waypoint k was sent
                why = (f"late: ready {1e3 * (ready - k * dt):+.1f} ms from waypoint {k}, a "
                       "set-point after it sent already")
        log.ok, log.why = ok, "" if ok else why
        # the lead: from the arrival to the plan at the servo process
        self.recent.append((ready if log.received is None else log.received) - t_a)
        self._lead = None
        self.shared.logs.append(log)
        if ok:
            self.planner = trial
            self.on_plan(k, sol, start)
        else:
            self.on_fail(why, late)
        return k
