"""The DDS side of the ROS 2 nodes: one Cyclone participant, ROS 2 topics written and read with
the QoS a ROS 2 node uses.

Writers are reliable, keep-last 10, volatile (ROS 2's default profile); readers are best-effort
(they match reliable and best-effort writers alike, as a sensor subscription does) and keep the
last `depth` samples. Samples are XCDR1 (`DataRepresentation` CDR only), as ROS 2 reads them.
The domain is ROS_DOMAIN_ID's (or --domain-id); the transport is Cyclone's own configuration:
CYCLONEDDS_URI, as for every ROS 2 process on Cyclone DDS.
"""

from __future__ import annotations

from cyclonedds.core import Qos, Policy
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from .names import dds_topic

try:  # the binding's own write of serialized bytes (DataWriter.write: serialize, pad, this)
    from cyclonedds._clayer import ddspy_write as _ddspy_write
except ImportError:  # pragma: no cover (another binding version: DataWriter.write)
    _ddspy_write = None

_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)
WRITER_QOS = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)),
                 Policy.History.KeepLast(10), Policy.Durability.Volatile, _XCDR1)


def reader_qos(depth: int) -> Qos:
    return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(depth),
               Policy.Durability.Volatile, _XCDR1)


class Bus:
    """One participant on `domain`: `writer(topic, Type)`, `reader(topic, Type, depth)`, `take`,
    `flush`."""

    def __init__(self, domain: int):
        self.participant = DomainParticipant(domain)
        self._topics: dict[str, Topic] = {}
        self._writers: list[DataWriter] = []

    def _topic(self, ros_name: str, kind) -> Topic:
        if ros_name not in self._topics:
            self._topics[ros_name] = Topic(self.participant, dds_topic(ros_name), kind)
        return self._topics[ros_name]

    def writer(self, ros_name: str, kind) -> DataWriter:
        w = DataWriter(self.participant, self._topic(ros_name, kind), qos=WRITER_QOS)
        self._writers.append(w)
        return w

    def reader(self, ros_name: str, kind, depth: int = 10) -> DataReader:
        return DataReader(self.participant, self._topic(ros_name, kind), qos=reader_qos(depth))

    @staticmethod
    def take(reader: DataReader, n: int = 64) -> list:
        """The samples received since the last take (valid ones only), oldest first."""
        return [s for s in reader.take(n) if not hasattr(s, "sample_info") or
                s.sample_info.valid_data]

    @staticmethod
    def serialized(writer: DataWriter, sample) -> tuple:
        """`sample` serialized for `writer` ahead of time: `write_serialized` then writes it
        without serializing it (the servo process's tick: its set-points are made before the tick
        is due, only written at it)."""
        data = sample.serialize(use_version_2=getattr(writer, "_use_version_2", False))
        return sample, data.ljust((len(data) + 3) & ~3, b"\0")  # 4-byte aligned, as write pads

    @staticmethod
    def write_serialized(writer: DataWriter, prepared: tuple) -> None:
        sample, data = prepared
        if _ddspy_write is None or not hasattr(writer, "_ref"):
            writer.write(sample)
            return
        if _ddspy_write(writer._ref, data) < 0:
            writer.write(sample)  # raises the binding's own DDSException

    def flush(self, timeout_s: float = 0.2) -> None:
        """Wait (at most `timeout_s` per writer) until every matched reader acknowledged the samples
        written, so that the last ones are not lost when the process ends."""
        for w in self._writers:
            try:
                w.wait_for_acks(duration(seconds=timeout_s))
            except Exception:  # noqa: BLE001 (a reader gone away: nothing left to wait for)
                pass
