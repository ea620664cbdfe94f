"""The typed parts of a Solution besides its arrays: how the solve went (`SolveRecord`), what the
file records of the problem (`ProblemRecord`), and a re-plan's call (`ReplanRecord`).

In the solution file their fields are top-level keys (a re-plan's under `replan`), exactly as when
they were untyped extras (docs/solution_file.md): `to_json` writes a field only when it is set (an
optional field left at None is no key), `from_json` takes its keys out of a file's mapping.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..json_records import JsonRecord, put_fields, take_fields


class _TopLevel(JsonRecord):
    """A record whose fields are top-level keys of the solution's mapping."""

    def to_json(self, d: dict) -> dict:
        """Write the set fields into the solution's mapping `d`."""
        return put_fields(self, d)

    @classmethod
    def from_json(cls, d: dict):
        """The record from a solution's mapping; its keys are removed from `d`."""
        return take_fields(cls, d, cls._readers())


@dataclass(frozen=True)
class CondensedStart(JsonRecord):
    """The condensed solve the lifted form started from (its time and iterations are counted in
    the plan's)."""

    status: str
    iterations: int
    solver: str | None  # its backend
    solve_time_s: float  # [s]
    objective: float  # its Tr(Sigma_T) plus smoothness


@dataclass(frozen=True)
class SecondStart(JsonRecord):
    """A 6x6-recursion model's second start from its diagonal model's plan (methods/ocp.py,
    `_second_start`): that solve's end, whether it scored below the first plan, and the Newton (and
    IPOPT) runs from it when it did."""

    status: str  # the diagonal model's solve
    iterations: int
    solve_time_s: float  # [s]
    ahead: bool  # its plan scored below the first plan in the full model
    newton_status: str | None = None
    newton_iterations: int | None = None
    newton_objective: float | None = None
    ipopt_status: str | None = None  # IPOPT finishing Newton's unfinished better point
    ipopt_iterations: int | None = None


@dataclass(frozen=True)
class StartState(JsonRecord):
    """The executed curve's state where a re-plan within enforced limits starts (it moves)."""

    velocity: list[float]  # [rad/s, or m/s for prismatic joints]
    acceleration: list[float]  # [rad/s^2, or m/s^2]


@dataclass(frozen=True)
class SolveRecord(_TopLevel):
    """How the solve went, whatever the backend; every field optional (None: not said, e.g. the
    baseline's). Keys of the solution file under their own names."""

    # the backend whose point is the plan: ipopt | newton | interior, or "none (the initial
    # guess; ...)" when the feasible start was kept
    solver: str | None = None
    init: str | None = None  # where it started: baseline, init_poses, "warm start (...)", ...
    hessian: str | None = None  # the OCP's attempts' labels joined by " + "
    covariance_form: str | None = None  # condensed | diagonal | full... of the transcription
    build_time_s: float | None = None  # building the solver [s], not in `solve_time_s`
    compiled: bool | None = None  # its derivatives compiled to C (solver.codegen)
    codegen_note: str | None = None  # why compiling failed (then not compiled)
    # the planning model's objective at the (cold) initial guess: Tr(Sigma_T) [m^2 + rad^2] ...
    initial_trace: float | None = None
    initial_objective: float | None = None  # ... and with the smoothness term
    worse_than_initial_guess: bool | None = None  # the plan's objective is above it
    ocp_trace_final: float | None = None  # the planning model's Tr(Sigma_T) at the plan
    constraint_violation: float | None = None  # the NLP's largest violation at the plan
    # the solver's own status when the plan broke enforced limits (`status` then says so)
    solver_status: str | None = None
    warm_start_q: list[list[float]] | None = None  # a re-plan's start: (T+1, nq) joints [rad, m]
    start_state: StartState | None = None  # a re-plan within enforced limits: the start's motion
    lifted: str | None = None  # why the lifted NLP did not run after its condensed start
    condensed_start: CondensedStart | None = None  # the lifted form's start
    second_start: SecondStart | None = None  # a 6x6-recursion model's second start

    @staticmethod
    def _readers() -> dict:
        return {"condensed_start": CondensedStart.from_json,
                "second_start": SecondStart.from_json, "start_state": StartState.from_json}


@dataclass(frozen=True)
class Timing(JsonRecord):
    """The problem's time (its `timing` section): what a waypoint step lasts and the tracker's
    rate."""

    step_s: float  # [s] per step
    tracker_hz: float  # [Hz]
    frames_per_step: int  # tracker frames folded into one observation per step


