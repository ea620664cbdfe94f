"""The node's loop in the planner process of `surestep serve` (node.py's docstring): the servo
process's reports (each set-point it sent), faults, the goal, and restarts: a new motion from rest
(`Planner.restart`, planned on the re-planning thread) when a fault hold's cause has cleared
(resume) or, with `--continuous`, for a new goal once the current one is held. A restart begins a
new epoch: waypoint 0 moves to a later servo tick, phase-locked to the tracker's frames again; the
servo clock (the stamps) runs on. The set-points themselves are the servo process's (servo.py):
this loop tells it each epoch, each hold and when to stop, and learns from its reports what was
sent. The restarts are restarts.py's part of the loop; what the run reports at its end,
run_report.py.
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque

import numpy as np

from ..errors import SurestepError
from ..model.grasp import grasp_probability
from . import messages as m
from .dds import Bus
from .estimate import from_message, moved
from .node import STATUS_PERIOD_S, build_replanner, make_watchdog, plan_message, say
from .played import PlayedCurve
from .replanner import Shared
from .restarts import Restarts
from .run_report import summary_line, write_log

# --replan-budget auto: re-plans timed on the tracker's frames before the motion starts (not
# played: PROBES of them, each prepared on the frame before), the budget the longest time from the
# frame's arrival of those that were real-time iterations (their feedback phase: the loop's
# re-plans; a full re-plan is mostly late there), else the second longest of all, plus
# BUDGET_MARGIN_S (the hand-over to the servo process and its tick), within [--replan-margin,
# BUDGET_MAX_STEPS steps]
PROBES = 5
BUDGET_MARGIN_S = 0.0015
BUDGET_MAX_STEPS = 0.8
BUDGET_FALLBACK_S = 0.02  # no probe re-plan succeeded
# the node's loop: every MONITOR_PERIOD_S (the servo process's reports, the arm's joints, the
# faults), deferred while a re-plan runs (the interpreter is the re-plan's), by at most DEFER_S
MONITOR_PERIOD_S = 0.01
DEFER_S = 0.02


class ServoLoop(Restarts):
    """Has `serve.planner`'s plans played by the servo process (`serve.servo`) until the goal is
    held, a signal, or (after a fault) a signal; `run()` returns the exit code."""

    def __init__(self, serve):
        self.serve, self.opts, self.ep = serve, serve.opts, serve.ep
        planner = serve.planner
        self.setup = planner.setup
        self.dt = self.setup.ocp.timing.step_s
        self.period = 1.0 / self.opts.servo_hz
        self.played = PlayedCurve(self.dt, planner.plan.q)
        names = list(self.setup.robot.joint_names)
        self.arm_idx = [i for i, n in enumerate(names) if n != "jaw"]
        self.jaw_idx = [i for i, n in enumerate(names) if n == "jaw"]
        self.names = serve.naming.of(names)
        self.shared = Shared()
        self.servo = serve.servo
        self.watchdog = make_watchdog(self.opts.faults, self.setup)
        self.sent_at: list[float] = []  # monotonic time of each set-point sent
        self.outcome = "running"
        self.camera = None  # the ECM's camera pose when it is not the problem's
        self._ecm_q = None
        self._last_status = ""
        self._status_at = -1.0
        self._first_seen: set[int] = {0}
        self.t_sent = -math.inf  # the last set-point's time from the current waypoint 0 [s]
        self.origin = 0.0  # monotonic: the first waypoint 0 (the log's times are from it)
        self.origin_wall_ns = 0
        self.last_q = np.array(planner.plan.q[0], float)  # the last set-point sent (all joints)
        self.dropped = 0  # set-point reports the servo process could not send back
        self.held_since = None
        self.at_goal = False  # --continuous: the goal reached and held
        self.pending_goal = None  # --continuous: the next goal [p, axis-angle], camera frame
        self.restarting = None  # the restart asked for and not applied yet
        self.holds: list[dict] = []  # each fault hold: when, why, when it cleared and resumed
        self._rest: deque = deque()  # (time, measured arm joints) while holding
        self._retry_at = 0.0
        self._said_ignored = False
        self.hold_status = ""
        self.epoch_at = 0.0  # monotonic: the last restart applied
        self.budget = self.opts.replan_budget_s  # [s] (auto: set by _probe)
        self.probes: list = []  # auto: the probe re-plans' times [s]

    # -- publishing -----------------------------------------------------------------------------
    def status(self, text: str, force: bool = False) -> None:
        now = time.monotonic()
        if force or text != self._last_status or now - self._status_at > STATUS_PERIOD_S:
            self.ep.status.write(m.String(text))
            self._last_status, self._status_at = text, now

    def _plan_msg(self, step: int, q, start) -> None:
        v, a = self.played.knots(step, q, start)
        ns = self.shared.t0_wall_ns + round(step * self.dt * 1e9)
        self.ep.plan.write(plan_message(ns, self.names, q, v, a, self.dt))

    def on_plan(self, step: int, sol, start) -> None:
        self.watchdog.replan_ok()
        self._plan_msg(step, np.asarray(sol.q, float), start)
        self.ep.planned_trace.write(m.Float64(float(sol.trace_final)))

    def on_fail(self, why: str, late: bool = False) -> None:
        say(f"serve: re-plan not played: {why}")
        if not late and self.watchdog.replan_failed(why, time.monotonic()):
            self._hold(self.watchdog.reason)

    def on_estimate(self, mean, cov) -> None:
        self.ep.trace.write(m.Float64(float(np.trace(cov))))
        g = self.serve.problem.grasp
        try:
            self.ep.confidence.write(m.Float64(float(grasp_probability(cov, g.position,
                                                                       g.angle))))
        except (ImportError, ValueError, np.linalg.LinAlgError):
            pass

    def _hold(self, reason: str) -> None:
        sh = self.shared
        if not sh.holding.is_set():
            sh.holding.set()
            self.servo.send(("hold", reason))
            self.serve.fault_hold = True
            now = time.monotonic()
            # "at": when the servo process held (its report; until then, when decided here)
            self.holds.append({"at": now - self.origin, "decided": now - self.origin,
                               "reason": reason,
                               "sent_before": len(self.sent_at),
                               "fault_seen": None if sh.fault_at is None
                               else sh.fault_at - self.origin,
                               "last_estimate": sh.last_estimate - self.origin,
                               "cleared": None, "resumed": None, "first_command": None})
            self._rest.clear()
            self.hold_status = f"hold: {reason}"
            say(f"serve: hold: {reason}"
                + ("" if self.opts.resume else "; --no-resume: held until stopped"))
            self.status(f"hold: {reason}", force=True)

    # -- the loop -------------------------------------------------------------------------------
    def _first_frame(self):
        """(samples, arrival) of the first tracker frame after the plan is ready (older ones
        dropped), or None after `wait_s`."""
        Bus.take(self.ep.tracker, 1000)
        deadline = time.monotonic() + self.opts.wait_s
        while time.monotonic() < deadline and not self.serve.signal:
            samples = self.ep.wait_tracker(0.1)
            if samples:
                return samples, time.monotonic()
        return None

    def run(self) -> int:
        sh = self.shared
        say(f"serve: waiting for the tracker on {self.ep.topics.tracker}")
        first = self._first_frame()
        if first is None:
            say(f"serve: no estimate on {self.ep.topics.tracker} within {self.opts.wait_s:g} s"
                + (f" ({self.serve.signal})" if self.serve.signal else "")
                + "; nothing published")
            return 0 if self.serve.signal else 1
        # waypoint 0 `budget` after a frame's arrival: the waypoints are phase-locked to the
        # tracker's frames (one per step), each re-plan has that long before its waypoint (the
        # last frame's re-plan is made first: `_register`; t0 after it)
        if self.opts.replan_budget_s is None:
            probed = self._probe(first)
            if probed is None:
                say("serve: " + (f"stopped ({self.serve.signal})" if self.serve.signal else
                                 "the tracker stopped")
                    + " before the motion started; nothing published")
                return 0 if self.serve.signal else 1
            first, lock, self.budget, self.probes = probed
        else:
            lock, self.budget = first[1], self.opts.replan_budget_s
        sh.last_estimate = sh.last_finite = first[1]
        left = self._register(first)
        sh.t0 = lock + self.budget
        while sh.t0 < time.monotonic() + 2 * self.period:
            sh.t0 += self.dt
        sh.t0_wall_ns = time.time_ns() + round((sh.t0 - time.monotonic()) * 1e9)
        self.origin, self.origin_wall_ns = sh.t0, sh.t0_wall_ns
        if left is None:  # the next frame's re-plan prepared (its waypoint: the lock's)
            k = max(math.ceil((first[1] + self.dt - sh.t0 + self.opts.replan_margin_s) / self.dt
                              - 1e-9), 0)
            self._prepare(k)
        self.replanner = build_replanner(self.serve.planner, self.played, sh, self.ep,
                                         self.serve.measured, self._camera_pose, self.opts,
                                         self.on_plan, self.on_fail, self.on_estimate,
                                         left, self.servo)
        q = np.asarray(self.serve.planner.plan.q, float)
        self.servo.send(("curve", self.dt, [self.names[i] for i in self.arm_idx],
                         [self.names[i] for i in self.jaw_idx], self.arm_idx, self.jaw_idx))
        self.servo.send(("epoch", sh.epoch, sh.t0, sh.t0_wall_ns, q, 0))
        self._plan_msg(0, q, None)
        self.replanner.start()
        try:
            code = self._loop()
        finally:
            self._finish()
        return code

    def _camera_pose(self):
        return self.camera

    def _prepare(self, k: int) -> None:
        planner = self.serve.planner
        if hasattr(planner, "prepare") and planner.step <= k < planner.horizon:
            try:
                planner.prepare(k)
            except SurestepError:
                pass

    def _register(self, frame):
        """The frame's estimate re-planned from waypoint 0 before the motion starts (the arm at
        rest there, so the estimate needs no moving): the first re-plan, which registers the
        camera to the tracker, is mostly a full one (tens of ms), late in the loop's race and
        then the re-plans after it too (their preparations on the unregistered plan). Returns
        the frame when the loop is to take it (an estimate not finite: its fault), else None."""
        mean, cov, finite = from_message(frame[0][-1])
        if not finite:
            return frame
        sh, planner, t = self.shared, self.serve.planner, time.monotonic()
        sh.estimates += len(frame[0])
        sh.finite_since, sh.estimate = frame[1], (mean, cov)
        try:
            sol = planner.replan(mean, cov, step=0)  # a success becomes its plan
            why = "" if sol.success else f" (not played: {sol.status})"
        except SurestepError as exc:
            sol, why = None, f" (not played: {exc})"
        if sol is not None and sol.success:
            self.played.reset(np.asarray(planner.plan.q, float))
            self.ep.planned_trace.write(m.Float64(float(sol.trace_final)))
        self.on_estimate(mean, cov)
        say(f"serve: the first estimate re-planned from waypoint 0 before the motion starts "
            f"(the camera registered to the tracker) in {(time.monotonic() - t) * 1e3:.1f} ms"
            + why)
        return None

    def _probe(self, first):
        """--replan-budget auto: the tracker's first frames re-planned as the loop re-plans them
        (not played; the arm at rest at the start): on one copy of the Planner, each frame's
        estimate moved along that copy's plan to the next waypoint (1, 2, ...) and re-planned
        there, the next one prepared between frames (`Planner.prepare`, the real-time iteration).
        The first frame's re-plan registers the camera (a full one, as the loop's first); the
        next PROBES are timed from their frame's arrival. Returns (the last frame, the frames'
        phase lock [monotonic s], the budget [s], the probes' times [s]), or None when the tracker
        stops or a signal comes."""
        planner, frame = self.serve.planner, first
        took, feedback, arrivals = [], [], [first[1]]
        trial = copy.copy(planner)
        here = trial.setup.pose_of(np.asarray(planner.plan.q[0], float))
        for step in range(1, PROBES + 2):
            mean, cov, finite = from_message(frame[0][-1])
            if finite and step < trial.horizon:
                try:
                    there = trial.setup.pose_of(trial.executed_state(step)[0])
                    sol = trial.replan(moved(mean, here, there), cov, step=step)
                    if sol.success and step > 1:
                        took.append(time.monotonic() - frame[1])
                        if getattr(sol.replan, "rti", None) == "feedback":
                            feedback.append(took[-1])
                    if hasattr(trial, "prepare") and step + 1 < trial.horizon:
                        trial.prepare(step + 1)
                except SurestepError:
                    pass
            frame = self._first_frame()
            if frame is None or self.serve.signal:
                return None
            arrivals.append(frame[1])
        if took:
            ranked = sorted(took)
            budget = (max(feedback) if feedback else
                      ranked[-2] if len(ranked) >= 3 else ranked[-1]) + BUDGET_MARGIN_S
            budget = min(max(budget, self.opts.replan_margin_s), BUDGET_MAX_STEPS * self.dt)
        else:
            budget = BUDGET_FALLBACK_S
        # the frames' phase: each arrival's offset from the last one's, modulo a step, median
        offsets = [(a - frame[1] + self.dt / 2) % self.dt - self.dt / 2 for a in arrivals]
        lock = frame[1] + float(np.median(offsets))
        say(f"serve: re-plan budget {budget * 1e3:.1f} ms (auto: {len(took)} re-plans on the "
            f"tracker's first frames took {', '.join(f'{t * 1e3:.1f}' for t in took)} ms, "
            f"{len(feedback)} of them real-time iterations)")
        return frame, lock, budget, took

    def _loop(self) -> int:
        """Every MONITOR_PERIOD_S (deferred while a re-plan runs, up to DEFER_S): the servo
        process's reports (one per set-point), the topics, the faults, the goal, restarts."""
        sh = self.shared
        next_at, lim = time.monotonic(), self.opts.faults.estimate_timeout_s
        while True:
            next_at = max(next_at + MONITOR_PERIOD_S, time.monotonic())
            if not sh.holding.is_set():  # a silence's limit passing: looked at then
                due = min(max(sh.last_estimate, self.epoch_at),
                          max(self.serve.measured.arrived, sh.t0)) + lim + 1e-4
                if time.monotonic() < due < next_at:
                    next_at = due
            self.servo.wait_gone(next_at - time.monotonic())
            self.replanner.idle.wait(DEFER_S)
            reports = self.servo.take(0.0)
            now = time.monotonic()
            for r in reports:
                self._on_report(r)
            if sh.restart_result is not None:
                self._apply_restart(now)
            self._read(now)
            if self.serve.signal:
                self.outcome = f"stopped ({self.serve.signal})"
                return 1 if self.serve.fault_hold else 0
            if self.servo.gone:
                code = self.servo.proc.poll()
                self.outcome = f"stopped: the servo process ended (exit {code})"
                say(f"serve: {self.outcome}; nothing more is sent")
                return 1
            t = now - sh.t0  # the servo clock's time from waypoint 0
            moving = t < self.played.end_time
            if not sh.holding.is_set():
                self._check(now, moving)
            if not sh.holding.is_set():
                t = self.t_sent
                self.held_since = self._goal_check(t, now, self.held_since)
                if self.held_since is not None and now - self.held_since >= self.opts.hold_s:
                    if not self.opts.continuous:
                        self.outcome = self._reached(t)
                        self.status("goal reached", force=True)
                        return 0
                    self._at_goal(t, now)
                else:
                    k = min(int(max(t, 0.0) / self.dt), round(self.played.end_time / self.dt))
                    self.status(f"moving: waypoint {max(k, 0)} of "
                                f"{round(self.played.end_time / self.dt)}")
            else:
                self._while_holding(now)
                if self.restarting is None:
                    self.status(self.hold_status or f"hold: {self.watchdog.reason}")
            self.servo.beat()

    def _on_report(self, r) -> None:
        kind = r[0]
        if kind == "sent":
            self._on_sent(r)
        elif kind == "held":
            _, why, sent, at = r
            if not self.shared.holding.is_set() and not why.startswith("SIG"):
                # the servo process held on its own (the planner silent), or for a NaN estimate
                self.watchdog.trip(why, time.monotonic())
                self._hold(self.watchdog.reason)
            if self.holds and self.holds[-1]["resumed"] is None:
                h = self.holds[-1]
                h["at"] = at - self.origin  # when the stream stopped
                h["sent_before"] = sent
        elif kind == "signal":
            self.serve.signal = self.serve.signal or f"{r[1]} to the servo process"

    def _reached(self, t: float) -> str:
        end = round(self.played.end_time / self.dt)
        late = self.replanner.planner.horizon - self.setup.ocp.horizon
        resumed = sum(h["resumed"] is not None for h in self.holds)
        return (f"goal reached and held {self.opts.hold_s:g} s at "
                f"{t + self.shared.t0 - self.origin:.2f} s (waypoint {end}, {late} steps later "
                "than planned" + (f", {resumed} fault hold(s) resumed" if resumed else "") + ")")

    def _read(self, now: float) -> None:
        self.serve.measured.update(Bus.take(self.ep.measured))
        self.serve.jaw.update(Bus.take(self.ep.jaw_measured))
        goals = Bus.take(self.ep.goal)
        if goals:
            self._on_goal(goals[-1])
        ecm = Bus.take(self.ep.ecm)
        if ecm and self.setup.ecm is not None:
            q = np.array(ecm[-1].position, float)
            if q.shape == (4,) and np.all(np.isfinite(q)):
                base = np.array(self.setup.camera_pose)
                pose = self.setup.ecm.base_pose @ self.setup.ecm.frame_pose(q)
                self.camera = None if np.allclose(pose, base, atol=1e-9, rtol=0) else pose

    def _check(self, now: float, moving: bool) -> None:
        sh, wd = self.shared, self.watchdog
        if sh.fault:
            wd.trip(sh.fault, now)
        if moving:
            # from a restart's start on (the re-planning thread reads no estimate while planning)
            wd.check_silence(now, max(sh.last_estimate, self.epoch_at),
                             max(self.serve.measured.arrived, sh.t0))
        if self.serve.measured.latest is not None:
            wd.check_tracking(now, self.serve.measured.latest)
        if wd.reason:
            self._hold(wd.reason)

    def _on_sent(self, r) -> None:
        """A set-point the servo process sent: the log, the watchdog, the first set-point of each
        plan."""
        _, epoch, _n, t, at, piece, q, dropped = r
        self.dropped = dropped
        q = np.asarray(q, float)
        self.last_q = q
        self.sent_at.append(at)
        if epoch != self.shared.epoch:
            return  # the motion before a restart (sent before the new epoch reached it)
        self.t_sent = t
        self.watchdog.commanded(at, q[self.arm_idx])
        if self.holds and self.holds[-1]["resumed"] is not None \
                and self.holds[-1]["first_command"] is None:
            self.holds[-1]["first_command"] = at - self.origin
        if piece not in self._first_seen:
            self._first_seen.add(piece)
            for g in reversed(self.shared.logs):
                if g.ok and g.step == piece and g.epoch == self.shared.epoch:
                    g.first_command = at - self.shared.t0
                    break

    def _goal_check(self, t: float, now: float, held_since):
        if t < self.played.end_time or self.serve.measured.latest is None:
            return None
        goal = self.played.pieces()[-1][1][-1][self.arm_idx]
        err = np.abs(self.serve.measured.latest - goal) / self.watchdog._tol
        if np.max(err) > 1.0:
            return None
        return now if held_since is None else held_since

    def _finish(self) -> None:
        sh = self.shared
        sh.stop.set()
        self.servo.send(("hold", self.outcome))
        self.serve.close_servo()
        for r in self.servo.take(0.0):  # the last set-points' reports (no new hold now)
            if r[0] == "sent":
                self._on_sent(r)
        self.status(f"stopped: {self.outcome}" if self.outcome.startswith("stopped")
                    else self.outcome, force=True)
        self.replanner.join(timeout=2.0)
        self.ep.bus.flush()
        if self.opts.log:
            write_log(self)
        print(summary_line(self), flush=True)
