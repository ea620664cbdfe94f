"""A problem made concrete: robot and camera loaded, start and goal resolved to joints and poses.

`build_setup` is the one place that turns a `Problem` into a `Setup`; the setup keeps what the
solvers read of it (`OcpSpec`) and what solution files record of its scene (`Scene`), not the
problem itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from ..model.belief import BeliefModel
from ..errors import FrameNotFound, ProblemError, UnreachablePose, UnsupportedJoint
from ..model.joint_noise import joint_noises
from ..model.lie import (continued, matrix_to_pose, np_exp_many, np_means, np_poses,
                         np_quat_of_matrix, pose_to_matrix)
from .spec import EndpointSpec, Problem
from ..model.robot import Robot
from .ocp_spec import EDITABLE, OcpSpec
from .scene import Scene
from .solver_config import resolve
from ..quiet import quiet_fd

# [rad or m] A batch-Newton IK solution farther than this from its guess (in any joint) is
# taken as another IK branch and the waypoint is solved from the previous one instead.
GUESS_RADIUS = 0.5
CAMERA_PARAMETERS_KEPT = 256  # camera parameters kept per robot (cleared when full)


@dataclass
class Setup:
    """Everything a method needs: robot, camera, start and goal, belief models.

    Poses `x = [p, r]` are in the camera frame (OpenCV) unless said otherwise.
    """

    ocp: OcpSpec  # what the solvers read of the problem
    scene: Scene  # what a solution file records of the arms
    robot: Robot
    camera_pose: np.ndarray  # 4x4, camera in world
    q_start: np.ndarray
    q_goal: np.ndarray
    x_start: np.ndarray
    x_goal: np.ndarray
    ecm: Robot | None = None
    other_arms: list = field(default_factory=list)  # arms that hold still (e.g. the needle arm)
    # (T+1) 4x4 camera poses when the camera moves
    camera_schedule: list = field(default_factory=list)

    def camera_poses(self, horizon: int | None = None) -> list[np.ndarray]:
        """Camera pose (world) at each waypoint 0..T: the schedule, or the fixed pose."""
        T = self.ocp.horizon if horizon is None else horizon
        return list(self.camera_schedule) if self.camera_schedule else [self.camera_pose] * (T + 1)

    def camera_changes(self) -> list | None:
        """Per step t, the 4x4 map from camera-t to camera-(t+1) coordinates (None: no
        move); None if fixed."""
        if not self.camera_schedule:
            return None
        C = self.camera_schedule
        return [None if np.array_equal(C[t], C[t + 1]) else np.linalg.inv(C[t + 1]) @ C[t]
                for t in range(len(C) - 1)]

    def in_step_frames(self, poses_cam0: np.ndarray) -> np.ndarray:
        """Waypoints given in the first camera frame, each re-expressed in its own
        step's camera frame."""
        if not self.camera_schedule:
            return np.asarray(poses_cam0, float)
        C0 = self.camera_schedule[0]
        return np.array([matrix_to_pose(np.linalg.inv(Ct) @ C0 @ pose_to_matrix(x))
                         for Ct, x in zip(self.camera_schedule, poses_cam0)])

    @property
    def T_cam_base(self) -> np.ndarray:
        """4x4 pose of the robot's URDF root in the camera frame."""
        return np.linalg.inv(self.camera_pose) @ self.robot.base_pose

    def with_ocp(self, *, smoothness: float | None = None, sigma0=None, **changes) -> Setup:
        """The same setup with OCP data changed (`OcpSpec`'s fields: horizon, noise, smoothness
        (the joint-step weight), min_depth, solver, gradient, limits, timing; `sigma0` the initial
        covariance); its models are rebuilt for the new noise."""
        unknown = set(changes) - set(EDITABLE)
        if unknown:
            raise TypeError(f"with_ocp: unknown field(s) {sorted(unknown)}; allowed: sigma0, "
                            f"{', '.join(EDITABLE)}")
        if smoothness is not None:
            changes["smoothness"] = smoothness
        if sigma0 is not None:
            changes["noise"] = replace(changes.get("noise", self.ocp.noise),
                                       Sigma0=np.asarray(sigma0, float))
        return replace(self, ocp=replace(self.ocp, **changes))

    @cached_property
    def model(self) -> BeliefModel:
        """Belief model with the observation components used in optimisation."""
        return BeliefModel(self.ocp.noise, self.ocp.intrinsics)

    @cached_property
    def eval_model(self) -> BeliefModel:
        """Belief model with all components: every method is evaluated with it."""
        return self.model.evaluation_model()

    def seen_from(self, camera_pose: np.ndarray) -> Setup:
        """The same robot, joints and start/goal joints seen from another camera pose
        (means recomputed)."""
        moved = replace(self, camera_pose=np.asarray(camera_pose, float))
        moved.x_start, moved.x_goal = moved.pose_of(self.q_start), moved.pose_of(self.q_goal)
        return moved

    def camera_parameter(self) -> np.ndarray:
        """The `camera` parameter of `Robot.camera_pose`: the root's pose in the camera frame
        and its quaternion, signed so that the start's rotation vector is the principal one
        (angle at most pi)."""
        key = (np.asarray(self.camera_pose, float).tobytes(),
               np.asarray(self.q_start, float).tobytes(), self.robot.base_pose.tobytes())
        # kept on the robot, which every copy of a setup (`replace`, `with_ocp`) shares: a
        # re-plan's setups are new instances of a few cameras and starts (about 0.25 ms each)
        cache = self.robot.__dict__.setdefault("_camera_parameters", {})
        value = cache.get(key)
        if value is None:
            Tcb = self.T_cam_base
            Qc = np_quat_of_matrix(Tcb[:3, :3])
            Qs = np.asarray(self.robot.fk_quaternion(self.q_start)).ravel()
            if Qc[0] * Qs[0] - Qc[1:] @ Qs[1:] < 0:  # the real part of Qc Qs (Hamilton)
                Qc = -Qc
            value = np.concatenate([Tcb[:3, :].ravel(order="F"), Qc])
            if len(cache) >= CAMERA_PARAMETERS_KEPT:
                cache.clear()
            cache[key] = value
        return value.copy()

    def means_of(self, q: np.ndarray) -> np.ndarray:
        """(N, 7) camera-frame means `(p, Q)` at the joint vectors `q` (N, nq),
        `Robot.camera_pose`: the FK quaternion, continuous along the joints (its sign is the
        start's principal one at q_start)."""
        return self.robot.camera_means(np.atleast_2d(np.asarray(q, float)),
                                       self.camera_parameter())

    def poses_of(self, q: np.ndarray) -> np.ndarray:
        """(N, 6) camera-frame poses `[p, r]` at the joint vectors `q` (N, nq): r the log of the
        means' quaternion, continued along the joints from the start's (docs/orientation.md); exp(r)
        is Pinocchio's rotation (tested)."""
        return np_poses(self.means_of(q))

    def mean_at(self, x: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The mean `(p, Q)` of the pose `x`, its quaternion on the side (sign) of the FK
        quaternion at joints q."""
        m = np_means(np.asarray(x, float))[0]
        if m[3:] @ self.means_of(q)[0, 3:] < 0:
            m[3:] = -m[3:]
        return m

    @property
    def m_start(self) -> np.ndarray:
        """The start's mean `(p, Q)` (the OCP's first node)."""
        return self.mean_at(self.x_start, self.q_start)

    @property
    def m_goal(self) -> np.ndarray:
        """The goal's mean `(p, Q)`: the OCP's terminal equality `mu_T = m_goal`, on the sheet
        of the goal joints."""
        return self.mean_at(self.x_goal, self.q_goal)

    def joint_noises(self, q: np.ndarray) -> np.ndarray | None:
        """(T, 21) vech of each step's joint-space motion noise along the joints `q` (T+1, nq), or
        None when the model has none (`BeliefModel.propagate`'s `joint`)."""
        if not self.model.joint_noise:
            return None
        return joint_noises(self.robot, self.ocp.noise.joint_sigma, q, self.camera_parameter())

    def pose_of(self, q: np.ndarray) -> np.ndarray:
        """Camera-frame pose `[p, r]` of the tracked frame at joints `q` (see `poses_of`)."""
        return self.poses_of(q)[0]

    def joints_for(self, x: np.ndarray, q0: np.ndarray, what: str = "pose",
                   raise_on_fail: bool = True, restarts: int = 20):
        """IK of a camera-frame pose from q0, then from `restarts` random starts: (q, residual [m],
        residual [rad])."""
        target = np.linalg.inv(self.T_cam_base) @ pose_to_matrix(x)
        return self.robot.inverse_kinematics(target, q0, what=what, raise_on_fail=raise_on_fail,
                                             restarts=restarts)

    def joint_line(self, T: int) -> np.ndarray:
        """Joint vectors evenly spaced from the start's to the goal's (T + 1 of them)."""
        return np.linspace(self.q_start, self.q_goal, T + 1)

    def joints_along(self, poses: np.ndarray, q0: np.ndarray, tol_m: float = 1e-6,
                     tol_rad: float = 1e-5, guesses: np.ndarray | None = None):
        """IK of every waypoint, each started from the previous solution.

        With `guesses` (one joint vector per waypoint, e.g. the joint-space line between
        start and goal), all waypoints are first solved at once by Newton's method from
        their guesses; a waypoint that does not converge there, or lands farther than
        `GUESS_RADIUS` from its guess (another IK branch), is solved from the previous one.

        Returns:
            (q_best (N, nq) best-effort solutions, reachable (N,) bool, res_m (N,), res_rad (N,)).
        """
        poses = np.asarray(poses, float)
        batch, done = None, np.zeros(len(poses), bool)
        base_cam = np.linalg.inv(self.T_cam_base)
        targets = np.zeros((len(poses), 4, 4))  # root frame
        targets[:, :3, :3], targets[:, :3, 3], targets[:, 3, 3] = (np_exp_many(poses[:, 3:]),
                                                                   poses[:, :3], 1.0)
        targets = base_cam @ targets
        if guesses is not None:
            batch, done, errors = self.robot.newton_batch(targets, guesses)
            done &= np.max(np.abs(batch - guesses), axis=1) <= GUESS_RADIUS
        qs, res_m, res_r = [], [], []
        q_prev = np.asarray(q0, float)
        for k, target in enumerate(targets):
            if done[k]:
                # the batch's own residual (its FK is checked against Pinocchio's in the tests)
                q_prev = batch[k]
                em, er = errors[k]
            else:
                q_prev, em, er = self.robot.inverse_kinematics(target, q_prev, raise_on_fail=False)
            qs.append(q_prev)
            res_m.append(em)
            res_r.append(er)
        res_m, res_r = np.array(res_m), np.array(res_r)
        return np.array(qs), (res_m <= tol_m) & (res_r <= tol_rad), res_m, res_r


def load_robot(file: str, key: str, spec, moving: bool = False) -> Robot:
    """The `Robot` of a problem's robot spec at `key`; a bad URDF or frame is a ProblemError.

    `moving`: the tracked frame must be moved by at least one joint (not the model's root).
    """
    try:
        with quiet_fd(2):
            # urdfdom prints parse errors on stderr; the error below says it in one line
            robot = Robot(spec.urdf, spec.base_pose, spec.frame, spec.grasp)
    except FrameNotFound as exc:
        raise ProblemError(file, f"{key}.frame", str(exc)) from None
    except UnsupportedJoint as exc:
        raise ProblemError(file, f"{key}.urdf", str(exc)) from None
    except (ValueError, RuntimeError, OSError) as exc:  # Pinocchio's URDF parser
        raise ProblemError(file, f"{key}.urdf", f"cannot load the URDF: {exc}") from None
    if moving and not robot.supporting_joints():
        raise ProblemError(file, f"{key}.frame", f"frame '{spec.frame}' is not moved by any joint "
                                                 "(it is fixed to the model's root); name a frame "
                                                 "on the arm's moving chain")
    return robot


def build_setup(problem: Problem) -> Setup:
    """Load the robot and the camera and resolve start and goal.

    Raises:
        ProblemError: frame missing, joints out of limits, goal behind the camera or unreachable.
    """
    file = str(problem.path)
    robot = load_robot(file, "robot", problem.robot, moving=True)
    problem = _joint_sigma_for(problem, robot)

    cam = problem.camera
    ecm = None
    if cam.pose is not None:
        camera_pose = cam.pose
    else:
        ecm = load_robot(file, "camera.ecm", cam.ecm)
        _check_joints(problem, ecm, cam.ecm_joints, "camera.ecm.joints")
        camera_pose = ecm.base_pose @ ecm.frame_pose(cam.ecm_joints)
        schedule = _camera_schedule(problem, ecm, camera_pose)

    setup = Setup(OcpSpec.of(problem), Scene.of(problem), robot, camera_pose, np.zeros(robot.nq),
                  np.zeros(robot.nq), np.zeros(6), np.zeros(6), ecm)
    if ecm is not None:
        setup.camera_schedule = schedule
    mid = np.where(np.isfinite(robot.lower), 0.5 * (robot.lower + robot.upper), 0.0)
    setup.q_start, setup.x_start = _endpoint(problem, setup, problem.start, mid)
    setup.x_start = _continued_at(setup, setup.x_start, setup.q_start)  # the principal vector
    setup.q_goal, setup.x_goal = _endpoint(problem, setup, problem.goal, setup.q_start)
    setup.x_goal = _continued_at(setup, setup.x_goal, setup.q_goal)
    # every solver rule, now
    resolve(problem.solver, setup.model, len(robot.supporting_joints()), file=file,
            limited=problem.limits.enforce)
    return setup


def _joint_sigma_for(problem: Problem, robot: Robot) -> Problem:
    """`noise.joint_motion_sigma` checked against the robot (one number per joint, or one
    for all: expanded)."""
    sigma = problem.noise.joint_sigma
    if sigma is None:
        return problem
    key = "noise.joint_motion_sigma"
    if len(sigma) == 1:
        sigma = sigma * robot.nq
    elif len(sigma) != robot.nq:
        raise ProblemError(str(problem.path), key, f"expected one number or {robot.nq} (one per "
                           f"joint: {', '.join(robot.joint_names)}), got {len(sigma)}")
    if problem.camera.moves and any(v > 0 for v in sigma):
        raise ProblemError(str(problem.path), key, "joint-space motion noise with camera.moves is "
                           "not supported (the noise's Jacobian is taken in one camera frame)")
    return replace(problem, noise=replace(problem.noise, joint_sigma=tuple(sigma)))


def _continued_at(setup: Setup, x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The pose `x` with its rotation vector continued to the side of the mean at joints
    `q` (same rotation)."""
    return np.concatenate([x[:3], continued(x[3:], setup.pose_of(q)[3:])[0]])


def _camera_schedule(problem: Problem, ecm: Robot, first: np.ndarray) -> list[np.ndarray]:
    moves = problem.camera.moves
    if not moves:
        return []
    T = problem.horizon
    poses, current = [], first
    by_step = {}
    for i, mv in enumerate(moves):
        if mv.step > T:
            raise ProblemError(str(problem.path), f"camera.moves[{i}].step", "must be <= horizon "
                               f"({T})")
        _check_joints(problem, ecm, mv.ecm_joints, f"camera.moves[{i}].ecm_joints")
        by_step[mv.step] = ecm.base_pose @ ecm.frame_pose(mv.ecm_joints)
    for t in range(T + 1):
        current = by_step.get(t, current)
        poses.append(current)
    return poses


def _check_joints(problem: Problem, robot: Robot, q: np.ndarray, key: str) -> None:
    if len(q) != robot.nq:
        raise ProblemError(str(problem.path), key,
                           f"expected {robot.nq} joint values ({', '.join(robot.joint_names)}), "
                           f"got {len(q)}")
    for name, v, lo, hi in zip(robot.joint_names, q, robot.lower, robot.upper):
        if not lo - 1e-12 <= v <= hi + 1e-12:
            raise ProblemError(str(problem.path), key, f"joint '{name}' = {v:g} outside its limits "
                               f"[{lo:g}, {hi:g}]")


def _endpoint(problem: Problem, setup: Setup, spec: EndpointSpec, seed: np.ndarray):
    file = str(problem.path)
    if spec.joints is not None:
        _check_joints(problem, setup.robot, spec.joints, spec.key)
        q = np.asarray(spec.joints, float)
        x = setup.pose_of(q)
    else:
        x = (np.asarray(spec.pose, float) if spec.relative is None
             else _relative_goal(problem, setup, spec))
        x = matrix_to_pose(pose_to_matrix(x))  # normalise the angle into [0, pi]
        _check_depth(problem, spec, x)
        _check_reach(problem, setup, spec, x)
        try:
            q, _, _ = setup.joints_for(x, seed, what=f"the pose at {spec.key}")
        except UnreachablePose as exc:
            raise ProblemError(file, spec.key, str(exc)) from None
    _check_depth(problem, spec, x)
    return q, x


def _relative_goal(problem: Problem, setup: Setup, spec: EndpointSpec) -> np.ndarray:
    """Camera-frame pose of a goal given in another arm's tracked-object frame."""
    arm = spec.relative.arm
    key = f"{spec.key}.arm"
    other = load_robot(str(problem.path), key, arm)
    _check_joints(problem, other, arm.joints, f"{key}.joints")
    setup.other_arms.append(other)
    T_world_obj = other.base_pose @ other.frame_pose(arm.joints)
    return matrix_to_pose(np.linalg.inv(setup.camera_pose) @ T_world_obj
                          @ pose_to_matrix(spec.relative.pose))


def reach_bound(robot: Robot) -> float:
    """An upper bound [m] on the distance from the URDF root to the tracked object: the lengths
    of the chain's joint placements, prismatic travels and frame offsets added up (inf for
    unbounded travel)."""
    f = robot.model.frames[robot.frame_id]
    total = float(np.linalg.norm(f.placement.translation) + np.linalg.norm(robot.offset[:3, 3]))
    jid = int(f.parentJoint)
    while jid > 0:
        j = robot._joints[jid - 1]
        total += float(np.linalg.norm(j.placement[:3, 3]))
        if j.prismatic:
            total += max(abs(j.lower), abs(j.upper)) * float(np.linalg.norm(j.axis))
        jid = int(robot.model.parents[jid])
    return total


def _check_reach(problem: Problem, setup: Setup, spec: EndpointSpec, x: np.ndarray) -> None:
    """A pose farther from the arm's root than the arm can reach is refused at once (the IK would
    search for seconds to say the same)."""
    p = (np.linalg.inv(setup.T_cam_base) @ pose_to_matrix(x))[:3, 3]
    bound = reach_bound(setup.robot)
    if np.isfinite(bound) and np.linalg.norm(p) > bound + 1e-9:
        raise ProblemError(str(problem.path), spec.key,
                           f"not reachable: the position is {np.linalg.norm(p):.4f} m from the "
                           f"arm's URDF root, beyond its reach of at most {bound:.4f} m")


def _check_depth(problem: Problem, spec: EndpointSpec, x: np.ndarray) -> None:
    file = str(problem.path)
    if x[2] <= 0:
        raise ProblemError(file, spec.key, f"the tool is behind the camera (depth z = {x[2]:.4f} "
                                           "m); the camera looks along its +z axis")
    if x[2] < problem.min_depth:
        raise ProblemError(file, spec.key, f"depth z = {x[2]:.4f} m is below constraints.min_depth "
                                           f"= {problem.min_depth} m")
