"""Restarts of `surestep serve`'s node loop (loop.ServoLoop): a new motion from rest, planned on the
re-planning thread (`Planner.restart`), when a fault hold's cause has cleared (resume) or, with
`--continuous`, for a new goal once the current one is held; a restart begins a new epoch (waypoint
0 at a later servo tick). A goal that cannot be taken is refused (stderr, the status topic).

`Restarts` is the part of ServoLoop that decides and applies them: its methods run on the loop's
state (the shared state with the re-planning thread, the holds, the played curve) and use its
`status`, `_plan_msg` and `_reached`.
"""

from __future__ import annotations

import math

import numpy as np

from . import messages as m
from .estimate import goal_from_message
from .node import say

REST_FRACTION = 0.1  # at rest: each joint's spread over the window, in its tolerances
RETRY_S = 1.0  # a failed resume is tried again after this


class Restarts:
    """ServoLoop's restarts: resume after a fault, a new goal (module docstring)."""

    def _at_goal(self, t: float, now: float) -> None:
        """--continuous, the goal held: a new goal (if one came) is planned from here."""
        if not self.at_goal:
            self.at_goal = True
            say(f"serve: {self._reached(t)}; --continuous: holding it, new goals on "
                f"{self.ep.topics.goal}")
        if self.pending_goal is not None and self.restarting is None:
            goal, self.pending_goal = self.pending_goal, None
            self._request(goal, "a new goal", now)
        if self.restarting is None:
            self.status("goal reached; holding (--continuous)")

    def _while_holding(self, now: float) -> None:
        """A fault hold: once its cause has cleared (`_cleared`), a restart from the held
        set-point (to the pending goal, if any)."""
        if not self.opts.resume:
            return
        q = self.serve.measured.latest
        if q is not None:
            self._rest.append((now, q))
        while self._rest and self._rest[0][0] < now - self.opts.resume_after_s - self.period:
            self._rest.popleft()
        if self.restarting is not None or now < self._retry_at:
            return
        why = self._cleared(now)
        if why is None:
            return
        self.holds[-1]["cleared"] = now - self.origin
        goal, self.pending_goal = self.pending_goal, None
        say(f"serve: fault cleared ({why}): planning a new motion from rest at the held "
            "set-point" + (" to the new goal" if goal is not None else ""))
        self.status(f"resuming: {why}", force=True)
        self._request(goal, "resume", now)

    def _cleared(self, now: float) -> str | None:
        """Why resuming is safe now, or None: for `resume_after_s`, finite tracker estimates
        arriving (none silent for the timeout), and the arm's (`_arm_settled`)."""
        sh, lim, win = self.shared, self.opts.faults.estimate_timeout_s, self.opts.resume_after_s
        if sh.finite_since is None or now - sh.last_finite > lim or now - sh.finite_since < win:
            return None
        arm = self._arm_settled(now)
        return None if arm is None else f"estimates finite for {now - sh.finite_since:.2f} s, {arm}"

    def _arm_settled(self, now: float) -> str | None:
        """The arm's measured joints arriving and, for `resume_after_s`, at rest (each joint's
        spread within REST_FRACTION of its tolerance) within the tolerance of the held set-point
        (a stuck arm: only once it has followed it again)."""
        win, meas = self.opts.resume_after_s, self.serve.measured
        if meas.latest is None or now - meas.arrived > self.opts.faults.estimate_timeout_s:
            return None
        if not self._rest or self._rest[0][0] > now - win + self.period:
            return None
        qs = np.array([q for _, q in self._rest])
        tol = self.watchdog._tol
        off = np.max(np.abs(qs - self.last_q[self.arm_idx]) / tol)
        spread = np.max((qs.max(axis=0) - qs.min(axis=0)) / tol)
        if off > 1.0 or spread > REST_FRACTION:
            return None
        return f"the arm at rest {off:.2f} tolerance from the held set-point"

    def _request(self, goal, why: str, now: float) -> None:
        self.restarting = {"holds": len(self.holds), "from_hold": self.shared.holding.is_set(),
                           "at": now}
        self.shared.restart_request = (self.last_q.copy(), goal, why)

    def _apply_restart(self, now: float) -> None:
        """The re-planning thread's restart: a new epoch, or a refusal (a goal), or a retry."""
        sh = self.shared
        (sol, err, took, (_, goal, why)), sh.restart_result = sh.restart_result, None
        req, self.restarting = self.restarting, None
        try:
            if sol is None:
                if goal is not None:
                    self.refuse(err)
                else:
                    say(f"serve: resume failed: {err}; holding, tried again in {RETRY_S:g} s")
                    self.hold_status = f"hold: {self.watchdog.reason} (resume failed: {err})"
                    self.status(self.hold_status, force=True)
                    self._retry_at = now + RETRY_S
                return
            # still safe: no new hold; a resume's arm still at rest there, no NaN since
            back = req["from_hold"] and (self._arm_settled(now) is None
                                         or sh.finite_since is None)
            if len(self.holds) != req["holds"] or back:
                say("serve: new plan dropped: " + (f"hold: {self.watchdog.reason}"
                                                   if not req["from_hold"] else
                                                   "the fault is back"))
                if goal is not None and self.pending_goal is None:
                    self.pending_goal = goal
                return
            self._new_epoch(sol, now)
            if req["from_hold"]:
                h = self.holds[-1]
                h["resumed"], h["restart_s"] = now - self.origin, took
                self.serve.fault_hold = False
                self.watchdog.clear()
                sh.fault = None
                sh.holding.clear()
            say(f"serve: {'resumed' if why == 'resume' else 'new goal'}: a new motion from rest, "
                f"{self.replanner.planner.horizon} steps (planned in {took:.2f} s), waypoint 0 at "
                f"{sh.t0 - self.origin:.2f} s")
        finally:
            sh.applied.set()

    def _new_epoch(self, sol, now: float) -> None:
        """The restart's plan from waypoint 0 at a later servo tick (the stamps' clock runs on),
        `replan_budget_s` after a tracker frame's arrival (the phase lock) and after now."""
        sh, dt, P = self.shared, self.dt, self.period
        lock = sh.last_estimate + self.budget
        target = lock + max(0, math.ceil((now + 2 * P - lock) / dt)) * dt
        m_ticks = max(1, math.ceil((target - sh.t0) / P - 1e-9))
        sh.t0 += m_ticks * P
        sh.t0_wall_ns += round(m_ticks * P * 1e9)
        sh.epoch += 1
        self.epoch_at = now
        q = np.asarray(sol.q, float)
        self.played.reset(q)
        self.servo.send(("epoch", sh.epoch, sh.t0, sh.t0_wall_ns, q, None))
        self.setup = self.replanner.planner.setup
        self.t_sent = -math.inf
        self._first_seen = {0}
        self.held_since, self.at_goal = None, False
        self._plan_msg(0, q, None)
        self.ep.planned_trace.write(m.Float64(float(sol.trace_final)))
        self.status(f"moving: waypoint 0 of {len(q) - 1}", force=True)

    def refuse(self, why: str) -> None:
        """A goal not taken: one line on stderr and the status topic; the node holds where it
        is (the goal it holds, or its fault hold)."""
        say(f"serve: goal refused: {why}")
        self.status(f"goal refused: {why}", force=True)

    def _on_goal(self, msg) -> None:
        x = goal_from_message(msg)
        if x is None:
            return self.refuse("not finite (a position and a non-zero quaternion)")
        if not self.opts.continuous:
            if not self._said_ignored:
                self._said_ignored = True
                say(f"serve: a goal on {self.ep.topics.goal} is taken with --continuous only; "
                    "ignored")
            return None
        if self.shared.holding.is_set() and not self.opts.resume:
            return self.refuse(f"holding on a fault ({self.watchdog.reason}) with --no-resume")
        self.pending_goal = x
        when = ("now" if self.at_goal else "once the fault clears" if self.shared.holding.is_set()
                else "once the current goal is reached and held")
        say(f"serve: new goal {np.round(x, 4).tolist()} received: planned {when}")
        return None
