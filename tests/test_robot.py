"""Symbolic kinematics (surestep_ocp.model.robot) against Pinocchio.

Robot.fk_function walks the Pinocchio model to build a CasADi expression; every
check here compares it with Pinocchio's own numeric kinematics (frame poses and
frame Jacobians). The rotation helpers (surestep_ocp.model.lie) against scipy: test_lie.py.
"""

from __future__ import annotations

import sysconfig
from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.errors import FrameNotFound
from surestep_ocp.model.robot import Robot

REPO_ROOT = Path(__file__).resolve().parents[1]
PSM_URDF = REPO_ROOT / "robots" / "psm.urdf"
ERD = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
UR5_URDF = ERD / "ur_description/urdf/ur5_robot.urdf"
PANDA_URDF = ERD / "panda_description/urdf/panda.urdf"
N_CONFIGS = 100
TOL = 1e-10

SYNTHETIC_URDF = """<?xml version="1.0"?>
<robot name="synthetic">
  <link name="base"/><link name="l1"/><link name="l2"/>
  <link name="l3"/><link name="l4"/><link name="tip"/>
  <joint name="spin" type="continuous">
    <parent link="base"/><child link="l1"/>
    <origin xyz="0.1 -0.05 0.2" rpy="0.3 -0.2 0.7"/><axis xyz="1 0 0"/>
  </joint>
  <joint name="slide" type="prismatic">
    <parent link="l1"/><child link="l2"/>
    <origin xyz="0.0 0.15 0.05" rpy="-0.4 0.1 0.2"/><axis xyz="0.6 0 0.8"/>
    <limit lower="-0.1" upper="0.3" effort="1" velocity="1"/>
  </joint>
  <joint name="tilt" type="revolute">
    <parent link="l2"/><child link="l3"/>
    <origin xyz="0.2 0.0 -0.1" rpy="0.0 0.5 -0.3"/><axis xyz="0 0.6 -0.8"/>
    <limit lower="-2.0" upper="2.0" effort="1" velocity="1"/>
  </joint>
  <joint name="push" type="prismatic">
    <parent link="l3"/><child link="l4"/>
    <origin xyz="0.05 0.05 0.0" rpy="0.2 0.2 0.2"/><axis xyz="0 0 1"/>
    <limit lower="0.0" upper="0.2" effort="1" velocity="1"/>
  </joint>
  <joint name="tip_joint" type="fixed">
    <parent link="l4"/><child link="tip"/>
    <origin xyz="0.01 0.02 0.03" rpy="1.0 -0.5 0.25"/>
  </joint>
</robot>
"""


