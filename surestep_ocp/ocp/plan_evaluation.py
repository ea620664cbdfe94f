"""A plan's evaluation: the one EKF pass every method's plan goes through, into a `Solution`.

`evaluate` takes a plan's poses (and joints) on a set-up and returns its Solution: the covariances
of the evaluation model with every observation component, the problem's records (timing, limits,
other arms, camera moves, ECM). Here, below the solvers, so that output/ only holds the Solution
type and writes files.
"""

from __future__ import annotations

import numpy as np

from ..errors import SurestepError
from ..model.lie import np_exp_many, np_log_many
from ..model.limits import recorded_limits
from ..output.solution import Solution
from ..output.solution_records import (LimitsRecord, Needle, Placement, ProblemRecord, SolveRecord,
                                       Timing)
from ..problem.scene import ArmRecord
from ..problem.setup import Setup


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


def _joint_lists(q: list) -> list[list[float] | None]:
    """Each waypoint's joints as a list of floats (None where it has none)."""
    if any(qi is None for qi in q):
        return [None if qi is None else [float(v) for v in qi] for qi in q]
    return np.asarray(q, float).tolist()


def _principal(poses: np.ndarray) -> np.ndarray:
    """(N, 6) poses with every rotation vector beyond pi replaced by the principal one of the same
    rotation (the OCP's means and the setup's goal are continued vectors, docs/orientation.md); the
    others untouched."""
    poses = np.array(poses, dtype=float)
    beyond = np.linalg.norm(poses[:, 3:], axis=1) > np.pi
    if beyond.any():  # (rarely: a re-plan evaluates a plan per frame)
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
        q=_joint_lists(q),
        poses=poses.tolist(),
        goal=_principal(setup.x_goal[None])[0].tolist(),
        camera=ocp.intrinsics.to_dict(),
        camera_pose=setup.camera_pose.tolist(),
        robot=robot,
        noise=noise,
        trace=np.trace(sig, axis1=1, axis2=2).tolist(),
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
