"""What the solvers read of a problem: `OcpSpec`, the solver-facing view of `Problem`.

The solvers take a `Setup` (robot, camera, start and goal made concrete) and read the rest through
`setup.ocp`: horizon, noise, camera intrinsics, objective weight, depth bound, motion limits,
timing, solver and gradient settings, and the file name for messages. `build_setup` makes it once
from the `Problem`; none of the solvers depends on the problem file's layout. A solver's variant of
a problem (a re-plan's horizon and Sigma_0, a method's noise model) is `Setup.with_ocp`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.belief import NoiseParams
from ..model.camera import Intrinsics
from ..model.detection import Detection
from .spec import GradientSpec, GraspSpec, LimitsSpec, Problem, SolverSpec, TimingSpec


@dataclass(frozen=True)
class OcpSpec:
    """The OCP's data besides robot, camera, start and goal."""

    source: str  # the problem file (for messages)
    horizon: int  # T, steps
    noise: NoiseParams  # the belief model's constants, Sigma_0 included
    intrinsics: Intrinsics  # the camera's (the belief model's field of view)
    smoothness: float  # weight of the joint-step term [1/rad^2]
    min_depth: float  # [m] the means' smallest depth
    solver: SolverSpec
    gradient: GradientSpec
    limits: LimitsSpec
    timing: TimingSpec
    grasp: GraspSpec = GraspSpec()  # the grasp's tolerance and confidence
    detection: Detection | None = None  # where the tracker sees the tool (None: everywhere)

    @classmethod
    def of(cls, problem: Problem) -> OcpSpec:
        return cls(str(problem.path), problem.horizon, problem.noise, problem.camera.intrinsics,
                   problem.objective.smoothness, problem.min_depth, problem.solver,
                   problem.gradient, problem.limits, problem.timing, problem.grasp,
                   problem.detection)

    @property
    def sigma0(self) -> np.ndarray:
        """(6, 6) the initial covariance [m^2, m rad, rad^2]."""
        return np.asarray(self.noise.Sigma0, float)


# the OcpSpec fields `Setup.with_ocp` changes (the problem's file and camera stay)
EDITABLE = ("horizon", "noise", "smoothness", "min_depth", "solver", "gradient", "limits", "timing",
            "grasp", "detection")
