"""Shared by the serve tests and benchmarks/serve_loop.py: a Cyclone configuration confined to the
loopback interface (no multicast, the peer listed as 127.0.0.1), a free domain id, and a recorder
that takes every sample's bytes off the wire for an independent decoder (rosbags)."""

from __future__ import annotations

import os
import time
from pathlib import Path

def loopback_env(tmp: Path, domain: int, trace: bool = False) -> dict:
    """The environment of a process confined to loopback DDS on `domain` (CYCLONEDDS_URI, and
    ROS_DOMAIN_ID); `trace`: Cyclone's configuration trace of each process in
    tmp/cyclone-PID.log."""
    from surestep_ocp.ros.loopback import write_loopback_config

    uri = write_loopback_config(tmp / "cyclonedds.xml",
                                f"{tmp}/cyclone-${{CYCLONEDDS_PID}}.log" if trace else None)
    return {**os.environ, "CYCLONEDDS_URI": uri, "ROS_DOMAIN_ID": str(domain),
            "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def free_domain() -> int:
    """A domain id unlikely to be in use by another test run on this machine (1..200)."""
    return 1 + (os.getpid() * 7 + int(time.time())) % 200


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
