"""The servo loop of `surestep serve` (node.py's docstring): ticks, set-points, faults, the goal.
"""

from __future__ import annotations

import time

import numpy as np

from . import messages as m
from .dds import Bus
from .node import (STATUS_PERIOD_S, build_replanner, joint_message, make_watchdog, plan_message,
                   say, ticks_of)
from .played import PlayedCurve
from .replanner import Shared


class ServoLoop:
    """Plays `serve.planner`'s plans at the servo rate until the goal is held, a signal, or (after a
    fault) a signal; `run()` returns the exit code."""

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
        self.watchdog = make_watchdog(self.opts.faults, self.setup)
        self.sent_at: list[float] = []  # monotonic time of each set-point sent
        self.outcome = "running"
        self.camera = None  # the ECM's camera pose when it is not the problem's
        self._ecm_q = None
        self._last_status = ""
        self._status_at = -1.0
        self._first_seen: set[int] = {0}

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
            from ..model.grasp import grasp_probability

            self.ep.confidence.write(m.Float64(float(grasp_probability(cov, g.position,
                                                                       g.angle))))
        except (ImportError, ValueError, np.linalg.LinAlgError):
            pass

    def _hold(self, reason: str) -> None:
        if not self.shared.holding.is_set():
            self.shared.holding.set()
            self.serve.fault_hold = True
            say(f"serve: hold: {reason}")
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
        # waypoint 0 `replan_budget_s` after this frame's arrival: the waypoints are phase-locked
        # to the tracker's frames (one per step), each re-plan has that long before its waypoint
        sh.t0 = first[1] + self.opts.replan_budget_s
        sh.t0_wall_ns = time.time_ns() + round((sh.t0 - time.monotonic()) * 1e9)
        sh.last_estimate = first[1]
        self.replanner = build_replanner(self.serve.planner, self.played, sh, self.ep,
                                         self.serve.measured, self._camera_pose, self.opts,
                                         self.on_plan, self.on_fail, self.on_estimate,
                                         (first[0], first[1]))
        self._plan_msg(0, np.asarray(self.serve.planner.plan.q, float), None)
        self.replanner.start()
        code = self._ticks()
        self._finish()
        return code

    def _camera_pose(self):
        return self.camera

    def _ticks(self) -> int:
        sh, n, held_since = self.shared, 0, None
        while True:
            target = sh.t0 + n * self.period
            delay = target - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            now = time.monotonic()
            late = ticks_of(now - sh.t0, self.period)
            n = max(n, late)  # a tick found a period late or more is skipped, not sent late
            t = n * self.period
            self._read(now)
            if self.serve.signal:
                self.outcome = f"stopped ({self.serve.signal})"
                return 1 if self.serve.fault_hold else 0
            moving = t < self.played.end_time
            if not sh.holding.is_set():
                self._check(now, moving)
            if not sh.holding.is_set():
                self._send(n, t, now)
                held_since = self._goal_check(t, now, held_since)
                if held_since is not None and now - held_since >= self.opts.hold_s:
                    if not self.opts.continuous:
                        self.outcome = self._reached(t)
                        self.status("goal reached", force=True)
                        return 0
                    self.status("goal reached; holding (--continuous)")
                else:
                    k = min(int(t / self.dt), round(self.played.end_time / self.dt))
                    self.status(f"moving: waypoint {k} of {round(self.played.end_time / self.dt)}")
            else:
                self.status(f"hold: {self.watchdog.reason}")
            n += 1

    def _reached(self, t: float) -> str:
        end = round(self.played.end_time / self.dt)
        late = self.replanner.planner.horizon - self.setup.ocp.horizon
        return (f"goal reached and held {self.opts.hold_s:g} s at {t:.2f} s (waypoint {end}, "
                f"{late} steps later than planned)")

    def _read(self, now: float) -> None:
        sh = self.shared
        self.serve.measured.update(Bus.take(self.ep.measured), sh.t0_wall_ns)
        self.serve.jaw.update(Bus.take(self.ep.jaw_measured), sh.t0_wall_ns)
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
            wd.check_silence(now, sh.last_estimate, max(self.serve.measured.arrived, sh.t0))
        if self.serve.measured.latest is not None:
            wd.check_tracking(now, self.serve.measured.latest)
        if wd.reason:
            self._hold(wd.reason)

    def _send(self, n: int, t: float, now: float) -> None:
        q, v, piece = self.played.sample(t, commit=True)
        ns = self.shared.t0_wall_ns + round(t * 1e9)
        self.ep.servo.write(joint_message(ns, [self.names[i] for i in self.arm_idx],
                                          q[self.arm_idx], v[self.arm_idx]))
        if self.jaw_idx:
            self.ep.jaw_servo.write(joint_message(ns, [self.names[i] for i in self.jaw_idx],
                                                  q[self.jaw_idx], v[self.jaw_idx]))
        self.sent_at.append(time.monotonic())
        self.watchdog.commanded(now, q[self.arm_idx])
        if piece not in self._first_seen:
            self._first_seen.add(piece)
            for g in reversed(self.shared.logs):
                if g.ok and g.step == piece:
                    g.first_command = self.sent_at[-1] - self.shared.t0
                    break

    def _goal_check(self, t: float, now: float, held_since):
        if t < self.played.end_time or self.serve.measured.latest is None:
            return None
        goal = self.played.pieces()[-1][1][-1][self.arm_idx]
        err = np.abs(self.serve.measured.latest - goal) / self.watchdog._tol
        if np.max(err) > 1.0:
            return None
        return now if held_since is None else held_since

    def goal_error(self):
        """(position [m], angle [rad], P(grasp)) of the last estimate from the goal, or None."""
        if self.shared.estimate is None:
            return None
        from scipy.spatial.transform import Rotation

        mean, cov = self.shared.estimate
        goal = np.asarray(self.setup.x_goal, float)
        dp = float(np.linalg.norm(mean[:3] - goal[:3]))
        dr = float((Rotation.from_rotvec(goal[3:]).inv() * Rotation.from_rotvec(mean[3:]))
                   .magnitude())
        g = self.serve.problem.grasp
        try:
            from ..model.grasp import grasp_probability

            p = float(grasp_probability(cov, g.position, g.angle))
        except ImportError:
            p = float("nan")
        return dp, dr, p

    def _finish(self) -> None:
        from .serve import summary_line

        sh = self.shared
        sh.stop.set()
        self.status(f"stopped: {self.outcome}" if self.outcome.startswith("stopped")
                    else self.outcome, force=True)
        self.replanner.join(timeout=2.0)
        self.ep.bus.flush()
        if self.opts.log:
            self._write_log()
        print(summary_line(self), flush=True)

    def _write_log(self) -> None:
        from dataclasses import asdict

        from ..output.solution import write_json_atomic

        data = {"replans": [asdict(g) for g in self.shared.logs],
                "sent_at": [t - self.shared.t0 for t in self.sent_at],
                "outcome": self.outcome, "hold": self.watchdog.reason,
                "hold_at": None if self.watchdog.at is None else self.watchdog.at - self.shared.t0,
                "estimates": self.shared.estimates, "period": self.period, "dt": self.dt,
                "last_estimate": self.shared.last_estimate - self.shared.t0,
                "fault_seen": (None if self.shared.fault_at is None
                               else self.shared.fault_at - self.shared.t0),
                "t0_wall": self.shared.t0_wall_ns * 1e-9}
        write_json_atomic(self.opts.log, data)
