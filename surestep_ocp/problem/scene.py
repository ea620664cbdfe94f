"""What a solution file records of the problem's scene: `Scene`, the arms as the file names them.

The solvers never read it; `build_setup` makes it once from the `Problem` so that a `Setup` carries
what `output/solution.py` writes beside a plan (the planned arm's URDF, frame and needle, the arms
that hold still, the ECM) without the problem itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..equality import ArrayEquality
from .spec import Problem, RobotSpec


@dataclass(frozen=True, eq=False)
class ArmRecord(ArrayEquality):
    """An arm as a solution file records it."""

    urdf: str  # as written relative to the repository (`RobotSpec.urdf_rel`)
    frame: str  # the tracked frame (the ECM's: the camera)
    base_pose: np.ndarray  # 4x4, URDF root in world
    joints: np.ndarray | None = None  # fixed joint values (an arm that holds still, the ECM)
    grasp: np.ndarray | None = None  # 4x4: the needle in `frame` (None: no needle)
    needle_radius: float | None = None  # [m]

    @classmethod
    def of(cls, spec: RobotSpec, joints: np.ndarray | None = None) -> ArmRecord:
        return cls(spec.urdf_rel, spec.frame, spec.base_pose,
                   spec.joints if joints is None else joints, spec.grasp, spec.needle_radius)


@dataclass(frozen=True, eq=False)
class Scene(ArrayEquality):
    """The planned arm, the arms that hold still (a goal given on another arm's needle) and the
    ECM (None: the camera pose given directly)."""

    robot: ArmRecord
    other_arms: tuple[ArmRecord, ...] = ()
    ecm: ArmRecord | None = None

    @classmethod
    def of(cls, problem: Problem) -> Scene:
        cam = problem.camera
        others = tuple(ArmRecord.of(spec.arm) for spec in (problem.start.relative,
                                                           problem.goal.relative)
                       if spec is not None)
        ecm = None if cam.ecm is None else ArmRecord.of(cam.ecm, cam.ecm_joints)
        return cls(ArmRecord.of(problem.robot), others, ecm)
