"""The servo stream of `surestep serve`, in a process of its own.

The node is two processes that share two pipes and nothing else. The planner process (serve.py,
loop.py, replanner.py) keeps the tracker subscription, the re-plans, the fault logic and the
node's own topics; this one, started by it (`python -m surestep_ocp.ros.servo`), plays the plans
at the servo rate on its own DDS participant, so a re-plan (Python holding the planner process's
interpreter lock) never delays a tick. Here:

- a copy of the played curve (played.PlayedCurve): an *epoch* (a motion's waypoint 0 on the servo
  clock and its first plan) and each re-plan's *piece* (from waypoint k; kept only if no set-point
  after k was sent: the C2 switch, decided here, where the set-points are sent), answered with
  `added` (kept or not) at once;
- at each tick of the servo clock (t0 + n / servo_hz) the curve's sample, written on
  `/ARM/servo_jp` and `/ARM/jaw/servo_jp` stamped with the tick's time; a tick found a period late
  is skipped, never sent late; each set-point sent is reported back (tick, time sent, the playing
  piece, joints) for the fault logic and the log;
- a hold (nothing more sent; the arm keeps its last set-point) when the planner process says so
  (a fault), when it is silent for `parent_timeout_s` (it sends a heartbeat), on SIGINT or SIGTERM
  (said to it, which then stops the node), and when it is gone (its pipe closed: killed): then the
  writers are flushed and this process exits.

Commands come on one pipe (multiprocessing.connection's framing, pickles). Reports go back on
another, written non-blocking, each in one write of at most PIPE_BUF bytes (atomic): when the
planner process does not read, they queue here (set-point reports past a bound are dropped, and
counted), so the stream never waits for the planner process.

Under `--servo-priority N` it runs under the real-time scheduler (SCHED_FIFO, priority N): it sleeps
between ticks, so it takes its core only for each tick's few hundred microseconds.

Commands: ("curve", dt, arm names, jaw names, arm indices, jaw indices), ("epoch", epoch, t0
[monotonic s], t0 [ns since the epoch], joints, first tick or None), ("piece", id, epoch, k,
joints, start), ("hold", reason), ("beat",), ("stop",). Reports: ("ready", pid, why not
real-time or None), ("sent", epoch, n, t, sent [monotonic s], piece, joints, dropped), ("added",
id, kept, sampled up to [s], received [monotonic s]), ("held", why, set-points sent, held
[monotonic s]), ("signal", name), ("stopped", sent).
Each tick's set-point is made (sampled, serialized) just before the tick and only written at it.
"""

from __future__ import annotations

import signal

# first: the planner process starts this one with SIGINT and SIGTERM blocked (so neither can
# interrupt its start-up); they are unblocked once these handlers are in place (main)
_SIGNAL: list = []


def _on_signal(signum, _frame) -> None:
    _SIGNAL.append(signal.Signals(signum).name)


import math
import os
import pickle
import struct
import subprocess
import sys
import threading
import time
from collections import deque
from multiprocessing.connection import Connection

import numpy as np

from .played import PlayedCurve

PIPE_BUF = 4096  # a pipe write of at most this many bytes is atomic (POSIX: at least 512)
MAX_QUEUED = 2000  # set-point reports queued here while the planner process does not read
POLL_S = 0.02  # the longest wait for a command while nothing is due (a signal is seen by then)
# a pipe's wait (poll(2)) counts in whole milliseconds, rounded up: it ends this long before a tick
# is due, the rest is slept (nanosleep) and the commands looked at once more just before the tick
SLEEP_S = 0.0015
STOP_WAIT_S = 2.0  # after a signal, wait this long for the planner process's stop


def ticks_of(t_now: float, period: float) -> int:
    """The servo tick at (or just before) time t_now since waypoint 0."""
    return int(math.floor(t_now / period + 1e-9))


