"""`surestep serve`: the node's life, from the arm's first measured joints to the goal held.

1. Waits for the arm's measured joints (and the jaw's), plans from them (`Planner`, within the
   limits; the problem's start is replaced by where the arm is, `--start measured`). Nothing is
   published before this first plan exists: a problem that cannot be planned is exit 2.
2. The servo process (servo.py, started first, its own DDS participant) plays the plan; each
   tracker estimate re-plans (replanner.py) in this, the planner process, whose loop (loop.py)
   watches the faults and tells the servo process each new plan, each hold and when to stop.
3. Once the last plan's goal time has passed and the arm has stayed within the tolerance of the
   goal set-point for `hold_s`, one line `serve: ...` on stdout and exit 0 (`--continuous`: it
   keeps holding and serving until stopped).
A fault holds (stderr, status topic); SIGINT / SIGTERM hold, flush and exit (0, or 1 after a
fault), the servo process stopped and waited for (it also ends, holding, when this process is
gone).
"""

from __future__ import annotations

import copy
import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import SurestepError
from ..methods.planner import Planner
from ..problem.setup import build_setup
from .dds import Bus
from .faults import FaultLimits
from .loop import ServoLoop
from .node import (Endpoints, Measured, Topics, say)
from .servo import ServoProcess

SERVO_START_S = 30.0  # [s] the servo process's start-up (Python, numpy, Cyclone) at most


@dataclass
class ServeOptions:
    problem: str
    arm: str = "PSM1"
    tracker_topic: str = "/PSM1/tracker/pose"
    namespace: str = "/surestep"
    servo_hz: float = 200.0
    domain: int = 0
    continuous: bool = False
    start: str = "measured"
    wait_s: float = 30.0
    hold_s: float = 0.5
    replan_margin_s: float = 0.002
    replan_budget_s: float | None = None  # None: auto (loop.ServoLoop._probe)
    joint_names: str | None = None
    faults: FaultLimits = field(default_factory=FaultLimits)
    log: str | None = None
    resume: bool = True
    resume_after_s: float = 0.3
    servo_priority: int = 0  # SCHED_FIFO priority of the servo process (0: the normal scheduler)


class Stop(BaseException):
    """SIGINT / SIGTERM before the loop runs."""


class Serve:
    """One node run (module docstring); `run()` returns the exit code."""

    def __init__(self, opts: ServeOptions, problem, naming):
        self.opts, self.problem, self.naming = opts, problem, naming
        self.topics = Topics.of(opts.arm, opts.tracker_topic, opts.namespace)
        self.signal: str | None = None
        self.fault_hold = False
        self.servo = None  # servo.ServoProcess

    # -- before the loop ------------------------------------------------------------------------
    def _on_signal(self, signum, _frame) -> None:
        self.signal = signal.Signals(signum).name
        if not getattr(self, "looping", False):
            raise Stop()

    def prepare(self):
        """Endpoints, the arm's joints, the first plan; a SurestepError (exit 2) if no plan."""
        self.ep = Endpoints(self.opts.domain, self.topics)
        arm = [n for n in self._urdf_names() if n != "jaw"]
        aliases = {v: k for k, v in self.naming.names.items()}
        aliases.update({f"outer_{n}": n for n in arm})
        self.measured = Measured(arm, aliases)
        self.jaw = Measured(["jaw"], {})
        q0 = self._wait_for_arm(arm)
        problem = self.problem.with_start(joints=q0.tolist()) if q0 is not None else self.problem
        say(f"serve: planning from {'the arm' if q0 is not None else 'the problem'}'s joints "
            f"{np.round(q0 if q0 is not None else [], 4).tolist()}")
        planner = Planner(problem)
        if not planner.plan.success:
            raise SurestepError(f"{self.opts.problem}: no plan from the arm's joints "
                                f"({planner.plan.status}); nothing published")
        say(f"serve: first plan {planner.plan.status}, {planner.horizon} steps "
            f"(build {planner.build_time_s:.1f} s)")
        self.planner = planner
        warm_up(planner)
        return planner

    def _urdf_names(self) -> list[str]:
        self.setup = build_setup(self.problem)
        return list(self.setup.robot.joint_names)

    def _wait_for_arm(self, arm) -> np.ndarray | None:
        """The arm's measured joints (and jaw's, if it publishes them) for the start."""
        say(f"serve: waiting for {self.topics.measured} (domain {self.opts.domain})")
        deadline = time.monotonic() + self.opts.wait_s
        while self.measured.latest is None:
            if time.monotonic() > deadline:
                raise SurestepError(f"--wait: no {self.topics.measured} within "
                                    f"{self.opts.wait_s:g} s; nothing published")
            self.measured.update(Bus.take(self.ep.measured))
            time.sleep(0.02)
        time.sleep(0.1)
        self.jaw.update(Bus.take(self.ep.jaw_measured))
        start = np.array(self.setup.q_start, float)
        q = start.copy()
        q[:len(arm)] = self.measured.latest
        if self.jaw.latest is not None and len(q) > len(arm):
            q[len(arm)] = self.jaw.latest[0]
        if self.opts.start == "problem":
            off = np.abs(q - start).max()
            if off > self.opts.faults.tolerance_m:
                raise SurestepError(f"--start problem: the arm is {off:.4g} from the problem's "
                                    "start joints; nothing published")
            return None
        return q

    # -- the loop -------------------------------------------------------------------------------
    def run(self) -> int:
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, self._on_signal)
        try:
            try:
                self.start_servo()  # its start-up alongside the first plan's
                self.prepare()
                if not self.servo.wait_ready(SERVO_START_S):
                    say(f"serve: the servo process did not start within {SERVO_START_S:g} s "
                        f"(exit {self.servo.proc.poll()}); nothing published")
                    return 1
                if self.servo.priority_error:
                    say(f"serve: --servo-priority {self.opts.servo_priority}: "
                        f"{self.servo.priority_error}: the servo process runs on the normal "
                        "scheduler")
            except Stop:
                say(f"serve: stopped ({self.signal}) before the first plan; nothing published")
                return 0
            self.looping = True
            return ServoLoop(self).run()
        finally:
            self.looping = True  # a signal now: the stop under way
            self.close_servo()

    def start_servo(self) -> None:
        self.servo = ServoProcess({"domain": self.opts.domain, "servo_topic": self.topics.servo,
                                   "jaw_topic": self.topics.jaw_servo,
                                   "period": 1.0 / self.opts.servo_hz,
                                   "parent_timeout_s": self.opts.faults.estimate_timeout_s,
                                   "priority": self.opts.servo_priority})

    def close_servo(self) -> None:
        """The servo process stopped (it holds, flushes its writers and exits) and waited for."""
        servo, self.servo_code = self.servo, getattr(self, "servo_code", None)
        if servo is not None and self.servo_code is None:
            self.servo_code = servo.close()


def warm_up(planner) -> None:
    """One re-plan and one restart on copies of the Planner (thrown away), so that the loop's
    first ones do not pay for first calls (measured: a re-plan about 40 ms against 10-15 ms)."""
    try:
        copy.copy(planner).replan(planner.plan.poses[1], planner.setup.eval_model.noise.Sigma0,
                                  step=1)
    except SurestepError:
        pass
    try:
        copy.copy(planner).restart(planner.plan.q[0])
    except SurestepError:
        pass


def stderr_flush() -> None:
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except (OSError, ValueError):
            pass
