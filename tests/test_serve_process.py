"""The servo process of `surestep serve` (surestep_ocp/ros/servo.py) on its own, without a Planner:
its tick loop in this process with a stand-in publisher (pieces kept or refused at their waypoint,
a hold, a new epoch on the same servo clock, the planner's silence, stop); then the process itself
over loopback DDS, driven by a stand-in planner process: its set-points decoded by rosbags, SIGTERM
to it (held, said, stopped by its planner, exit 0), and its planner killed (it ends by itself: no
orphan)."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from multiprocessing import Pipe
from multiprocessing.connection import Connection

import numpy as np
import pytest

from surestep_ocp.ros.servo import Stream

PERIOD, DT = 0.005, 0.05


class Publisher:
    """The stand-in: what would be written, in order."""

    def __init__(self):
        self.sent = []

    def curve(self, *names):
        self.names = names

    def prepare(self, q, v, ns):
        return (np.array(q), np.array(v), ns)

    def send(self, prepared):
        self.sent.append(prepared)


class Driver:
    """The planner process's side of a Stream running in a thread of this one."""

    def __init__(self, parent_timeout_s=5.0):
        self.ctl_r, self.ctl = Pipe(duplex=False)
        rep_r, rep_w = os.pipe()
        os.set_blocking(rep_w, False)
        self.rep = Connection(rep_r, writable=False)
        self.pub = Publisher()
        self.stream = Stream(self.ctl_r, rep_w, PERIOD, parent_timeout_s, self.pub)
        self.why = None
        self.reports = []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        self.ctl.send(("curve", DT, ["a"] * 6, ["jaw"], list(range(6)), [6]))

    def _run(self):
        self.why = self.stream.run()

    def until(self, kind, timeout=20.0):
        """Reports up to the first of `kind` (waits for it)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.rep.poll(0.05):
                r = self.rep.recv()
                self.reports.append(r)
                if r[0] == kind:
                    return r
        raise AssertionError(f"no {kind} report; got {[r[0] for r in self.reports][-20:]}")


def _plan(n=20, scale=0.01):
    return np.cumsum(np.full((n + 1, 7), scale), axis=0)


def test_ticks_pieces_hold_and_a_new_epoch():
    d = Driver()
    t0 = time.monotonic() + 0.05
    wall = 1_700_000_000_000_000_000
    d.ctl.send(("epoch", 0, t0, wall, _plan(), 0))
    while d.until("sent")[3] < 1.5 * DT:  # past waypoint 1
        pass
    # a piece from a waypoint far ahead is kept; one from a waypoint already passed is not
    d.ctl.send(("piece", 1, 0, 15, _plan(5, 0.02) + _plan()[15] - _plan(5, 0.02)[0], None))
    kept = d.until("added")
    assert kept[1] == 1 and kept[2] is True
    d.ctl.send(("piece", 2, 0, 1, _plan(), None))
    refused = d.until("added")
    assert refused[1] == 2 and refused[2] is False and refused[3] > 0
    d.ctl.send(("piece", 3, 7, 16, _plan(), None))  # another epoch's: not kept
    assert d.until("added")[2] is False
    d.ctl.send(("hold", "test"))
    held = d.until("held")
    assert held[1] == "test" and held[3] <= time.monotonic()
    count = len(d.pub.sent)
    assert held[2] == count  # nothing sent after the hold
    time.sleep(0.05)
    assert len(d.pub.sent) == count
    # a new epoch: the clock runs on (t0 moved by whole ticks), the new motion from its start
    t1 = t0 + 100 * PERIOD
    d.ctl.send(("epoch", 1, t1, wall + round(100 * PERIOD * 1e9), _plan() + 1.0, None))
    sent = d.until("sent")
    assert sent[1] == 1 and len(d.pub.sent) > count
    d.ctl.send(("stop",))
    d.thread.join(10)
    assert d.why == "stop"
    ticks = np.array([(ns - wall) * 1e-9 for _, _, ns in d.pub.sent]) / PERIOD
    assert np.all(np.diff(ticks) > 0)
    assert np.abs(ticks - np.round(ticks)).max() < 1e-6  # one servo clock across the epochs
    # the new motion: at rest at its start until its waypoint 0
    assert all(np.allclose(q, _plan()[0] + 1.0) and not v.any() for q, v, _ in d.pub.sent[count:])
    # every set-point reported, in order
    while d.rep.poll(0.1):
        d.reports.append(d.rep.recv())
    reported = [r for r in d.reports if r[0] == "sent"]
    assert len(reported) == len(d.pub.sent)
    assert [(r[1], r[2]) for r in reported] == sorted((r[1], r[2]) for r in reported)


def test_the_planners_silence_holds():
    d = Driver(parent_timeout_s=0.2)
    d.ctl.send(("epoch", 0, time.monotonic() + 0.02, 0, _plan(), 0))
    held = d.until("held")
    assert "planner process silent" in held[1]
    d.ctl.send(("stop",))
    d.thread.join(10)
    assert d.why == "stop"


PLANNER = r"""
import json, os, sys, time
import numpy as np
from surestep_ocp.ros.servo import ServoProcess