# -- this process -------------------------------------------------------------------------------
class Publisher:
    """The set-points on DDS: `prepare(q, v, stamp_ns)` makes (and serializes) the arm's and the
    jaw's JointState before the tick, `send(prepared)` writes them at it."""

    def __init__(self, bus, servo_topic: str, jaw_topic: str):
        # cyclonedds: loaded on use (the tick loop runs without it)
        from . import messages, node

        self.bus, self.joint_message = bus, node.joint_message
        self.servo = bus.writer(servo_topic, messages.JointState)
        self.jaw = bus.writer(jaw_topic, messages.JointState)
        self.arm_names = self.jaw_names = self.arm_idx = self.jaw_idx = None

    def curve(self, arm_names, jaw_names, arm_idx, jaw_idx) -> None:
        self.arm_names, self.jaw_names = list(arm_names), list(jaw_names)
        self.arm_idx, self.jaw_idx = list(arm_idx), list(jaw_idx)

    def prepare(self, q, v, ns: int) -> list:
        joint_message = self.joint_message
        a, j = self.arm_idx, self.jaw_idx
        out = [(self.servo, self.bus.serialized(
            self.servo, joint_message(ns, self.arm_names, q[a], v[a])))]
        if j:
            out.append((self.jaw, self.bus.serialized(
                self.jaw, joint_message(ns, self.jaw_names, q[j], v[j]))))
        return out

    def send(self, prepared: list) -> None:
        for writer, data in prepared:
            self.bus.write_serialized(writer, data)


class Stream:
    """The tick loop (module docstring) over `ctl` (the command connection), `rep_fd` (the report
    pipe, non-blocking) and `publisher` (Publisher, or a stand-in in the tests)."""

    def __init__(self, ctl, rep_fd: int, period: float, parent_timeout_s: float, publisher=None):
        self.ctl, self.rep_fd = ctl, rep_fd
        self.period, self.parent_timeout_s = period, parent_timeout_s
        self.publisher = publisher
        self.played = None
        self.dt = None
        self.t0, self.t0_wall_ns, self.epoch, self.n = 0.0, 0, -1, 0
        self.holding = True  # nothing to play before the first epoch
        self.sent, self.dropped = 0, 0
        self.last_heard = time.monotonic()
        self.out: deque = deque()  # framed reports not written yet
        self.prepared = None  # (tick, t, joints, piece, the publisher's messages) made ahead

    # -- reports ----------------------------------------------------------------------------------
    def report(self, msg, droppable: bool = False) -> None:
        if droppable and len(self.out) >= MAX_QUEUED:
            self.dropped += 1
            return
        data = pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL)
        frame = struct.pack("!i", len(data)) + data
        if len(frame) > PIPE_BUF:
            raise ValueError(f"servo report of {len(frame)} bytes (at most {PIPE_BUF})")
        self.out.append(frame)
        self.flush_out()

    def flush_out(self) -> bool:
        """Write the queued reports (each whole or not at all); False if the reader is gone."""
        while self.out:
            try:
                os.write(self.rep_fd, self.out[0])
            except BlockingIOError:
                return True
            except OSError:  # BrokenPipeError: the planner process is gone
                self.out.clear()
                return False
            self.out.popleft()
        return True

    # -- commands ---------------------------------------------------------------------------------
    def handle(self, msg) -> bool:
        """One command; True for stop."""
        self.last_heard = time.monotonic()
        kind = msg[0]
        if kind == "beat":
            return False
        self.prepared = None  # made again after any change
        if kind == "piece":
            _, ident, epoch, k, q, start = msg
            kept = epoch == self.epoch and self.played is not None and self.played.add(k, q, start)
            upto = -math.inf if self.played is None else float(self.played._sampled)
            self.report(("added", ident, bool(kept), upto, time.monotonic()))
        elif kind == "hold":
            self.hold(str(msg[1]))
        elif kind == "epoch":
            _, self.epoch, self.t0, self.t0_wall_ns, q, first = msg
            self.played = PlayedCurve(self.dt, q)
            n = ticks_of(time.monotonic() - self.t0, self.period) + 1  # after now: none twice
            self.n = n if first is None else max(n, first)
            self.holding = False
        elif kind == "curve":
            _, self.dt, arm_names, jaw_names, arm_idx, jaw_idx = msg
            self.publisher.curve(arm_names, jaw_names, arm_idx, jaw_idx)
        elif kind == "stop":
            return True
        return False

    def hold(self, why: str) -> None:
        if not self.holding:
            self.holding = True
            self.report(("held", why, self.sent, time.monotonic()))

    # -- the loop ---------------------------------------------------------------------------------
    def run(self) -> str:
        """Ticks until stopped; returns why: 'stop', 'gone' (the planner process), or a signal's
        name. Until SLEEP_S before a tick: waits for commands; then makes the tick's set-point,
        sleeps until it is due, looks at the commands once more (any: made again) and writes it."""
        try:
            while True:
                if not self.flush_out():
                    return "gone"
                if _SIGNAL:
                    return self._after_signal(_SIGNAL[0])
                now = time.monotonic()
                if self.holding:
                    if self.ctl.poll(POLL_S) and self.handle(self.ctl.recv()):
                        return "stop"
                    continue
                due = self.t0 + self.n * self.period
                if due - now > SLEEP_S:
                    if self.ctl.poll(min(due - now - SLEEP_S, POLL_S)):
                        if self.handle(self.ctl.recv()):
                            return "stop"
                    elif time.monotonic() - self.last_heard > self.parent_timeout_s:
                        self.hold(f"the planner process silent for "
                                  f"{time.monotonic() - self.last_heard:.3f} s")
                    continue
                # a tick found a period late or more is skipped, not sent late
                self.n = max(self.n, ticks_of(now - self.t0, self.period))
                if self.prepared is None or self.prepared[0] != self.n:
                    self.prepared = self.prepare(self.n)
                delay = self.t0 + self.n * self.period - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if self.ctl.poll(0):  # a hold, or a piece for this very tick
                    if self.handle(self.ctl.recv()):
                        return "stop"
                    continue
                if ticks_of(time.monotonic() - self.t0, self.period) > self.n:
                    continue  # woken a period late: the tick after, made again
                self.send(self.prepared)
                self.prepared = None
                self.n += 1
        except (EOFError, OSError):
            return "gone"

    def prepare(self, n: int) -> tuple:
        t = n * self.period
        q, v, piece = self.played.sample(t, commit=True)
        return n, t, q, piece, self.publisher.prepare(q, v, self.t0_wall_ns + round(t * 1e9))

    def send(self, prepared) -> None:
        n, t, q, piece, messages = prepared
        self.publisher.send(messages)
        at = time.monotonic()
        self.sent += 1
        self.report(("sent", self.epoch, n, t, at, piece, q.tolist(), self.dropped),
                    droppable=True)

    def _after_signal(self, name: str) -> str:
        """Held at once; said to the planner process, whose stop is waited for (a while)."""
        self.hold(f"{name} to the servo process")
        self.report(("signal", name))
        end = time.monotonic() + STOP_WAIT_S
        try:
            while time.monotonic() < end:
                self.flush_out()
                if self.ctl.poll(POLL_S) and self.handle(self.ctl.recv()):
                    break
        except (EOFError, OSError):
            pass
        return name


