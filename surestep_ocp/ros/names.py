"""ROS 2 names for `surestep serve` / `sim-robot`: the arm, the topics (checked as ROS 2 checks a
fully qualified topic name), the domain id; each bad value a one-line error naming its option.

No DDS here: the checks run before anything is imported or published.
"""

from __future__ import annotations

import os
import re

from ..errors import SurestepError, shown

ARMS = ("PSM1", "PSM2", "PSM3")  # the dVRK's patient-side arms (the problems plan a PSM)
DEFAULT_ARM = "PSM1"
CAMERA_ARM = "ECM"
DEFAULT_NAMESPACE = "/surestep"  # the node's own topics: plan, trace, status, goal
# the tracker's estimate (geometry_msgs/PoseWithCovarianceStamped, camera frame) by default
TRACKER_TOPIC = "/{arm}/tracker/pose"
MAX_DOMAIN_ID = 232  # ROS 2 / DDS: the UDP ports of higher ids overflow
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
MAX_TOPIC_LENGTH = 255 - len("rt/")  # DDS topic names (rmw's limit, less the prefix)


def check_arm(arm: str, option: str = "--arm") -> str:
    """A dVRK PSM's name (the problems plan a PSM)."""
    if arm not in ARMS:
        raise SurestepError(f"{option}: '{shown(arm)}' is not a dVRK patient-side arm "
                            f"({', '.join(ARMS)})")
    return arm


def check_topic(name: str, option: str) -> str:
    """`name` as a fully qualified ROS 2 topic name (a relative one is taken from the root `/`):
    tokens of letters, digits and `_`, none starting with a digit, no empty token, no `__`."""
    full = name if name.startswith("/") else "/" + name
    tokens = full[1:].split("/")
    bad = (not name or len(full) > MAX_TOPIC_LENGTH or "__" in full
           or any(not _TOKEN.match(t) for t in tokens))
    if bad:
        raise SurestepError(f"{option}: '{shown(name)}' is not a ROS 2 topic name (tokens of "
                            "letters, digits and _ separated by /, none empty or starting with a "
                            "digit, no __)")
    return full


def check_domain(value, option: str = "--domain-id") -> int:
    """A DDS domain id ROS 2 allows: a whole number in 0..MAX_DOMAIN_ID."""
    try:
        d = int(str(value).strip())
    except ValueError:
        d = -1
    if d < 0 or d > MAX_DOMAIN_ID or str(value).strip().lstrip("+") != str(d):
        raise SurestepError(f"{option}: '{shown(str(value))}' is not a domain id (a whole number "
                            f"0..{MAX_DOMAIN_ID})")
    return d


def domain_id(option_value) -> int:
    """The domain: --domain-id, else ROS_DOMAIN_ID, else 0 (as every ROS 2 process)."""
    if option_value is not None:
        return check_domain(option_value)
    env = os.environ.get("ROS_DOMAIN_ID", "").strip()
    return check_domain(env, "ROS_DOMAIN_ID") if env else 0


def dds_topic(ros_name: str) -> str:
    """ROS 2's DDS topic of a fully qualified topic name: `rt` + the name."""
    return "rt" + ros_name