servo = ServoProcess({"domain": int(sys.argv[1]), "servo_topic": "/PSM1/servo_jp",
                      "jaw_topic": "/PSM1/jaw/servo_jp", "period": 0.005,
                      "parent_timeout_s": 5.0, "priority": int(sys.argv[2])})
assert servo.wait_ready(60)
print(json.dumps({"servo_pid": servo.pid, "priority_error": servo.priority_error}), flush=True)
names = ["yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw"]
servo.send(("curve", 0.05, names, ["jaw"], list(range(6)), [6]))
q = np.linspace(0, 0.1, 41)[:, None] * np.ones(7)
servo.send(("epoch", 0, time.monotonic() + 0.5, time.time_ns() + 500_000_000, q, 0))
while not servo.gone:
    for r in servo.take(0.05):
        if r[0] != "sent":
            print(json.dumps({"report": r[0]}), flush=True)
        if r[0] == "signal":
            servo.send(("stop",))
    servo.beat()
print(json.dumps({"servo_exit": servo.proc.wait(10)}), flush=True)
"""


def _lines(p):
    while True:
        line = p.stdout.readline()
        if not line:
            return
        yield json.loads(line)


def test_the_servo_process_over_dds(tmp_path):
    pytest.importorskip("cyclonedds")
    from serve_dds import Recorder, alive, free_domain, loopback_env, set_points

    from surestep_ocp.ros import messages as m

    domain = free_domain()
    env = loopback_env(tmp_path, domain)
    os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]
    try:
        rec = Recorder(domain, {"/PSM1/servo_jp": m.JointState,
                                "/PSM1/jaw/servo_jp": m.JointState})
        # SIGTERM to the servo process: it holds, says so; its planner stops it; exit 0. Under
        # the real-time scheduler (--servo-priority) where this machine permits it
        p = subprocess.Popen([sys.executable, "-c", PLANNER, str(domain), "10"], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        lines = _lines(p)
        ready = next(lines)
        servo_pid = ready["servo_pid"]
        if ready["priority_error"] is None:  # every thread: the tick loop's and Cyclone's
            tids = [int(t) for t in os.listdir(f"/proc/{servo_pid}/task")]
            assert len(tids) > 1
            assert all(os.sched_getscheduler(t) == os.SCHED_FIFO for t in tids)
        else:
            assert "SCHED_FIFO not permitted" in ready["priority_error"]
        while len(rec.samples["/PSM1/servo_jp"]) < 50:
            rec.poll()
            time.sleep(0.01)
            assert p.poll() is None, p.stderr.read()
        os.kill(servo_pid, signal.SIGTERM)
        said = [d for d in lines]
        p.wait(30)
        assert {"report": "held"} in said and {"report": "signal"} in said, said
        assert said[-1] == {"servo_exit": 0}
        assert p.returncode == 0 and "Traceback" not in p.stderr.read()
        time.sleep(0.3)
        rec.poll()
        n = len(rec.samples["/PSM1/servo_jp"])
        t, q, servo, jaw = set_points(rec)
        assert n >= 50 and len(jaw) == n
        assert all(list(s.name)[0] == "yaw" and len(s.position) == 6 for _, s in servo)
        assert np.all(np.diff(t) > 0)
        ticks = (t - t[0]) / 0.005
        assert np.abs(ticks - np.round(ticks)).max() < 1e-3
        # its planner killed: it ends by itself (the pipe closed), no orphan
        p = subprocess.Popen([sys.executable, "-c", PLANNER, str(domain), "0"], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        servo_pid = next(_lines(p))["servo_pid"]
        assert os.sched_getscheduler(servo_pid) == os.SCHED_OTHER
        while len(rec.samples["/PSM1/servo_jp"]) < n + 20:
            rec.poll()
            time.sleep(0.01)
        p.kill()
        # its stdout and stderr are the servo process's too: they end when it does
        _, err = p.communicate(timeout=30)
        end = time.monotonic() + 10  # (its files close a moment before it ends)
        while alive(servo_pid) and time.monotonic() < end:
            time.sleep(0.02)
        assert not alive(servo_pid), f"servo process {servo_pid} still running"
        assert "the planner process is gone" in err and "Traceback" not in err, err
    finally:
        del os.environ["CYCLONEDDS_URI"]
