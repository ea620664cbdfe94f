"""One `Solution` type for every method, evaluated by one function, saved as JSON atomically."""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurestepError, shown
from ..model.belief import entropy
from ..model.lie import matrix_to_pose, np_angle, np_exp_many, np_log_many, pose_to_matrix
from ..model.limits import LimitsReport, SkippedReport, read_report, recorded_limits
from ..problem.scene import ArmRecord
from ..problem.setup import Setup
from ..status import Status
from .attempt_record import AttemptRecord
from .certificate import Certificate
from .files import check_finite, check_replaceable
from .solution_records import (
    LimitsRecord,
    Needle,
    Placement,
    ProblemRecord,
    ReplanRecord,
    SolveRecord,
    Timing,
)


@dataclass(frozen=True)
class Solution:
    """A planned trajectory and its evaluation (see docs/solution_file.md). Frozen: a layer that
    gives a plan a verdict or a record returns a new Solution (`dataclasses.replace`), so a solver's
    plan is never changed under whoever holds it."""

    method: str
    problem: str
    # the one meaning of success: an OCP plan's certificate is met (docs/certificate.md); the
    # baseline's and the gradient variants' own (a completed plan, not an optimum)
    success: bool
    # the outcome: the backend's status, or `Not_Certified` when it claimed a success that the
    # certificate does not confirm (then `backend_status` holds the claim); a `Status` for every
    # solver and verdict, a sentence for the baseline and the gradient variant (status.py)
    status: Status | str
    solve_time_s: float
    iterations: int
    horizon: int
    joint_names: list[str]
    q: list[list[float] | None]
    poses: list[list[float]]
    goal: list[float]
    camera: dict
    camera_pose: list[list[float]]
    robot: dict
    noise: dict
    trace: list[float]
    sigma: list[list[list[float]]]
    sigma_final: list[list[float]]
    objective: float
    # the solve strategy's attempts, in order
    attempts: list[AttemptRecord] = field(default_factory=list)
    run: SolveRecord = field(default_factory=SolveRecord)  # how the solve went
    problem_record: ProblemRecord = field(default_factory=ProblemRecord)  # timing, limits, scene
    replan: ReplanRecord | None = None  # a `Planner.replan` call's
    # the plan against its motion limits (`enforce`, `surestep compare`); None: not checked
    motion_limits: LimitsReport | SkippedReport | None = None
    # only what is specific to a method or backend (docs/solution_file.md)
    extras: dict[str, Any] = field(default_factory=dict)
    # the plan's optimality certificate (ocp/certificate.py); None: not computed
    certificate: Certificate | None = None
    backend_status: str | None = None  # the backend's own status, before the certificate
    backend_success: bool | None = None  # the backend's own success, before the certificate

    # ----------------------------------------------------------- derived numbers
    @property
    def trace_final(self) -> float:
        return float(self.trace[-1])

    @property
    def terminal_error(self) -> tuple[float, float]:
        """Distance [m] and angle [rad] between the plan's last waypoint and the goal
        (first camera frame)."""
        x, g = np.asarray(self.poses[-1]), np.asarray(self.goal)
        if self.problem_record.camera_poses:  # poses are in their own step's camera frame
            C = [np.asarray(c) for c in self.problem_record.camera_poses]
            x = matrix_to_pose(np.linalg.inv(C[0]) @ C[-1] @ pose_to_matrix(x))
        return float(np.linalg.norm(x[:3] - g[:3])), np_angle(x[3:], g[3:])

    @property
    def entropy_final(self) -> float:
        return entropy(np.asarray(self.sigma_final))

    # ----------------------------------------------------------- arrays (the public API)
    @property
    def joints(self) -> np.ndarray:
        """(T+1, nq) joint values [rad, or m for prismatic joints] in `joint_names` order; NaN rows
        where a pose-space waypoint has no IK solution."""
        return np.array([[np.nan] * len(self.joint_names) if q is None else q for q in self.q],
                        float)

    @property
    def positions(self) -> np.ndarray:
        """(T+1, 3) tool positions [m] in the camera frame (of each waypoint's step when
        the camera moves)."""
        return np.asarray(self.poses, float)[:, :3]

    @property
    def orientations(self) -> np.ndarray:
        """(T+1, 3) tool orientations as axis-angle vectors [rad], same frame as `positions`."""
        return np.asarray(self.poses, float)[:, 3:]

    @property
    def pose_matrices(self) -> np.ndarray:
        """(T+1, 4, 4) tool poses (rotation, position [m]) in the camera frame."""
        return np.array([pose_to_matrix(x) for x in self.poses])

    @property
    def covariances(self) -> np.ndarray:
        """(T+1, 6, 6) EKF covariances Sigma_t|t of (position [m], orientation [rad]): blocks in
        m^2, m rad, rad^2; the evaluation's model (every observation component)."""
        return np.asarray(self.sigma, float)

    @property
    def times(self) -> np.ndarray:
        """(T+1,) time [s] of each waypoint from the start (`timing.step_s` per step)."""
        timing = self.problem_record.timing
        return np.arange(self.horizon + 1) * (0.05 if timing is None else float(timing.step_s))

    def to_dict(self) -> dict:
        """The solution file's mapping: the typed records' fields and the extras as top-level keys
        (a re-plan's record under `replan`, the limit report under `motion_limits` after the
        extras), as before they were typed."""
        d = asdict(self)
        for key in _RECORDS:
            d.pop(key)
        self.run.to_json(d)
        extras = d.pop("extras")
        d.update(extras)
        if self.motion_limits is not None:
            d["motion_limits"] = self.motion_limits.to_json()
        self.problem_record.to_json(d)
        if self.replan is not None:
            d["replan"] = self.replan.to_json()
        for key in ("backend_status", "backend_success"):
            if d[key] is None:
                del d[key]
        if self.certificate is not None:
            d["certificate"] = self.certificate.to_json()
        return d

    def save(self, path: str | Path) -> Path:
        """Write the solution (atomically); NaN or Infinity anywhere in it is an
        error naming the key."""
        d = self.to_dict()
        check_finite(d, f"the {self.method} solution")
        return write_json_atomic(path, d)

    @classmethod
    def load(cls, path: str | Path) -> Solution:
        return cls.from_dict(json.loads(Path(path).read_text()))

    @classmethod
    def from_dict(cls, d: dict) -> Solution:
        """A solution from its file's mapping (`to_dict`'s). A recorded value whose shape is not
        its record's (a file from before that value was recorded so) stays in `extras`, unread
        but written back unchanged."""
        d = dict(d)
        names = set(cls.__dataclass_fields__) - {"extras", "attempts", *_RECORDS}
        core = {k: d.pop(k) for k in names if k not in _OPTIONAL or k in d}
        attempts = [AttemptRecord.from_dict(a) for a in d.pop("attempts", [])]
        extras: dict[str, Any] = {}
        run = _typed(SolveRecord, d, extras)
        problem_record = _typed(ProblemRecord, d, extras)
        replan = _read_key(ReplanRecord.from_json, d, "replan")
        motion_limits = _read_key(read_report, d, "motion_limits")
        certificate = _read_key(Certificate.from_json, d, "certificate")
        return cls(**core, attempts=attempts, run=run, problem_record=problem_record,
                   replan=replan, motion_limits=motion_limits, certificate=certificate,
                   extras={**extras, **d})


