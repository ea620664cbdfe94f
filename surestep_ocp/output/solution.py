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
from ..model.lie import matrix_to_pose, np_angle, pose_to_matrix
from ..model.limits import LimitsReport, SkippedReport, read_report
from ..status import Status
from .attempt_record import AttemptRecord
from .certificate import Certificate
from .files import check_finite, check_replaceable
from .solution_records import (
    ProblemRecord,
    ReplanRecord,
    SolveRecord,
)


@dataclass(frozen=True)
class Solution:
    """A planned trajectory and its evaluation (see docs/solution_file.md). Frozen: a layer that
    gives a plan a verdict or a record returns a new Solution (`replaced`), so a solver's plan is
    never changed under whoever holds it."""

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

    def replaced(self, **changes) -> Solution:
        """A copy with `changes`: `dataclasses.replace` without re-running `__init__` (a Solution
        derives nothing from its fields, and a re-plan makes several copies: 3 us each, not 20);
        a name that is not a field is a TypeError, as there."""
        unknown = changes.keys() - _FIELDS
        if unknown:
            raise TypeError(f"Solution has no field {', '.join(sorted(unknown))}")
        new = object.__new__(Solution)
        new.__dict__.update(self.__dict__)
        new.__dict__.update(changes)
        return new

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


_FIELDS = frozenset(Solution.__dataclass_fields__)
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