@dataclass(frozen=True)
class LimitsRecord(JsonRecord):
    """The motion limits the plan was made with (`surestep export` honours them): `enforce`, and
    the resolved limits with their sources, or why there are none (`unavailable`)."""

    enforce: bool
    joint_names: list[str] | None = None
    velocity: list[float] | None = None  # [rad/s, or m/s] per joint
    acceleration: list[float] | None = None  # [rad/s^2, or m/s^2] per joint
    tool_speed_m_s: float | None = None  # [m/s]
    tool_rotation_rad_s: float | None = None  # [rad/s]
    rcm_min_distance_m: float | None = None  # [m]
    sources: dict[str, str] | None = None  # where each limit came from
    unavailable: str | None = None  # no URDF velocity limits: why


@dataclass(frozen=True)
class Needle(JsonRecord):
    """A grasped needle: its radius and its pose in the arm's frame."""

    radius: float  # [m]
    grasp: list[list[float]]  # 4x4, position [m]


@dataclass(frozen=True)
class Placement(JsonRecord):
    """A robot of the scene besides the planned one (another arm, the ECM): its URDF, frame,
    base pose and fixed joints."""

    urdf: str
    frame: str
    base_pose: list[list[float]]  # 4x4 in world, position [m]
    q: list[float]  # joints [rad, or m for prismatic joints]
    needle: Needle | None = None  # the needle it holds

    @staticmethod
    def _readers() -> dict:
        return {"needle": Needle.from_json}


@dataclass(frozen=True)
class ProblemRecord(_TopLevel):
    """What the solution file records of the problem beyond the Solution's own fields (`robot`,
    `camera`, `noise`, ...): its time, limits, other robots and camera moves."""

    timing: Timing | None = None
    limits: LimitsRecord | None = None
    other_arms: list[Placement] | None = None  # None: no other arm
    camera_poses: list[list[list[float]]] | None = None  # a moving camera: 4x4 in world per step
    ecm: Placement | None = None  # the camera's arm, when the camera is on one

    @staticmethod
    def _readers() -> dict:
        return {"timing": Timing.from_json, "limits": LimitsRecord.from_json,
                "other_arms": lambda v: [Placement.from_json(a) for a in v],
                "ecm": Placement.from_json}


@dataclass(frozen=True)
class ReplanAttempt(JsonRecord):
    """One attempt of a re-plan within enforced limits (methods/planner.py)."""

    reserve: float  # the fraction of each limit kept free for later corrections
    steps_added: int  # steps added at the goal (the correction too large for the time left)
    status: str
    iterations: int
    relaxed_iterations: int  # of them, with the broken rows relaxed


@dataclass(frozen=True)
class ReplanRecord(JsonRecord):
    """A `Planner.replan` call (solution file key `replan`)."""

    step: int  # the waypoint the re-plan starts at
    time_s: float  # the whole call without solver builds [s]
    solver: str | None  # the backend of the plan
    build_time_s: float  # solvers built during the call [s]
    kept_previous: bool | None = None  # within enforced limits: it failed, the previous plan stays
    attempts: list[ReplanAttempt] | None = None  # within enforced limits: its attempts
    # within enforced limits: the tracker's estimate put the goal out of reach, so the camera
    # registration of the plan before was used
    registration_held: bool | None = None
    # within enforced limits: the tracker's estimate put the goal out of reach, and the nearest
    # estimate under its belief that reaches it was registered: its squared Mahalanobis distance
    # (over 16.8, the chi-square 99 % quantile: the belief puts the goal out of reach;
    # methods/registration.py)
    registration_constrained: float | None = None
    # within enforced limits, a real-time iteration (`Planner(rti=True)`): "feedback" (the
    # prepared iterate with the measured goal) or "full: <why>" (a full re-plan instead)
    rti: str | None = None
    feedback_s: float | None = None  # from the call until the plan's joints were known [s]
    prepare_s: float | None = None  # its preparation [s], builds apart
    prepared_ahead: bool | None = None  # prepared before the call (`Planner.prepare`), not in it
    certificate_s: float | None = None  # its certificate (in `time_s`: the command waits on it) [s]
    # a real-time iteration's feedback by the clock: from `feedback_s`'s start until the
    # certificate's verdict, the plan's Solution (its evaluation) and certificate included [s]
    verdict_s: float | None = None

    @staticmethod
    def _readers() -> dict:
        return {"attempts": lambda v: [ReplanAttempt.from_json(a) for a in v]}