def warm_up(publisher) -> None:
    """Everything a tick runs, once, before the first epoch (imports, first calls: the first
    tick must not pay for them)."""
    curve = PlayedCurve(0.05, np.zeros((3, 7)))
    q, v, _ = curve.sample(0.01)
    curve.add(1, np.ones((2, 7)), (np.zeros(7), np.zeros(7)))
    q, v, _ = curve.sample(0.06)
    names = [f"j{i}" for i in range(6)]
    publisher.curve(names, ["jaw"], list(range(6)), [6])
    publisher.prepare(q, v, 0)
    publisher.arm_names = publisher.jaw_names = publisher.arm_idx = publisher.jaw_idx = None


def real_time(priority: int) -> str | None:
    """This process's threads under SCHED_FIFO at `priority` (1..99; 0: nothing done): the tick
    loop's and Cyclone's own (a write may wait on them); why not, or None."""
    if not priority:
        return None
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    try:
        for tid in tids:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return f"SCHED_FIFO not permitted ({exc.strerror if isinstance(exc, OSError) else exc})"
    return None


def main(argv=None) -> int:
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    argv = sys.argv[1:] if argv is None else argv
    ctl = Connection(int(argv[0]), writable=False)
    rep_fd = int(argv[1])
    os.set_blocking(rep_fd, False)
    try:
        _, config = ctl.recv()
    except (EOFError, OSError):
        return 0
    from .dds import Bus

    bus = Bus(config["domain"])
    stream = Stream(ctl, rep_fd, config["period"], config["parent_timeout_s"],
                    Publisher(bus, config["servo_topic"], config["jaw_topic"]))
    warm_up(stream.publisher)
    stream.report(("ready", os.getpid(), real_time(config.get("priority", 0))))
    why = stream.run()
    stream.holding = True
    if why == "gone":
        print("serve: servo process: the planner process is gone: holding the last set-point "
              f"({stream.sent} sent)", file=sys.stderr, flush=True)
    bus.flush()
    stream.report(("stopped", stream.sent))
    stream.flush_out()
    return 0


