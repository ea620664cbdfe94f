"""The joint names an exported trajectory gives the consumer (`surestep export --joint-names`).

The one map from the URDF's joint names (`robots/psm.urdf`) to the dVRK's: `dvrk`, the names of the
dVRK's current kinematics files (saw `share/kinematic/PSM.json`, the URDF's own); `dvrk-ros-model`,
the names of the dVRK's ROS model (`dvrk-ros` `dvrk_model/model/psm.urdf.xacro`) and of older
kinematics files and bags, `outer_` before each (docs/motion_limits_and_export.md, "Joint names").
The jaw keeps its name (`jaw` in both).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import SurestepError, shown

# robots/psm.urdf, in the plan's order
PSM_ARM = ("yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw")
PRESETS = {
    "dvrk": dict(zip(PSM_ARM, PSM_ARM)),
    "dvrk-ros-model": {n: f"outer_{n}" for n in PSM_ARM},
}
DEFAULT_PRESET = "dvrk"  # for the PSM; other robots: their URDF's names
URDF = "urdf"  # the choice recorded when a robot other than the PSM keeps its URDF's names
EXPLICIT = "explicit"  # the choice recorded for a comma-separated list
NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")  # a ROS 2 name token


@dataclass(frozen=True)
class JointNaming:
    """`choice` (a preset, `urdf` or `explicit`) and the name written for each URDF joint."""

    choice: str
    names: dict[str, str]

    def of(self, urdf_names: list[str]) -> list[str]:
        """The written names of `urdf_names` (a joint not in the map, the jaw: its own)."""
        return [self.names.get(n, n) for n in urdf_names]

    def to_dict(self) -> dict:
        return {"choice": self.choice, "names": dict(self.names)}

    def comment(self) -> str:
        """One line for a file's header."""
        return f"{self.choice} (--joint-names; the URDF's {', '.join(self.names)} written as " \
               f"{', '.join(self.names.values())})"


def allowed(n: int) -> str:
    return f"allowed: {', '.join(PRESETS)}, or {n} comma-separated joint names"


def joint_naming(value: str | None, arm: list[str], others: list[str] = ()) -> JointNaming:
    """The naming of the plan's arm joints `arm` (URDF names; `others`, the jaw, keep theirs) for
    `--joint-names` `value`: None (the default), a preset or a comma-separated list; a one-line
    error for anything else."""
    is_psm = tuple(arm) == PSM_ARM
    if value is None:
        return JointNaming(DEFAULT_PRESET, dict(PRESETS[DEFAULT_PRESET])) if is_psm else \
            JointNaming(URDF, dict(zip(arm, arm)))
    if "," not in value:
        if value not in PRESETS:
            raise SurestepError(f"--joint-names: '{shown(value)}' is not a "
                                f"preset; {allowed(len(arm))}")
        if not is_psm:
            raise SurestepError(f"--joint-names {value}: the plan's joints ({', '.join(arm)}) are "
                                f"not the PSM's; give {len(arm)} comma-separated joint names")
        return JointNaming(value, dict(PRESETS[value]))
    names = [n.strip() for n in value.split(",")]
    if len(names) != len(arm):
        raise SurestepError(f"--joint-names: {len(names)} names given, the plan has {len(arm)} arm "
                            f"joints ({', '.join(arm)}); {allowed(len(arm))}")
    bad = [n for n in names if not NAME.match(n)]
    if bad:
        raise SurestepError(f"--joint-names: '{shown(bad[0])}' is not a joint name (a letter, then "
                            f"letters, digits, _); {allowed(len(arm))}")
    taken = [n for i, n in enumerate(names) if n in names[:i] or n in others]
    if taken:
        raise SurestepError(f"--joint-names: '{shown(taken[0])}' is given twice (or is the jaw's); "
                            f"{allowed(len(arm))}")
    return JointNaming(EXPLICIT, dict(zip(arm, names)))
