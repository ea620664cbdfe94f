"""Robot kinematics: a Pinocchio model and its symbolic CasADi forward kinematics.

The PyPI `pin` wheels ship no `pinocchio.casadi`, so the symbolic forward
kinematics is built here by walking the Pinocchio `Model`: joint placements,
1-DoF joints (revolute, continuous, prismatic, about any axis) and fixed frames.
Any serial or tree URDF made of such joints works.

Joint vectors in this package hold one value per 1-DoF joint (angle [rad] or
displacement [m]), in the model's joint order; continuous joints (Pinocchio
stores them as `(cos, sin)`) are converted at the boundary by `to_pinocchio`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
from scipy.optimize import least_squares

from ..errors import FrameNotFound, UnreachablePose, UnsupportedJoint
from ..buffered import thread_buffered
from .lie import np_log, np_quat_of_matrix, quat_mul, so3_exp, so3_log

# the camera parameter of `Robot.camera_pose`: vec(T_cam_base[:3, :]), then its quaternion
CAMERA_PARAMETERS = 16


@dataclass(frozen=True)
class _Joint:
    name: str
    parent: int  # index into Pinocchio's joints (0 = universe)
    placement: np.ndarray  # 4x4, parent joint frame -> this joint frame at zero
    axis: np.ndarray  # unit 3-vector, in this joint's frame
    prismatic: bool
    continuous: bool  # stored by Pinocchio as (cos, sin)
    lower: float
    upper: float


_IK_FUNCS: dict[tuple, ca.Function] = {}  # (urdf, mtime, frame, offset) -> IK residual Function


def _quat_of(R: np.ndarray) -> ca.DM:
    """Quaternion `(w, x, y, z)` of a constant rotation matrix (either sign; used
    as a fixed factor)."""
    return ca.DM(np_quat_of_matrix(R))


def _se3(M: pin.SE3) -> np.ndarray:
    return np.asarray(M.homogeneous, dtype=float)


def _parse_joints(model: pin.Model) -> list[_Joint]:
    joints = []
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        name = model.names[jid]
        if jm.nv != 1 or jm.nq not in (1, 2):
            raise UnsupportedJoint(
                f"joint '{name}' ({jm.shortname()}) has {jm.nv} degrees of freedom; "
                "only revolute, continuous and prismatic joints are supported"
            )
        jd = jm.createData()
        jm.calc(jd, pin.neutral(model)[jm.idx_q : jm.idx_q + jm.nq])
        S = np.asarray(jd.S).ravel()
        lin, ang = S[:3], S[3:]
        if np.linalg.norm(lin) > 1e-12 and np.linalg.norm(ang) > 1e-12:
            raise UnsupportedJoint(f"joint '{name}' ({jm.shortname()}) is helical; not supported")
        prismatic = np.linalg.norm(lin) > 1e-12
        continuous = jm.nq == 2
        if continuous:
            lower, upper = -np.inf, np.inf
        else:
            lower = float(model.lowerPositionLimit[jm.idx_q])
            upper = float(model.upperPositionLimit[jm.idx_q])
        joints.append(
            _Joint(
                name=name,
                parent=int(model.parents[jid]),
                placement=_se3(model.jointPlacements[jid]),
                axis=lin if prismatic else ang,
                prismatic=prismatic,
                continuous=continuous,
                lower=lower,
                upper=upper,
            )
        )
    return joints


def _joint_motion(j: _Joint, q):
    """Homogeneous transform of a 1-DoF joint's motion by `q` (CasADi)."""
    T = ca.SX.eye(4)
    if j.prismatic:
        T[:3, 3] = ca.DM(j.axis) * q
    else:
        T[:3, :3] = so3_exp(ca.DM(j.axis) * q)
    return T


