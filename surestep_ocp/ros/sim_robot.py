"""`surestep sim-robot`: a simulated PSM and tracker on the dVRK's ROS 2 topics, so that
`surestep serve` runs its whole loop without a robot.

The arm: `/ARM/measured_js` and `/ARM/jaw/measured_js` at `rate`, starting at the problem's start
joints and following the last `servo_jp` / `jaw/servo_jp` set-point within the joint velocity
limits and the joint bounds (each tick moves at most v_max / rate towards it). `/ECM/measured_js`:
the problem's ECM joints (still). The tracker (`SimulatedTracker`, the evaluation's motion and
observation noise and EKF): at the problem's tracker rate the tool moves as the arm's kinematics did
since the last frame (camera-frame displacement, body-frame rotation, as closed_loop commands it),
with the model's motion noise, and is observed; the detector (`rollout.Detection`) misses a tool
outside the image region; a missed frame is not published (the simulated EKF still updates with
it: an approximation). Each estimate is stamped with its image's time and published `latency` s
later on the tracker topic (geometry_msgs/PoseWithCovarianceStamped, camera frame).
`meshcat_hz`: a Meshcat view (viz/live.py, its own server on 127.0.0.1) of the arm and the
tracker's belief, updated from a thread at that rate.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

from ..evaluation.tracker import SimulatedTracker
from ..methods.registry import run_method
from ..model.detection import Detection
from ..model.limits import problem_limits
from . import messages as m
from .dds import Bus
from .estimate import quaternion
from .sim_faults import active

SERVO_SILENT_S = 0.1  # [s] servo_jp this long silent: said on stderr (the arm holds regardless)


class SimRobot:
    def __init__(self, setup, ecm_joints, arm, tracker_topic, domain, rate, seed, latency, duration,
                 faults, meshcat_hz: float = 0.0):
        self.setup, self.rate, self.latency, self.duration = setup, rate, latency, duration
        self.faults, self.ecm_joints = faults, ecm_joints
        names = list(setup.robot.joint_names)
        self.names = names
        self.arm_idx = [i for i, n in enumerate(names) if n != "jaw"]
        self.jaw_idx = [i for i, n in enumerate(names) if n == "jaw"]
        self.q = np.array(setup.q_start, float)
        self.target = self.q.copy()
        lim = problem_limits(setup)
        self.vmax = np.array(lim.velocity, float)
        self.lower, self.upper = np.array(setup.robot.lower), np.array(setup.robot.upper)
        self.tracker = SimulatedTracker(setup.eval_model, setup.pose_of(self.q), rng=seed)
        self.detection, self.rng = Detection(), np.random.default_rng(seed + 1)
        self.frame_dt = setup.ocp.timing.step_s
        bus = self.bus = Bus(domain)
        self.w_meas = bus.writer(f"/{arm}/measured_js", m.JointState)
        self.w_jaw = bus.writer(f"/{arm}/jaw/measured_js", m.JointState)
        self.w_ecm = bus.writer("/ECM/measured_js", m.JointState)
        self.w_pose = bus.writer(tracker_topic, m.PoseWithCovarianceStamped)
        self.r_servo = bus.reader(f"/{arm}/servo_jp", m.JointState, depth=50)
        self.r_jaw = bus.reader(f"/{arm}/jaw/servo_jp", m.JointState, depth=50)
        self.pending: deque = deque()  # (publish at, message)
        self.first_servo: float | None = None
        self.last_servo, self.silent_said = 0.0, False
        self.stop: str | None = None
        self._fault_on: dict = {}
        self.meshcat_hz, self.view = meshcat_hz, None
        self.counts = {"measured": 0, "estimates": 0, "missed": 0, "servo": 0}

    def _on_signal(self, signum, _frame) -> None:
        self.stop = signal.Signals(signum).name

    def run(self) -> int:
        for s in (signal.SIGINT, signal.SIGTERM):
            signal.signal(s, self._on_signal)
        print(f"sim-robot: {self.w_meas.topic.name[2:]} at {self.rate:g} Hz, tracker "
              f"{self.w_pose.topic.name[2:]} at {1 / self.frame_dt:g} Hz", file=sys.stderr,
              flush=True)
        if self.meshcat_hz:
            self._start_view()
        t0, n = time.monotonic(), 0
        next_frame, x_prev = t0, self.setup.pose_of(self.q)
        while self.stop is None:
            now = time.monotonic()
            if self.duration and now - t0 > self.duration:
                break
            fault_t = None if self.first_servo is None else now - self.first_servo
            self._say_faults(fault_t)
            self._follow(fault_t)
            self._servo_silence(now)
            self._publish_joints(n)
            if now >= next_frame:
                x_prev = self._frame(x_prev, fault_t)
                next_frame += self.frame_dt
            while self.pending and self.pending[0][0] <= now:
                self.w_pose.write(self.pending.popleft()[1])
            n += 1
            time.sleep(max(0.0, t0 + n / self.rate - time.monotonic()))
        self.bus.flush()
        c = self.counts
        print(f"sim-robot: stopped ({self.stop or 'duration'}); {c['servo']} servo_jp received, "
              f"{c['measured']} measured_js and {c['estimates']} estimates sent, {c['missed']} "
              "frames missed by the detector"
              + (f", {self.view.updates} Meshcat updates sent" if self.view else ""), flush=True)
        return 0

    def _start_view(self) -> None:
        """The Meshcat view (its server on 127.0.0.1) and the thread that updates it."""
        from ..viz import live, server  # meshcat: loaded on use

        vis = server.visualizer()
        self.view = live.LiveView(run_method(self.setup, "baseline").to_dict(), vis)
        print(f"sim-robot: Meshcat view at {vis.url()} (the arm and the tracker's belief at "
              f"{self.meshcat_hz:g} Hz)", file=sys.stderr, flush=True)

        def loop():
            period = 1.0 / self.meshcat_hz
            while self.stop is None:
                tr = self.tracker
                self.view.update(self.q.copy(), tr.mean.copy(), tr.covariance.copy())
                time.sleep(period)

        threading.Thread(target=loop, name="meshcat-view", daemon=True).start()

    def _say_faults(self, fault_t) -> None:
        """Each injected fault's start and end on stderr (with the wall time, for the
        benchmark's delays)."""
        for f in self.faults:
            on = f.active(f.kind, fault_t)
            if on != self._fault_on.get(f, False):
                self._fault_on[f] = on
                print(f"sim-robot: fault {f.kind} {'on' if on else 'off'} at {fault_t:.3f} s "
                      f"(wall {time.time():.6f})", file=sys.stderr, flush=True)

    def _servo_silence(self, now: float) -> None:
        """Say once when servo_jp stops (the arm holds its last set-point, as the dVRK does)."""
        if self.first_servo is None or self.silent_said:
            return
        if now - self.last_servo > SERVO_SILENT_S:
            self.silent_said = True
            print(f"sim-robot: servo_jp silent for {now - self.last_servo:.3f} s: holding the last "
                  f"set-point ({now - self.first_servo:.3f} s after the first)", file=sys.stderr,
                  flush=True)

    def _follow(self, fault_t) -> None:
        for msg in Bus.take(self.r_servo, 200):
            if len(msg.position) == len(self.arm_idx) and np.all(np.isfinite(msg.position)):
                self.target[self.arm_idx] = msg.position
                self.counts["servo"] += 1
                self.last_servo = time.monotonic()
                if self.first_servo is None:
                    self.first_servo = self.last_servo
        for msg in Bus.take(self.r_jaw, 200):
            if len(msg.position) == len(self.jaw_idx) and np.all(np.isfinite(msg.position)):
                self.target[self.jaw_idx] = msg.position
        if active(self.faults, "stuck", fault_t):
            return
        step = np.clip(self.target - self.q, -self.vmax / self.rate, self.vmax / self.rate)
        self.q = np.clip(self.q + step, self.lower, self.upper)

    def _publish_joints(self, n: int) -> None:
        stamp = m.Header(stamp=m.stamp(time.time_ns()))
        arm = [self.names[i] for i in self.arm_idx]
        self.w_meas.write(m.JointState(header=stamp, name=arm,
                                       position=self.q[self.arm_idx].tolist()))
        if self.jaw_idx:
            self.w_jaw.write(m.JointState(header=stamp, name=["jaw"],
                                          position=self.q[self.jaw_idx].tolist()))
        self.counts["measured"] += 1
        if self.setup.ecm is not None and n % max(1, round(self.rate / 10)) == 0:
            ecm = self.ecm_joints
            if ecm is not None:
                self.w_ecm.write(m.JointState(header=stamp, name=list(
                    self.setup.ecm.joint_names), position=list(map(float, ecm))))

    def _frame(self, x_prev, fault_t):
        """One tracker frame: the tool moved as the arm did since the last one; observed."""
        stamp_ns = time.time_ns()
        x_now = self.setup.pose_of(self.q)
        tr = self.tracker
        R = Rotation.from_rotvec(tr.mean[3:]) * Rotation.from_rotvec(x_prev[3:]).inv() \
            * Rotation.from_rotvec(x_now[3:])
        mean, cov = tr.move_to(np.hstack([tr.mean[:3] + x_now[:3] - x_prev[:3], R.as_rotvec()]))
        seen = self.rng.random() < self.detection.probability(
            self.setup.eval_model.camera, tr.true_pose[None, :3])[0]
        if active(self.faults, "tracker-silent", fault_t):
            return x_now
        if not seen:
            self.counts["missed"] += 1
            return x_now
        if active(self.faults, "nan", fault_t):
            mean = np.full(6, np.nan)
        q = quaternion(mean[3:]) if np.all(np.isfinite(mean)) else np.full(4, np.nan)
        msg = m.PoseWithCovarianceStamped(
            header=m.Header(stamp=m.stamp(stamp_ns), frame_id="camera"),
            pose=m.PoseWithCovariance(pose=m.Pose(m.Point(*map(float, mean[:3])),
                                                  m.Quaternion(*map(float, q))),
                                      covariance=[float(c) for c in np.ravel(cov)]))
        self.pending.append((time.monotonic() + self.latency, msg))
        self.counts["estimates"] += 1
        return x_now
