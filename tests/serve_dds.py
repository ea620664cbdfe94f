"""Shared by the serve tests and benchmarks/serve_loop.py: a Cyclone configuration confined to the
loopback interface (no multicast, the peer listed as 127.0.0.1), a free domain id, a recorder
that takes every sample's bytes off the wire for an independent decoder (rosbags), and the checks
the tests share (set-points within the limits, the node's servo process ended)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SURESTEP = [sys.executable, "-m", "surestep_ocp.cli"]


def loopback_env(tmp: Path, domain: int, trace: bool = False) -> dict:
    """The environment of a process confined to loopback DDS on `domain` (CYCLONEDDS_URI, and
    ROS_DOMAIN_ID); `trace`: Cyclone's configuration trace of each process in
    tmp/cyclone-PID.log."""
    from surestep_ocp.ros.loopback import write_loopback_config

    uri = write_loopback_config(tmp / "cyclonedds.xml",
                                f"{tmp}/cyclone-${{CYCLONEDDS_PID}}.log" if trace else None)
    return {**os.environ, "CYCLONEDDS_URI": uri, "ROS_DOMAIN_ID": str(domain),
            "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


_HELD: list = []  # the open lock files of the domains this process holds (released at its exit)


def free_domain() -> int:
    """A domain id (1..200) no other process of this machine holds: each is reserved by an exclusive
    lock on its own file, held until this process exits (pytest-xdist's workers run DDS pairs at
    the same time; a domain shared by two pairs mixes their messages)."""
    import fcntl
    import random
    import tempfile

    folder = Path(tempfile.gettempdir()) / "surestep-dds-domains"
    folder.mkdir(exist_ok=True)
    for domain in random.Random(os.getpid()).sample(range(1, 201), 200):
        f = open(folder / f"{domain}.lock", "w")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        _HELD.append(f)
        return domain
    raise RuntimeError("no free DDS domain id: 200 held by other processes")


class Recorder:
    """Readers (reliable, deep) on ROS 2 topics; `poll()` keeps each sample's raw CDR bytes and its
    arrival time, by topic."""

    def __init__(self, domain: int, topics: dict):
        from cyclonedds.core import Policy, Qos
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        self.participant = DomainParticipant(domain)
        qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                  Policy.History.KeepLast(5000), Policy.Durability.Volatile)
        self.readers = {name: DataReader(self.participant,
                                         Topic(self.participant, "rt" + name, kind), qos=qos)
                        for name, kind in topics.items()}
        self.samples = {name: [] for name in topics}

    def poll(self) -> None:
        from cyclonedds._clayer import ddspy_take
        from cyclonedds.core import InstanceState, SampleState, ViewState

        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        for name, r in self.readers.items():
            for data, info in ddspy_take(r._ref, mask, 1000):
                if info.valid_data:
                    self.samples[name].append((time.time(), bytes(data)))

    def decoded(self, name: str, ros_type: str) -> list:
        """(arrival time, message decoded by rosbags' ROS 2 Humble type store) of every sample."""
        from rosbags.typesys import Stores, get_typestore

        ts = get_typestore(Stores.ROS2_HUMBLE)
        return [(t, ts.deserialize_cdr(b, ros_type)) for t, b in self.samples[name]]


def topics() -> dict:
    """The topics the serve tests record, with the package's DDS types."""
    from surestep_ocp.ros import messages as m

    return {"/PSM1/servo_jp": m.JointState, "/PSM1/jaw/servo_jp": m.JointState,
            "/PSM1/measured_js": m.JointState, "/PSM1/tracker/pose": m.PoseWithCovarianceStamped,
            "/surestep/plan": m.JointTrajectory, "/surestep/status": m.String,
            "/surestep/trace": m.Float64, "/surestep/planned_trace": m.Float64,
            "/surestep/confidence": m.Float64, "/surestep/goal": m.PoseStamped}


def run_pair(tmp: Path, problem: str, serve_args: list, sim_args: list, until,
             timeout_s: float = 240.0) -> dict:
    """sim-robot and serve in their own processes, a recorder here; `until(rec, serve, domain)`
    True ends the wait (then serve gets SIGTERM if it still runs). Returns the outputs, the
    recorder and the node's --log."""
    domain = free_domain()
    env = loopback_env(tmp, domain, trace=True)
    os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]  # the recorder's participant too
    rec = Recorder(domain, topics())
    sim = subprocess.Popen(SURESTEP + ["sim-robot", problem] + sim_args, env=env, cwd=tmp,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    serve = subprocess.Popen(SURESTEP + ["serve", problem, "--log", str(tmp / "log.json")]
                             + serve_args, env=env, cwd=tmp, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    deadline = time.time() + timeout_s
    try:
        while serve.poll() is None and time.time() < deadline and not until(rec, serve, domain):
            rec.poll()
            time.sleep(0.01)
        if serve.poll() is None:
            serve.send_signal(signal.SIGTERM)
        out, err = serve.communicate(timeout=30)
        rec.poll()
    finally:
        for p in (serve, sim):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        sim_out, sim_err = sim.communicate(timeout=30)
        del os.environ["CYCLONEDDS_URI"]
    log = json.loads((tmp / "log.json").read_text()) if (tmp / "log.json").exists() else None
    return {"code": serve.returncode, "out": out, "err": err, "sim_code": sim.returncode,
            "sim_out": sim_out, "sim_err": sim_err, "rec": rec, "log": log,
            "cyclone_logs": [f.read_text(errors="replace") for f in tmp.glob("cyclone-*.log")]}


def stamps(msgs) -> np.ndarray:
    """The header stamps [s] of decoded messages ((arrival, message) pairs)."""
    return np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in msgs])


def set_points(rec: Recorder, arm: str = "PSM1") -> tuple:
    """(stamps, joints with the jaw last, servo and jaw messages) of the recorded set-points."""
    servo = rec.decoded(f"/{arm}/servo_jp", "sensor_msgs/msg/JointState")
    jaw = rec.decoded(f"/{arm}/jaw/servo_jp", "sensor_msgs/msg/JointState")
    q = np.array([np.r_[s.position, j.position] for (_, s), (_, j) in zip(servo, jaw)])
    return stamps(servo), q, servo, jaw


def assert_stretch_within_limits(lim, t: np.ndarray, q: np.ndarray, tol: float = 1e-6) -> None:
    """Divided differences of set-points sampled from one played curve: a first one is a mean of
    the velocity, a second one (times 2) a value of the acceleration in between, so each is within
    its limit where the curve is."""
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    assert np.all(np.abs(v) <= lim.velocity * (1 + tol) + 1e-9), np.abs(v / lim.velocity).max()
    a = 2 * np.diff(v, axis=0) / (t[2:] - t[:-2])[:, None]
    assert np.all(np.abs(a) <= lim.acceleration * (1 + 1e-3) + 1e-6), \
        np.abs(a / lim.acceleration).max()


def alive(pid: int) -> bool:
    """The process runs (not ended, not a zombie)."""
    try:
        return "State:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


def assert_servo_process_ended(log) -> None:
    """The node's servo process (its pid and exit code in the node's --log) ended, exit 0 (its
    files close a moment before it ends: waited for, a while)."""
    servo = log["servo"]
    end = time.monotonic() + 10
    while alive(servo["pid"]) and time.monotonic() < end:
        time.sleep(0.02)
    assert not alive(servo["pid"]) and servo["exit"] == 0, servo
