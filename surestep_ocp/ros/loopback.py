"""A Cyclone DDS configuration confined to this machine: the loopback interface only, multicast
off, the one peer 127.0.0.1 (unicast discovery of the participants on it). For the demo, the
tests and the benchmark: `CYCLONEDDS_URI=file://...` of the file written here; nothing leaves
127.0.0.1. (A lab uses its own CYCLONEDDS_URI, as every ROS 2 process on Cyclone.)

    .venv/bin/python -m surestep_ocp.ros.loopback out/cyclonedds.xml   # prints the URI
"""

from __future__ import annotations

import sys
from pathlib import Path

LOOPBACK_XML = """<?xml version="1.0" encoding="UTF-8"?>
<CycloneDDS><Domain Id="any">
  <General>
    <Interfaces><NetworkInterface name="lo"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
  {tracing}
</Domain></CycloneDDS>
"""


def write_loopback_config(path: str | Path, trace_file: str | None = None) -> str:
    """Write the configuration to `path` (with Cyclone's configuration trace to `trace_file`, in
    which `${CYCLONEDDS_PID}` is each process's id); returns its `file://` URI."""
    tracing = (f"<Tracing><Verbosity>config</Verbosity><OutputFile>{trace_file}</OutputFile>"
               "</Tracing>" if trace_file else "")
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(LOOPBACK_XML.format(tracing=tracing))
    return path.as_uri()


if __name__ == "__main__":
    print(write_loopback_config(sys.argv[1] if len(sys.argv) > 1 else "cyclonedds.xml"))