# -- the planner process's side -------------------------------------------------------------------
class ServoProcess:
    """The servo process, from the planner process: `send` commands; a thread receives the
    reports: `added` ones answer `add`, the others are `take`n by the node's loop."""

    def __init__(self, config: dict, start_timeout_s: float = 60.0):
        ctl_r, ctl_w = os.pipe()
        rep_r, rep_w = os.pipe()
        # blocked while the child starts: it inherits the mask, and unblocks them once its own
        # handlers are in place (a Ctrl-C meanwhile: held here until after Popen, then delivered)
        sigs = {signal.SIGINT, signal.SIGTERM}
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "surestep_ocp.ros.servo", str(ctl_r), str(rep_w)],
                pass_fds=(ctl_r, rep_w), stdin=subprocess.DEVNULL)
        finally:
            os.close(ctl_r)
            os.close(rep_w)
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        self.ctl = Connection(ctl_w, readable=False)
        self.rep = Connection(rep_r, writable=False)
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._reports: deque = deque()
        self._answers: dict = {}
        self._ids = 0
        self.pid: int | None = None
        self.priority_error: str | None = None  # why the real-time scheduler was not had
        self.gone = False  # its report pipe closed: it ended
        self.last_sent = time.monotonic()  # the last command sent (the heartbeat's clock)
        self.send(("config", config))
        self._rx = threading.Thread(target=self._receive, name="surestep-servo-reports",
                                    daemon=True)
        self._rx.start()

    def _receive(self) -> None:
        while True:
            try:
                msg = self.rep.recv()
            except (EOFError, OSError):
                with self._cond:
                    self.gone = True
                    self._cond.notify_all()
                return
            with self._cond:
                if msg[0] == "added":
                    self._answers[msg[1]] = msg
                elif msg[0] == "ready":
                    self.pid, self.priority_error = msg[1], msg[2]
                else:
                    self._reports.append(msg)
                self._cond.notify_all()

    def send(self, msg) -> bool:
        """False when the servo process is gone."""
        try:
            with self._send_lock:
                self.ctl.send(msg)
                self.last_sent = time.monotonic()
            return True
        except (OSError, ValueError):
            return False

    def take(self, timeout_s: float) -> list:
        """The reports received (waiting up to `timeout_s` for one)."""
        with self._cond:
            if not self._reports and not self.gone:
                self._cond.wait(timeout_s)
            out = list(self._reports)
            self._reports.clear()
        return out

    def wait_gone(self, timeout_s: float) -> bool:
        """Sleeps `timeout_s` unless the servo process ends meanwhile; True if it has."""
        with self._cond:
            if not self.gone and timeout_s > 0:
                self._cond.wait_for(lambda: self.gone, timeout_s)
            return self.gone

    def wait_ready(self, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        with self._cond:
            while self.pid is None and not self.gone and time.monotonic() < end:
                self._cond.wait(0.05)
            return self.pid is not None

    def add(self, epoch: int, k: int, q, start, stop=None) -> tuple | None:
        """A re-plan's piece from waypoint k: the servo process's answer (added, id, kept,
        sampled up to, received), or None if it is gone (or `stop` is set meanwhile)."""
        with self._cond:
            self._ids += 1
            ident = self._ids
        if not self.send(("piece", ident, epoch, k, q, start)):
            return None
        with self._cond:
            while ident not in self._answers:
                if self.gone or (stop is not None and stop.is_set()):
                    return None
                self._cond.wait(0.05)
            return self._answers.pop(ident)

    def beat(self, every_s: float = 0.1) -> None:
        if time.monotonic() - self.last_sent > every_s:
            self.send(("beat",))

    def close(self, timeout_s: float = 3.0) -> int | None:
        """Stop it (its writers flushed) and wait; killed if it does not end. Its exit code."""
        self.send(("stop",))
        try:
            self.ctl.close()
        except OSError:
            pass
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


if __name__ == "__main__":
    sys.exit(main())