# the typed records of a Solution, written as top-level keys of its file
_RECORDS = ("run", "problem_record", "replan", "motion_limits", "certificate")
# fields a file written before them does not hold
_OPTIONAL = ("backend_status", "backend_success")


def _read_key(read, d: dict, key: str):
    """The record `read` makes of `d[key]` (the key then removed from `d`); None when there is no
    such key or its value does not read (it stays in `d`, for the extras)."""
    if key not in d:
        return None
    try:
        record = read(d[key])
    except (KeyError, TypeError, ValueError):
        return None
    del d[key]
    return record


def _typed(record, d: dict, extras: dict):
    """`record` (SolveRecord or ProblemRecord) from the keys of `d` named like its fields (removed
    from `d`); a value that does not read as its field's goes to `extras` as it is."""
    taken = {f: d.pop(f) for f in record.__dataclass_fields__ if f in d}
    for k, v in list(taken.items()):
        try:
            record.from_json({k: v})
        except (KeyError, TypeError, ValueError):
            extras[k] = taken.pop(k)
    return record.from_json(taken)


def write_json_atomic(path: str | Path, obj: Any) -> Path:
    """Write JSON to a temporary file beside `path`, then rename it over `path`."""
    return write_text_atomic(path, json.dumps(obj, indent=1, default=_jsonable) + "\n")


