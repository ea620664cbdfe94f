"""The checks of what a Planner is given: the tracker's estimate (mean and covariance), the camera
pose, the waypoint index, a restart's joints and goal.

They are checked as the problem files' values are (finite, real, within the same bounds), so a
re-planning loop fed a bad estimate gets a SurestepError naming the argument, not a plan made from
it; kept apart from the Planner so its methods read as planning.
"""

from __future__ import annotations

import numpy as np

from ..errors import SurestepError
from ..model.belief import NX
from ..problem.setup import Setup

RIGID_TOL = 1e-6  # a camera pose's rotation is orthonormal to this
MAX_POSITION = 100.0  # [m] as the problem files' positions (problem/parse.py)
MAX_COVARIANCE = 1e6  # as the problem files' covariances: an entry at most this [m^2, m rad, rad^2]


def real_array(value, name: str) -> np.ndarray:
    """`value` as a float array; a complex or non-numeric one is an error naming the argument."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError, RecursionError):
        raise SurestepError(f"replan: {name} must be an array of real numbers") from None
    if np.iscomplexobj(arr) or arr.dtype == object or arr.dtype.kind not in "biuf":
        raise SurestepError(f"replan: {name} must be an array of real numbers, got {arr.dtype}")
    return arr.astype(float)


def whole_step(step) -> int:
    """The waypoint index given to `replan`: a whole number (a bool, a fraction, infinity or a list
    is an error)."""
    if isinstance(step, (bool, np.bool_)) or not isinstance(step, (int, np.integer, float,
                                                                   np.floating)):
        raise SurestepError(f"replan: step must be a whole number, got {type(step).__name__}")
    if not np.isfinite(step) or step != int(step):
        raise SurestepError(f"replan: step must be a whole number, got {step}")
    return int(step)


def checked_estimate(mean, covariance, min_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """The tracker's mean (6,) and covariance (6, 6), checked as the problem files' are: finite,
    real, the mean in front of the camera (at least the minimum depth), the covariance symmetric (to
    1e-9 relative: it is not silently symmetrised), positive definite and no entry beyond
    MAX_COVARIANCE."""
    mean, cov = real_array(mean, "mean"), real_array(covariance, "covariance")
    if mean.shape != (NX,) or not np.all(np.isfinite(mean)):
        raise SurestepError("replan: mean must be 6 finite numbers [px, py, pz, rx, ry, rz], "
                            + (f"got shape {mean.shape}" if mean.shape != (NX,)
                               else f"got {mean.tolist()}"))
    if np.abs(mean[:3]).max() > MAX_POSITION:
        raise SurestepError(f"replan: mean's position must be within {MAX_POSITION:g} m, "
                            f"got {mean[:3].tolist()}")
    if mean[2] < min_depth:
        raise SurestepError(f"replan: mean's depth {mean[2]:.4g} m is below the minimum depth "
                            f"{min_depth:g} m (constraints.min_depth): the tool would be behind or "
                            "at the camera")
    if cov.shape != (NX, NX) or not np.all(np.isfinite(cov)):
        raise SurestepError("replan: covariance must be a finite 6x6 matrix, "
                            + (f"got shape {cov.shape}" if cov.shape != (NX, NX)
                               else "got non-finite entries"))
    if np.abs(cov).max() > MAX_COVARIANCE:
        raise SurestepError(f"replan: covariance entries must be at most {MAX_COVARIANCE:g}, got "
                            f"{np.abs(cov).max():.3g}")
    if np.abs(cov - cov.T).max() > 1e-9 * max(np.abs(cov).max(), 1e-300):
        raise SurestepError("replan: covariance must be symmetric (to 1e-9 relative)")
    cov = 0.5 * (cov + cov.T)  # the rounding left
    if np.linalg.eigvalsh(cov)[0] <= 0:
        raise SurestepError("replan: covariance must be positive definite")
    return mean, cov


def checked_camera_pose(camera_pose) -> np.ndarray:
    """The camera pose given to `replan` (4, 4): finite and a rigid transform (a rotation to
    RIGID_TOL, a translation within MAX_POSITION, a last row 0 0 0 1)."""
    C = real_array(camera_pose, "camera_pose")
    if C.shape != (4, 4) or not np.all(np.isfinite(C)):
        raise SurestepError("replan: camera_pose must be a finite 4x4 matrix, "
                            + (f"got shape {C.shape}" if C.shape != (4, 4)
                               else "got non-finite entries"))
    R = C[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > RIGID_TOL or np.linalg.det(R) <= 0
            or np.abs(C[3] - [0, 0, 0, 1]).max() > RIGID_TOL
            or np.abs(C[:3, 3]).max() > MAX_POSITION):
        raise SurestepError("replan: camera_pose must be a rigid transform: a rotation "
                            f"(orthonormal, determinant +1, to {RIGID_TOL:g}), "
                            f"a translation within {MAX_POSITION:g} m, "
                            "and a last row 0 0 0 1")
    return C


def checked_rest_joints(joints, base: Setup) -> np.ndarray:
    """The joints a `restart` starts from at rest: finite, one per joint, within their bounds."""
    q = real_array(joints, "joints")
    lo, hi = base.robot.lower, base.robot.upper
    if q.shape != lo.shape or not np.all(np.isfinite(q)):
        raise SurestepError(f"restart: joints must be {lo.size} finite numbers, got shape "
                            f"{q.shape}")
    if np.any(q < lo) or np.any(q > hi):
        bad = [i for i in range(q.size) if not lo[i] <= q[i] <= hi[i]]
        raise SurestepError(f"restart: joint(s) {bad} outside their bounds "
                            f"{[[float(lo[i]), float(hi[i])] for i in bad]}: {q[bad].tolist()}")
    return q


def checked_goal(goal, base: Setup) -> np.ndarray:
    """A `restart`'s new goal pose (6,): finite, at least the minimum depth in front of the camera
    (its reachability is the restart's IK)."""
    x = real_array(goal, "goal")
    if x.shape != (NX,) or not np.all(np.isfinite(x)):
        raise SurestepError("restart: goal must be 6 finite numbers [px, py, pz, rx, ry, "
                            f"rz], got shape {x.shape}")
    if x[2] < base.ocp.min_depth:
        raise SurestepError(f"restart: goal's depth {x[2]:.4g} m is below the minimum "
                            f"depth {base.ocp.min_depth:g} m (constraints.min_depth)")
    return x