@pytest.fixture(scope="module")
def synthetic_urdf(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("urdf") / "synthetic.urdf"
    path.write_text(SYNTHETIC_URDF)
    return path


def random_joints(model: pin.Model, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random configuration: (one value per joint for the package, Pinocchio's q vector).

    Written here from Pinocchio's joint models (not via Robot.to_pinocchio): continuous
    joints (nq = 2) are stored as (cos, sin) and sampled over [-pi, pi].
    """
    q_pkg, q_pin = [], np.zeros(model.nq)
    for jid in range(1, model.njoints):
        jm = model.joints[jid]
        if jm.nq == 2:
            a = rng.uniform(-np.pi, np.pi)
            q_pin[jm.idx_q : jm.idx_q + 2] = np.cos(a), np.sin(a)
        else:
            lo, hi = model.lowerPositionLimit[jm.idx_q], model.upperPositionLimit[jm.idx_q]
            a = rng.uniform(max(lo, -np.pi), min(hi, np.pi))
            q_pin[jm.idx_q] = a
        q_pkg.append(a)
    return np.array(q_pkg), q_pin


def _vee(S: np.ndarray) -> np.ndarray:
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


def fk_and_jacobian_functions(robot: Robot, frame: str) -> ca.Function:
    """(p, R, Jp, Jw) of the package's symbolic FK; Jw from dR/dq_i R^T = skew(w_i)."""
    fk = robot.fk_function(frame)
    q = ca.SX.sym("q", robot.nq)
    p, R = fk(q)
    Jp = ca.jacobian(p, q)
    dR = ca.jacobian(ca.vec(R), q)  # column i: vec(dR/dq_i), column-major
    return ca.Function("fkj", [q], [p, R, Jp, dR])


CASES = [  # (name, URDF, frames, seed)
    ("psm", PSM_URDF, ["tool", "jaw_tip"], 1),
    ("ur5", UR5_URDF, ["tool0"], 2),
    ("panda", PANDA_URDF, ["panda_hand_tcp", "panda_leftfinger", "panda_rightfinger"], 3),
]


def check_against_pinocchio(urdf: Path, frames: list[str], seed: int, n: int = N_CONFIGS):
    robot = Robot(urdf, frame=frames[0])
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    funcs = {f: fk_and_jacobian_functions(robot, f) for f in frames}
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q, q_pin = random_joints(model, rng)
        pin.framesForwardKinematics(model, data, q_pin)
        for f in frames:
            fid = model.getFrameId(f)
            M = data.oMf[fid]
            p, R, Jp, dR = (np.asarray(v) for v in funcs[f](q))
            np.testing.assert_allclose(
                p.ravel(), M.translation, rtol=0, atol=TOL, err_msg=f"{f} position"
            )
            np.testing.assert_allclose(R, M.rotation, rtol=0, atol=TOL, err_msg=f"{f} rotation")
            J = pin.computeFrameJacobian(model, data, q_pin, fid, pin.LOCAL_WORLD_ALIGNED)
            Jw = np.column_stack(
                [_vee(dR[:, i].reshape(3, 3, order="F") @ R.T) for i in range(robot.nq)]
            )
            np.testing.assert_allclose(Jp, J[:3], rtol=0, atol=TOL, err_msg=f"{f} linear Jacobian")
            np.testing.assert_allclose(Jw, J[3:], rtol=0, atol=TOL, err_msg=f"{f} angular Jacobian")
            # the package's numeric path (Robot.frame_pose, its own q conversion) agrees
            np.testing.assert_allclose(robot.frame_pose(q, f), M.homogeneous, rtol=0, atol=1e-14)
    return robot, model


@pytest.mark.parametrize("name, urdf, frames, seed", CASES, ids=[c[0] for c in CASES])
def test_symbolic_fk_and_jacobian_match_pinocchio(name, urdf, frames, seed):
    """The OCP's kinematic constraint and its derivatives are exactly Pinocchio's, on real arms."""
    assert urdf.is_file(), urdf
    robot, model = check_against_pinocchio(urdf, frames, seed=seed)
    assert robot.nq == model.nv
    assert robot.joint_names == [model.names[j] for j in range(1, model.njoints)]


def test_panda_has_prismatic_fingers():
    """The Panda case really exercises prismatic joints (aligned and unaligned) in a tree."""
    model = pin.buildModelFromUrdf(str(PANDA_URDF))
    kinds = {model.names[j]: model.joints[j].shortname() for j in range(1, model.njoints)}
    assert kinds["panda_finger_joint1"] == "JointModelPY", kinds
    assert kinds["panda_finger_joint2"] == "JointModelPrismaticUnaligned", kinds


def test_synthetic_continuous_and_unaligned_joints(synthetic_urdf):
    """Continuous (cos, sin) joints and joints about arbitrary axes are converted correctly."""
    model = pin.buildModelFromUrdf(str(synthetic_urdf))
    kinds = [model.joints[j].shortname() for j in range(1, model.njoints)]
    assert kinds == [
        "JointModelRUBX",
        "JointModelPrismaticUnaligned",
        "JointModelRevoluteUnaligned",
        "JointModelPZ",
    ]
    assert model.nq == 5 and model.nv == 4
    robot, _ = check_against_pinocchio(synthetic_urdf, ["tip", "l2", "l3"], seed=7)
    assert robot.nq == 4
    assert np.isinf(robot.lower[0]) and np.isinf(robot.upper[0])
    # a continuous joint is periodic: q and q + 2 pi give the same pose
    fk = robot.fk_function("tip")
    q = np.array([0.4, 0.1, -0.5, 0.05])
    p1, R1 = fk(q)
    p2, R2 = fk(q + np.array([2 * np.pi, 0, 0, 0]))
    np.testing.assert_allclose(np.asarray(p1), np.asarray(p2), atol=1e-14)
    np.testing.assert_allclose(np.asarray(R1), np.asarray(R2), atol=1e-14)


def test_to_pinocchio_conversion(synthetic_urdf):
    """One value per joint maps to Pinocchio's q, with (cos, sin) for continuous joints."""
    robot = Robot(synthetic_urdf, frame="tip")
    q = np.array([2.5, 0.1, -0.5, 0.05])
    np.testing.assert_allclose(
        robot.to_pinocchio(q), [np.cos(2.5), np.sin(2.5), 0.1, -0.5, 0.05], atol=1e-15
    )


def test_fk_cached_property_is_tracked_frame():
    """Robot.fk is the FK of the frame the robot tracks (the one the OCP constrains)."""
    robot = Robot(PSM_URDF, frame="jaw_tip")
    q = np.array([0.1, -0.2, 0.15, 0.3, 0.2, -0.1, 0.4])
    p, R = robot.fk(q)
    T = robot.frame_pose(q)
    np.testing.assert_allclose(np.asarray(p).ravel(), T[:3, 3], atol=TOL)
    np.testing.assert_allclose(np.asarray(R), T[:3, :3], atol=TOL)


# ------------------------------------------------------------------ inverse kinematics


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_inverse_kinematics_recovers_reachable_pose(seed):
    """IK (goal, initial guess) reaches a pose the arm can reach, inside its limits."""
    robot = Robot(PSM_URDF, frame="tool")
    rng = np.random.default_rng(seed)
    lo, hi = robot.lower, robot.upper
    q_true = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
    target = robot.frame_pose(q_true)
    q0 = 0.5 * (lo + hi)
    q, err_p, err_r = robot.inverse_kinematics(target, q0)
    assert err_p <= 1e-9 and err_r <= 1e-9
    T = robot.frame_pose(q)
    assert np.linalg.norm(T[:3, 3] - target[:3, 3]) <= 1e-9
    assert Rotation.from_matrix(T[:3, :3].T @ target[:3, :3]).magnitude() <= 1e-9
    assert np.all(q >= lo) and np.all(q <= hi)
    # the jaw does not move the tool frame: IK leaves it at its starting value
    assert q[robot.joint_names.index("jaw")] == q0[robot.joint_names.index("jaw")]


def test_inverse_kinematics_unreachable_raises():
    """An out-of-reach pose raises UnreachablePose, or returns the best effort if asked."""
    from surestep_ocp.errors import UnreachablePose

    robot = Robot(PSM_URDF, frame="tool")
    target = np.eye(4)
    target[:3, 3] = [0.0, 0.0, -1.0]  # 1 m down the shaft: beyond the insertion range
    q0 = 0.5 * (robot.lower + robot.upper)
    with pytest.raises(UnreachablePose) as info:
        robot.inverse_kinematics(target, q0, restarts=2)
    assert info.value.residual_m > 0.5
    q, err_p, _ = robot.inverse_kinematics(target, q0, restarts=2, raise_on_fail=False)
    assert err_p > 0.5 and np.all(q >= robot.lower) and np.all(q <= robot.upper)


def test_frame_not_found_lists_frames():
    """A misspelt frame name fails at construction and lists the available frames."""
    with pytest.raises(FrameNotFound) as info:
        Robot(PSM_URDF, frame="tooltip")
    msg = str(info.value)
    assert "tooltip" in msg
    for name in ("tool", "jaw_tip", "wrist_yaw_link", "psm_rcm"):
        assert name in info.value.available and name in msg
    robot = Robot(PSM_URDF)
    with pytest.raises(FrameNotFound):
        robot.fk_function("nope")


def test_batched_ik_keeps_its_buffers_per_thread():
    """The batched IK and the camera means are evaluated in place in buffers that each thread has
    to itself (an in-process Dask cluster runs configurations in threads of one process): two
    threads get distinct buffers, and IK run from several threads at once gives what it gives
    alone, checked against Pinocchio's FK of the targets' joints."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from surestep_ocp.buffered import thread_buffered as _buffered

    robot = Robot(PSM_URDF, frame="tool")
    rng = np.random.default_rng(3)
    lo, hi = robot.lower, robot.upper
    truth = [np.clip(rng.uniform(lo, hi), lo, hi) for _ in range(8)]
    targets = [robot.frame_pose(q) for q in truth]
    seeds = [np.clip(q + 0.05 * rng.normal(size=q.shape), lo, hi) for q in truth]

    def solve(k):
        q, ok, _ = robot.newton_batch(np.stack([targets[k]] * 3), np.stack([seeds[k]] * 3))
        return q, ok

    alone = [solve(k) for k in range(8)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(solve, list(range(8)) * 6))
    for k, (q, ok) in enumerate(together):
        np.testing.assert_array_equal(q, alone[k % 8][0])
        np.testing.assert_array_equal(ok, alone[k % 8][1])
    # the solutions reach the targets (Pinocchio's FK, not the batch's own residual)
    for k, (q, ok) in enumerate(alone):
        for qi, oki in zip(q, ok):
            if oki:
                np.testing.assert_allclose(robot.frame_pose(qi), targets[k], atol=1e-9)
    assert any(ok.all() for _, ok in alone)

    def double():
        x = ca.SX.sym("x")
        return ca.Function("f", [x], [2 * x])

    here = _buffered(("test", 1), double)
    other = []
    t = threading.Thread(target=lambda: other.append(_buffered(("test", 1), double)))
    t.start()
    t.join()
    assert other[0] is not here
    assert _buffered(("test", 1), None) is here  # this thread's, built once