class Robot:
    """A kinematic model loaded from a URDF, with numeric and symbolic FK and IK.

    Args:
        urdf: path of the URDF file.
        base_pose: 4x4 pose of the URDF root in the world frame.
        frame: name of the frame the tracked object is attached to.
        offset: 4x4 pose of the tracked object in that frame (e.g. a needle's grasp
            transform); identity by default. `frame_pose` and `fk_expr` called without
            a frame name give the tracked object's pose (frame composed with offset).
    """

    def __init__(self, urdf: str | Path, base_pose: np.ndarray | None = None, frame: str = "tool",
                 offset: np.ndarray | None = None):
        self.urdf = Path(urdf)
        self.model = pin.buildModelFromUrdf(str(self.urdf))
        self.data = self.model.createData()
        self._joints = _parse_joints(self.model)
        self.base_pose = np.eye(4) if base_pose is None else np.asarray(base_pose, dtype=float)
        self.frame = frame
        self.offset = np.eye(4) if offset is None else np.asarray(offset, dtype=float)
        self.frame_id = self.frame_index(frame)
        # IK Functions are shared by every Robot of the same file, frame and offset (a new setup per
        # problem, e.g. per evaluation instance, would otherwise rebuild them; the cost is in
        # docs/solve_speed.md, "Builds shared between set-ups")
        self._ik_key = (str(self.urdf.resolve()), self.urdf.stat().st_mtime_ns, frame,
                        self.offset.tobytes())

    # ------------------------------------------------------------------ model facts
    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self._joints]

    @property
    def nq(self) -> int:
        return len(self._joints)

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self._joints])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self._joints])

    @property
    def frame_names(self) -> list[str]:
        return [f.name for f in self.model.frames]

    def frame_index(self, name: str) -> int:
        if not self.model.existFrame(name):
            raise FrameNotFound(name, self.frame_names)
        return int(self.model.getFrameId(name))

    def supporting_joints(self, frame: str | None = None) -> list[int]:
        """Indices (into `joint_names`) of the joints that move `frame` (kept per frame: IK asks
        at every call)."""
        known = self.__dict__.setdefault("_supporting", {})
        name = frame or self.frame
        if name not in known:
            jid = int(self.model.frames[self.frame_index(name)].parentJoint)
            known[name] = tuple(sorted(i - 1 for i in self.model.supports[jid] if i > 0))
        return list(known[name])

    # ------------------------------------------------------------------ numeric FK
    def to_pinocchio(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio configuration vector of a joint vector (one value per joint)."""
        out = np.zeros(self.model.nq)
        for k, (j, jm) in enumerate(zip(self._joints, self.model.joints[1:])):
            if j.continuous:
                out[jm.idx_q : jm.idx_q + 2] = np.cos(q[k]), np.sin(q[k])
            else:
                out[jm.idx_q] = q[k]
        return out

    def frame_pose(self, q: np.ndarray, frame: str | None = None) -> np.ndarray:
        """4x4 pose of `frame` (default: the tracked object) in the URDF root
        frame, by Pinocchio."""
        fid = self.frame_index(frame or self.frame)
        pin.framesForwardKinematics(self.model, self.data, self.to_pinocchio(np.asarray(q, float)))
        T = _se3(self.data.oMf[fid])
        return T if frame is not None else T @ self.offset

    def frame_jacobian(self, q: np.ndarray, frame: str) -> np.ndarray:
        """6 x nq Jacobian of `frame` (Pinocchio, LOCAL_WORLD_ALIGNED): rows 0-2 map the joint rates
        to the velocity of the frame's origin, rows 3-5 to its angular velocity, both in the root's
        axes; one column per joint value (a continuous joint's angle rate)."""
        fid = self.frame_index(frame)
        return np.asarray(pin.computeFrameJacobian(self.model, self.data,
                                                   self.to_pinocchio(np.asarray(q, float)),
                                                   fid, pin.LOCAL_WORLD_ALIGNED), dtype=float)

    # ------------------------------------------------------------------ symbolic FK
    def fk_expr(self, q: ca.SX, frame: str | None = None) -> ca.SX:
        """4x4 symbolic pose of `frame` (default: the tracked object) in the URDF root frame."""
        fid = self.frame_index(frame or self.frame)
        f = self.model.frames[fid]
        chain = []
        jid = int(f.parentJoint)
        while jid > 0:
            chain.append(jid)
            jid = int(self.model.parents[jid])
        T = ca.SX.eye(4)
        for jid in reversed(chain):
            j = self._joints[jid - 1]
            T = T @ ca.DM(j.placement) @ _joint_motion(j, q[jid - 1])
        T = T @ ca.DM(_se3(f.placement))
        return T if frame is not None else T @ ca.DM(self.offset)

    def fk_quaternion_expr(self, q: ca.SX) -> ca.SX:
        """Unit quaternion `(w, x, y, z)` of the tracked object's orientation in the URDF
        root frame (CasADi).

        The product of the joints' half-angle quaternions and the constant placements' (fixed
        signs): a smooth function of the joints whose sign is continuous along every joint path (the
        double cover), where a quaternion taken from the rotation matrix must pick a sign.
        """
        f = self.model.frames[self.frame_id]
        chain = []
        jid = int(f.parentJoint)
        while jid > 0:
            chain.append(jid)
            jid = int(self.model.parents[jid])
        Q = _quat_of(np.eye(3))
        for jid in reversed(chain):
            j = self._joints[jid - 1]
            Q = quat_mul(Q, _quat_of(j.placement[:3, :3]))
            if not j.prismatic:
                Q = quat_mul(Q, ca.vertcat(ca.cos(0.5 * q[jid - 1]),
                                           ca.sin(0.5 * q[jid - 1]) * ca.DM(j.axis)))
        return quat_mul(quat_mul(Q, _quat_of(_se3(f.placement)[:3, :3])),
                        _quat_of(self.offset[:3, :3]))

    @cached_property
    def fk_quaternion(self) -> ca.Function:
        """`fk_quaternion(q) -> Q` of `fk_quaternion_expr` (built once)."""
        q = ca.SX.sym("q", self.nq)
        return ca.Function("fk_quaternion", [q], [self.fk_quaternion_expr(q)], ["q"], ["Q"])

    @cached_property
    def camera_pose(self) -> ca.Function:
        """`pose(q, camera) -> mean` (position [m], unit quaternion `(w, x, y, z)`: 7 numbers) of
        the tracked object in the camera frame; `camera` (CAMERA_PARAMETERS) is vec of the root's
        3x4 pose in the camera frame, then that rotation's quaternion with the sign that makes the
        start's angle at most pi (`Setup.camera_parameter`).

        The quaternion is the product of the joints' half-angle quaternions (`fk_quaternion_expr`):
        smooth in the joints, no chart (docs/orientation.md).
        """
        q, cam = ca.SX.sym("q", self.nq), ca.SX.sym("camera", CAMERA_PARAMETERS)
        Tcb, Tq = cam[:12].reshape((3, 4)), self.fk_expr(q)
        Q = quat_mul(cam[12:], self.fk_quaternion_expr(q))
        return ca.Function("pose", [q, cam], [ca.vertcat(Tcb[:, :3] @ Tq[:3, 3] + Tcb[:, 3], Q)],
                           ["q", "camera"], ["mean"])

    def camera_poses(self, n: int) -> ca.Function:
        """`camera_pose` mapped over n joint vectors (columns), built once per n."""
        maps = self.__dict__.setdefault("_camera_pose_maps", {})
        if n not in maps:
            maps[n] = self.camera_pose.map(n)
        return maps[n]

    def camera_means(self, q: np.ndarray, camera: np.ndarray) -> np.ndarray:
        """(N, 7) `camera_pose` at the rows of `q` (N, nq), evaluated in place (no DM
        conversions: the re-planning loop calls it a few times a frame)."""
        n, maps = len(q), self.camera_poses

        def means():
            Q, C = ca.MX.sym("q", self.nq, n), ca.MX.sym("camera", self.camera_pose.size1_in(1))
            return ca.Function("camera_means", [Q, C], [ca.densify(maps(n)(Q, C))])

        # per thread (in-place buffers); the same file, frame and offset: the same function
        f = thread_buffered(("camera_means", self._ik_key, n), means)
        return f(np.asarray(q, float).T, camera)[0].reshape(n, 7).copy()

    def fk_function(self, frame: str | None = None) -> ca.Function:
        """CasADi Function `fk_<frame>(q) -> (p[3], R[3x3])` in the URDF root frame."""
        name = frame or self.frame
        q = ca.SX.sym("q", self.nq)
        T = self.fk_expr(q, frame)
        return ca.Function(f"fk_{name}", [q], [T[:3, 3], T[:3, :3]], ["q"], ["p", "R"])

    @cached_property
    def fk(self) -> ca.Function:
        """Symbolic FK of the tracked object (frame composed with offset; built once)."""
        return self.fk_function()

    # ------------------------------------------------------------------ inverse kinematics
    @property
    def _ik_funcs(self) -> ca.Function:
        if self._ik_key not in _IK_FUNCS:
            _IK_FUNCS[self._ik_key] = self._build_ik_funcs()
        return _IK_FUNCS[self._ik_key]

    def compile_ik(self, compile_fns) -> str | None:
        """IK from now on with the residual `compile_fns` makes of it (its compiled C), for every
        robot of this model, once: `compile_fns({"ik_residual": f}) -> (functions, note)`, the
        note None when it compiled (`codegen.compiled_or_interpreted`). Returns that note (None:
        compiled, now or before)."""
        fn = self._ik_funcs
        if fn.class_name() != "SXFunction":
            return None
        fns, note = compile_fns({"ik_residual": fn})
        if note is None:
            _IK_FUNCS[self._ik_key] = fns["ik_residual"]
            # the mapped ones are rebuilt on the new function (in every thread: the key names it)
        return note

    def _build_ik_funcs(self) -> ca.Function:
        q = ca.SX.sym("q", self.nq)
        Tw = ca.SX.sym("Tw", 4, 4)  # target pose of the tracked frame in the URDF root frame
        T = self.fk_expr(q)
        e_p = T[:3, 3] - Tw[:3, 3]
        e_r = so3_log(Tw[:3, :3].T @ T[:3, :3])
        e = ca.vertcat(e_p, 0.05 * e_r)  # 0.05 m/rad: a wrist-sized lever arm
        return ca.Function("ik_residual", [q, Tw], [e, ca.jacobian(e, q)], ["q", "T"], ["e", "J"])

    def pose_error(self, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
        """Distance [m] and angle [rad] from the tracked frame at `q` (Pinocchio) to `target`
        (4x4, root frame)."""
        Tq = self.frame_pose(q)
        return (float(np.linalg.norm(Tq[:3, 3] - target[:3, 3])),
                float(np.linalg.norm(np_log(target[:3, :3].T @ Tq[:3, :3]))))

    def newton_batch(self, targets: np.ndarray, guesses: np.ndarray, iterations: int = 12):
        """Plain Newton IK of many targets at once (one CasADi call per iteration),
        each from its own guess.

        Args:
            targets: (N, 4, 4) poses of the tracked frame in the URDF root frame.
            guesses: (N, nq) joint vectors to start from (joints that do not move
                the frame are kept).

        Returns:
            (q (N, nq), converged (N,), errors (N, 2)): converged entries are inside the joint
            limits with a residual below 1e-13 (position [m], orientation times 0.05 m); the
            others are to be solved otherwise. `errors`: distance [m] and angle [rad] to the
            target of the converged ones.
        """
        N, nq = len(targets), self.nq
        fn = self._ik_funcs

        def batch():
            # (evaluated in place on NumPy arrays, dense: no DM conversions per iteration)
            Qs, Ts = ca.MX.sym("Q", nq, N), ca.MX.sym("T", 4, 4 * N)
            return ca.Function("ik_batch", [Qs, Ts],
                               [ca.densify(v) for v in fn.map(N)(Qs, Ts)])

        # per thread (in-place buffers; e.g. an in-process Dask cluster's workers are threads)
        f = thread_buffered(("ik", fn, N), batch)
        movable = np.array(self.supporting_joints())
        lo, hi = self.lower[movable], self.upper[movable]
        Q = np.array(guesses, dtype=float)
        T = np.hstack(list(targets))
        done, alive = np.zeros(N, bool), np.all((Q[:, movable] >= lo) & (Q[:, movable] <= hi),
                                                axis=1)
        errors = np.full((N, 2), np.inf)
        for _ in range(iterations + 1):
            E, J = f(Q.T, T)  # (6, N), (6, N nq), column-major
            E = E.reshape(N, 6)
            J = J.reshape(N, nq, 6).transpose(0, 2, 1)[:, :, movable]
            now = alive & ~done & (np.linalg.norm(E, axis=1) < 1e-13)
            if now.any():
                errors[now] = np.stack([np.linalg.norm(E[now, :3], axis=1),
                                        np.linalg.norm(E[now, 3:], axis=1) / 0.05], 1)
                done |= now
            active = alive & ~done
            if not active.any():
                break
            idx = np.flatnonzero(active)
            try:  # square Jacobians (six movable joints): one batched solve
                if J.shape[1] != J.shape[2]:
                    raise np.linalg.LinAlgError("not square")
                if len(idx) == N:  # (every target still moving: no gather)
                    Q[:, movable] -= np.linalg.solve(J, E[:, :, None])[:, :, 0]
                else:
                    Q[np.ix_(idx, movable)] -= np.linalg.solve(J[idx], E[idx][:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                # a singular one, or redundant/deficient arms: least squares each
                for k in idx:
                    try:
                        Q[k, movable] -= np.linalg.lstsq(J[k], E[k], rcond=None)[0]
                    except np.linalg.LinAlgError:
                        alive[k] = False
            alive &= np.all((Q[:, movable] >= lo) & (Q[:, movable] <= hi), axis=1)
        return Q, done, errors

    def inverse_kinematics(
        self,
        target: np.ndarray,
        q0: np.ndarray,
        what: str = "pose",
        restarts: int = 20,
        seed: int = 0,
        tol_m: float = 1e-9,
        tol_rad: float = 1e-9,
        raise_on_fail: bool = True,
    ) -> tuple[np.ndarray, float, float]:
        """Joint vector whose tracked frame reaches `target` (4x4, URDF root frame).

        Bounded least squares (joint limits as bounds), started at `q0`, then at
        seeded random configurations. Joints that do not move the frame keep
        their `q0` values.

        Returns:
            (q, position residual [m], orientation residual [rad]).

        Raises:
            UnreachablePose: no start converged below the tolerances (when `raise_on_fail`).
        """
        f = self._ik_funcs
        movable = np.array(self.supporting_joints())
        lo, hi = self.lower[movable], self.upper[movable]
        lo_f = np.where(np.isfinite(lo), lo, -np.pi)
        hi_f = np.where(np.isfinite(hi), hi, np.pi)
        base = np.array(q0, dtype=float)

        def full(x):
            q = base.copy()
            q[movable] = x
            return q

        def fun(x):
            return np.asarray(f(full(x), target)[0]).ravel()

        def jac(x):
            return np.asarray(f(full(x), target)[1])[:, movable]

        rng = np.random.default_rng(seed) if restarts else None
        best = None
        for k in range(restarts + 1):  # q0 first, then seeded random starts
            x0 = np.clip(np.clip(base[movable], lo_f, hi_f) if k == 0 else rng.uniform(lo_f, hi_f),
                         lo, hi)
            if k == 0:  # a nearby start: plain Newton steps first
                q_newton, ok, _ = self.newton_batch(target[None], full(x0)[None])
            if k == 0 and ok[0]:
                x = q_newton[0, movable]
            else:
                x = least_squares(fun, x0, jac=jac, bounds=(lo, hi), xtol=1e-15, ftol=1e-15,
                                  gtol=1e-15, max_nfev=200).x
            q = full(x)
            err_p, err_r = self.pose_error(q, target)
            if best is None or err_p + 0.05 * err_r < best[1] + 0.05 * best[2]:
                best = (q, err_p, err_r)
            if err_p <= tol_m and err_r <= tol_rad:
                return best
        if raise_on_fail:
            raise UnreachablePose(what, best[1], best[2])
        return best