def write_text_atomic(path: str | Path, text: str | bytes) -> Path:
    """Write `text` whole or not at all: a temporary file beside `path`, renamed over it. Never
    replaces a directory, a device or another non-regular file; a file-system refusal is a
    one-line SurestepError."""
    path = Path(path)
    check_replaceable(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise SurestepError(f"{shown(str(path), 200)}: cannot write it "
                            f"({exc.strerror or exc})") from None
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
    try:
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as fh:
            fh.write(text)
        check_replaceable(path)  # again: it may have changed while the text was written
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise SurestepError(f"{shown(str(path), 200)}: cannot write it "
                            f"({exc.strerror or exc})") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _jsonable(o: Any):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _cov_json(M: np.ndarray):
    """A scalar when the matrix is a multiple of the identity, else the 6x6 list."""
    M = np.asarray(M)
    s = M[0, 0]
    return float(s) if np.array_equal(M, s * np.eye(len(M))) else M.tolist()


def noise_dict(setup: Setup) -> dict:
    n = setup.ocp.noise
    d = {k: _cov_json(getattr(n, k)) for k in ("W_p0", "W_o0", "V_d0", "V_f0", "V_o0", "V_min",
                                               "Sigma0")}
    d.update(depth_star=n.depth_star, o_star=list(n.o_star),
             components=list(setup.model.components),
             orientation_formula=n.orientation_formula, cosine_guard=n.cosine_guard,
             cut_band=n.cut_band)
    if setup.model.joint_noise:
        d["joint_motion_sigma"] = list(n.joint_sigma)
    return d


def _needle(arm: ArmRecord) -> dict:
    """A needle as the solution file records it: its radius [m] and its 4x4 pose in the arm's
    frame."""
    return {"radius": arm.needle_radius, "grasp": arm.grasp.tolist()}


def _principal(poses: np.ndarray) -> np.ndarray:
    """(N, 6) poses with every rotation vector beyond pi replaced by the principal one of the same
    rotation (the OCP's means and the setup's goal are continued vectors, docs/orientation.md); the
    others untouched."""
    poses = np.array(poses, dtype=float)
    beyond = np.linalg.norm(poses[:, 3:], axis=1) > np.pi
    poses[beyond, 3:] = np_log_many(np_exp_many(poses[beyond, 3:]))
    return poses


def evaluate(
    setup: Setup,
    method: str,
    poses: np.ndarray,
    q: list[np.ndarray | None],
    *,
    success: bool,
    status: str,
    solve_time_s: float,
    iterations: int,
    objective: float,
    components: tuple[str, ...] | None = None,
    run: SolveRecord | None = None,
    extras: dict | None = None,
    sigma: np.ndarray | None = None,
) -> Solution:
    """The single evaluation every method goes through: the EKF with all components along `poses`.

    `run`: how the solve went (the solver's, its start, ...); `extras`: what only this method or
    backend reports. The problem's record (timing, limits, other arms, camera moves, ECM) is the
    setup's.

    `sigma`: the (T+1, 6, 6) covariances of that EKF along `poses` when the caller has them already
    (the re-planning loop propagates them in one compiled call, planner.py; a fixed camera only).
    """
    poses = np.array(poses, dtype=float)
    poses = setup.in_step_frames(_principal(poses))  # planned in the first camera frame
    sig = _evaluated_covariances(setup, method, poses, q, sigma)
    ocp, scene = setup.ocp, setup.scene
    noise = noise_dict(setup)
    if components is not None:
        noise["components"] = list(components)
    robot = {"urdf": scene.robot.urdf, "frame": scene.robot.frame,
             "base_pose": setup.robot.base_pose.tolist()}
    if scene.robot.grasp is not None:
        robot["needle"] = _needle(scene.robot)
    record = _problem_record(setup)
    return Solution(
        method=method,
        problem=ocp.source,
        success=bool(success),
        status=str(status),
        solve_time_s=float(solve_time_s),
        iterations=int(iterations),
        horizon=len(poses) - 1,
        joint_names=setup.robot.joint_names,
        q=[None if qi is None else [float(v) for v in qi] for qi in q],
        poses=poses.tolist(),
        goal=_principal(setup.x_goal[None])[0].tolist(),
        camera=ocp.intrinsics.to_dict(),
        camera_pose=setup.camera_pose.tolist(),
        robot=robot,
        noise=noise,
        trace=[float(np.trace(s)) for s in sig],
        sigma=sig.tolist(),
        sigma_final=sig[-1].tolist(),
        objective=float(objective),
        run=run or SolveRecord(),
        problem_record=record,
        extras=dict(extras or {}),
    )


def _evaluated_covariances(setup: Setup, method: str, poses: np.ndarray,
                           q: list[np.ndarray | None], sigma: np.ndarray | None) -> np.ndarray:
    """The (T+1, 6, 6) covariances of the evaluation EKF along `poses` (in their step frames), or
    `sigma` when the caller has them already."""
    joint = None
    if setup.model.joint_noise and sigma is None:
        # the joint-space motion noise needs every waypoint's joints
        if any(qi is None for qi in q):
            raise SurestepError(f"{method}: a waypoint without joints (unreachable) has no "
                                "joint-space motion noise (noise.joint_motion_sigma)")
        joint = setup.joint_noises(np.asarray(q, float))
    return (setup.eval_model.propagate(poses, setup.camera_changes(),
                                       joint=joint)[0] if sigma is None
            else np.asarray(sigma))


def _problem_record(setup: Setup) -> ProblemRecord:
    """The problem's record in the solution: its timing, motion limits, other arms, camera moves
    and ECM."""
    ocp, scene = setup.ocp, setup.scene
    tm = ocp.timing  # the file's timing (noise's V_* are already divided by frames_per_step)
    arms = [Placement(a.urdf, a.frame, a.base_pose.tolist(), [float(v) for v in a.joints],
                      None if a.grasp is None else Needle(**_needle(a)))
            for a in scene.other_arms]
    return ProblemRecord(
        timing=Timing(tm.step_s, tm.tracker_hz, tm.frames),
        # what `surestep export` honours (docs/motion_limits_and_export.md, "Export")
        limits=LimitsRecord.from_json(recorded_limits(setup)),
        other_arms=arms or None,
        camera_poses=[C.tolist() for C in setup.camera_schedule] or None,
        ecm=None if setup.ecm is None else Placement(
            scene.ecm.urdf, scene.ecm.frame, setup.ecm.base_pose.tolist(),
            list(map(float, scene.ecm.joints))))
