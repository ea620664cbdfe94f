"""Checks robots/psm.urdf and robots/ecm.urdf against an independent modified-DH forward kinematics.

The DH tables below are copied by hand from /work/shared/reference/dvrk_kinematics.md
(section 1a PSM + LND 400006, section 2a ECM) and the tool-tip offsets from sections 1b / 2b.
Nothing here is read from the URDF files, so a mistake in a joint origin shows up as a mismatch.
"""

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
PSM_URDF = ROBOTS / "psm.urdf"
ECM_URDF = ROBOTS / "ecm.urdf"

HALF_PI = np.pi / 2
N_SAMPLES = 50
TOL = 1e-9  # URDF vs DH FK, both exact
SANITY_TOL = 1e-4  # the reference sanity values are rounded to 0.1 mm

# (type, alpha, A, D, offset) per modified-DH row; offset goes to theta (R) or to D (P).
PSM_DH = [
    ("R", +HALF_PI, 0.0, 0.0, +HALF_PI),  # yaw
    ("R", -HALF_PI, 0.0, 0.0, -HALF_PI),  # pitch
    ("P", +HALF_PI, 0.0, 0.0, -0.4318),  # insertion (L_rcc)
    ("R", 0.0, 0.0, 0.4162, 0.0),  # roll (L_tool)
    ("R", -HALF_PI, 0.0, 0.0, -HALF_PI),  # wrist_pitch
    ("R", -HALF_PI, 0.0091, 0.0, -HALF_PI),  # wrist_yaw (L_pitch2yaw)
]
ECM_DH = [
    ("R", +HALF_PI, 0.0, 0.0, +HALF_PI),  # yaw
    ("R", -HALF_PI, 0.0, 0.0, -HALF_PI),  # pitch
    ("P", +HALF_PI, 0.0, 0.0, -0.3822),  # insertion
    ("R", 0.0, 0.0, 0.3829, 0.0),  # roll
]

PSM_JOINTS = ["yaw", "pitch", "insertion", "roll", "wrist_pitch", "wrist_yaw", "jaw"]
PSM_LINKS = ["yaw_link", "pitch_link", "insertion_link", "roll_link", "wrist_pitch_link",
             "wrist_yaw_link"]
PSM_LOWER = [-1.588, -0.925025, 0.0, -4.53786, -1.39626, -1.39626, -0.698132]
PSM_UPPER = [1.588, 0.925025, 0.24, 4.53786, 1.39626, 1.39626, 1.39626]

ECM_JOINTS = ["yaw", "pitch", "insertion", "roll"]
ECM_LINKS = ["yaw_link", "pitch_link", "insertion_link", "roll_link"]
ECM_LOWER = [-1.5708, -0.76794, 0.0, -1.552]
ECM_UPPER = [1.5708, 1.1344, 0.255, 1.552]


def _hom(R=np.eye(3), p=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


PSM_TOOLTIP = _hom(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]))
PSM_JAW_TIP = _hom(p=(0.0, 0.0, 0.0102))
ECM_TOOLTIP = _hom(np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
OPENCV_FROM_ISI = _hom(np.diag([-1.0, -1.0, 1.0]))  # Rz(180 deg)


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return _hom(np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]))


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return _hom(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]))


def trans_x(d):
    return _hom(p=(d, 0.0, 0.0))


def trans_z(d):
    return _hom(p=(0.0, 0.0, d))


def dh_frames(table, q):
    """All modified-DH frames 1..n in frame 0: T_i = Rot_x(alpha) Trans_x(A) Rot_z(theta)
    Trans_z(D)."""
    T = np.eye(4)
    frames = []
    for (kind, alpha, A, D, offset), qi in zip(table, q):
        theta, d = (qi + offset, D) if kind == "R" else (0.0, D + qi + offset)
        T = T @ rot_x(alpha) @ trans_x(A) @ rot_z(theta) @ trans_z(d)
        frames.append(T)
    return frames


def psm_dh_tool(q):
    return dh_frames(PSM_DH, q[:6])[-1] @ PSM_TOOLTIP


def ecm_dh_tip(q):
    return dh_frames(ECM_DH, q[:4])[-1] @ ECM_TOOLTIP


def load(path):
    model = pin.buildModelFromUrdf(str(path))
    return model, model.createData()


def pin_fk(model, data, q, names):
    pin.framesForwardKinematics(model, data, np.asarray(q, dtype=float))
    return {n: data.oMf[model.getFrameId(n)].homogeneous.copy() for n in names}


def assert_pose(T_pin, T_ref, tol, what=""):
    dp = np.max(np.abs(T_pin[:3, 3] - T_ref[:3, 3]))
    dR = np.max(np.abs(T_pin[:3, :3] - T_ref[:3, :3]))
    assert dp <= tol and dR <= tol, f"{what}: |dp|={dp:.3e} |dR|={dR:.3e}"


def samples(model, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(model.lowerPositionLimit, model.upperPositionLimit,
                       size=(N_SAMPLES, model.nq))


@pytest.fixture(scope="module")
def psm():
    return load(PSM_URDF)


@pytest.fixture(scope="module")
def ecm():
    return load(ECM_URDF)


# --------------------------------------------------------------------------- structure


def test_psm_joint_names_and_order(psm):
    """Downstream code indexes q by position, so the joint order must be the dVRK order."""
    model, _ = psm
    assert list(model.names)[1:] == PSM_JOINTS
    assert model.nq == model.nv == 7
    kinds = [model.joints[model.getJointId(n)].shortname() for n in PSM_JOINTS]
    assert kinds[:6] == ["JointModelRZ", "JointModelRZ", "JointModelPZ", "JointModelRZ",
                         "JointModelRZ", "JointModelRZ"]
    assert kinds[6] in ("JointModelRevoluteUnaligned", "JointModelRX")  # axis -x_tool


def test_ecm_joint_names_and_order(ecm):
    """Downstream code indexes q by position, so the joint order must be the dVRK order."""
    model, _ = ecm
    assert list(model.names)[1:] == ECM_JOINTS
    assert model.nq == model.nv == 4
    kinds = [model.joints[model.getJointId(n)].shortname() for n in ECM_JOINTS]
    assert kinds == ["JointModelRZ", "JointModelRZ", "JointModelPZ", "JointModelRZ"]


def test_joint_limits_match_tables(psm, ecm):
    """The optimiser's box constraints come from the model, so they must equal the saw limits."""
    np.testing.assert_array_equal(psm[0].lowerPositionLimit, PSM_LOWER)
    np.testing.assert_array_equal(psm[0].upperPositionLimit, PSM_UPPER)
    np.testing.assert_array_equal(ecm[0].lowerPositionLimit, ECM_LOWER)
    np.testing.assert_array_equal(ecm[0].upperPositionLimit, ECM_UPPER)


def test_root_frames_are_the_rcm(psm, ecm):
    """Frame 0 of both chains must be the RCM so scenes can place robots by their RCM."""
    for (model, data), root in ((psm, "psm_rcm"), (ecm, "ecm_rcm")):
        T = pin_fk(model, data, pin.neutral(model), [root])[root]
        assert_pose(T, np.eye(4), 0.0, root)


def test_visual_geometry_loads():
    """The viewer needs coloured primitive visuals for every moving part."""
    for path, n_min in ((PSM_URDF, 8), (ECM_URDF, 4)):
        model = pin.buildModelFromUrdf(str(path))
        geom = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.VISUAL)
        assert geom.ngeoms >= n_min
        kinds = {type(obj.geometry).__name__ for obj in geom.geometryObjects}
        assert kinds <= {"Sphere", "Box", "Cylinder"}, kinds  # primitives only, no mesh files
        colours = {tuple(np.round(obj.meshColor, 3)) for obj in geom.geometryObjects}
        assert len(colours) >= 4, colours  # distinct materials, recognisable in a viewer


# --------------------------------------------------------------------------- FK vs DH


def test_psm_link_frames_equal_dh_frames(psm):
    """Each PSM link frame must be its DH frame, so per-link geometry sits where the DH table
    says."""
    model, data = psm
    for q in samples(model, 1):
        fk = pin_fk(model, data, q, PSM_LINKS)
        for name, T_ref in zip(PSM_LINKS, dh_frames(PSM_DH, q[:6])):
            assert_pose(fk[name], T_ref, TOL, f"{name} q={q}")


def test_psm_tool_and_jaw_tip_equal_dh(psm):
    """tool (dVRK measured_cp) and jaw_tip drive the costs, so they must match DH * tooltip
    offset."""
    model, data = psm
    for q in samples(model, 2):
        fk = pin_fk(model, data, q, ["tool", "jaw_tip"])
        T_tool = psm_dh_tool(q)
        assert_pose(fk["tool"], T_tool, TOL, f"tool q={q}")
        assert_pose(fk["jaw_tip"], T_tool @ PSM_JAW_TIP, TOL, f"jaw_tip q={q}")


def test_ecm_link_frames_equal_dh_frames(ecm):
    """Each ECM link frame must be its DH frame, so the scope geometry sits where the DH table
    says."""
    model, data = ecm
    for q in samples(model, 3):
        fk = pin_fk(model, data, q, ECM_LINKS)
        for name, T_ref in zip(ECM_LINKS, dh_frames(ECM_DH, q)):
            assert_pose(fk[name], T_ref, TOL, f"{name} q={q}")


def test_ecm_tip_and_camera_equal_dh(ecm):
    """ecm_tip / camera define where the images are taken from, so they must match DH * offsets."""
    model, data = ecm
    for q in samples(model, 4):
        fk = pin_fk(model, data, q, ["ecm_tip", "camera"])
        T_tip = ecm_dh_tip(q)
        assert_pose(fk["ecm_tip"], T_tip, TOL, f"ecm_tip q={q}")
        assert_pose(fk["camera"], T_tip @ OPENCV_FROM_ISI, TOL, f"camera q={q}")


def test_psm_shaft_passes_through_rcm(psm):
    """The remote-centre-of-motion constraint: the shaft axis (DH frame 4 z) always hits the RCM."""
    model, data = psm
    for q in samples(model, 5):
        T4 = pin_fk(model, data, q, ["roll_link"])["roll_link"]
        p, z = T4[:3, 3], T4[:3, 2]
        assert np.linalg.norm(p - np.dot(p, z) * z) < TOL


# --------------------------------------------------------------------------- sanity poses


@pytest.mark.parametrize(
    "q6, pos, rot",
    [
        ((0, 0, 0, 0, 0, 0), (0.0, 0.0, 0.0065), [[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
        ((0, 0, 0.10, 0, 0, 0), (0.0, 0.0, -0.0935), [[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
        ((0.3, -0.2, 0.15, 0.5, 0.3, -0.4), (0.0404, 0.0261, -0.1348), None),
    ],
)
def test_psm_sanity_poses(psm, q6, pos, rot):
    """The reference doc's hand-checked PSM poses catch a systematically wrong DH transcription."""
    model, data = psm
    q = np.append(np.asarray(q6, float), 0.0)
    T = pin_fk(model, data, q, ["tool"])["tool"]
    np.testing.assert_allclose(T[:3, 3], pos, atol=SANITY_TOL)
    np.testing.assert_allclose(psm_dh_tool(q)[:3, 3], pos, atol=SANITY_TOL)
    if rot is not None:
        np.testing.assert_allclose(T[:3, :3], rot, atol=SANITY_TOL)


@pytest.mark.parametrize("q3, z", [(0.0, -0.0007), (0.10, -0.1007)])
def test_ecm_sanity_poses(ecm, q3, z):
    """The reference doc's ECM poses: the lens sits q3 + 0.7 mm past the RCM looking along -z."""
    model, data = ecm
    T = pin_fk(model, data, [0.0, 0.0, q3, 0.0], ["ecm_tip"])["ecm_tip"]
    np.testing.assert_allclose(T[:3, 3], (0.0, 0.0, z), atol=SANITY_TOL)
    np.testing.assert_allclose(T[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=SANITY_TOL)


# --------------------------------------------------------------------------- frame conventions


def test_jaw_does_not_move_tool_frames(psm):
    """The jaw opening is a leaf branch: opening the gripper must not move the tracked tool
    frames."""
    model, data = psm
    lo, hi = model.lowerPositionLimit[6], model.upperPositionLimit[6]
    for q in samples(model, 6)[:10]:
        q_a, q_b = q.copy(), q.copy()
        q_a[6], q_b[6] = lo, hi
        fa = pin_fk(model, data, q_a, ["tool", "jaw_tip", "jaw_link"])
        fb = pin_fk(model, data, q_b, ["tool", "jaw_tip", "jaw_link"])
        for name in ("tool", "jaw_tip"):
            assert_pose(fa[name], fb[name], 0.0 + 1e-15, name)
        # the jaw pivots about the wrist-yaw axis (tool -x) through the tool origin
        assert np.allclose(fa["jaw_link"][:3, 3], fa["tool"][:3, 3], atol=TOL)
        assert np.allclose(fb["jaw_link"][:3, 0], fb["tool"][:3, 0], atol=TOL)
        assert not np.allclose(fa["jaw_link"][:3, 2], fb["jaw_link"][:3, 2], atol=1e-3)


def test_camera_frame_is_opencv_rotation_of_tip(ecm):
    """camera must be the ISI tip frame turned 180 deg about z: same z, x and y flipped."""
    model, data = ecm
    for q in samples(model, 7)[:10]:
        fk = pin_fk(model, data, q, ["ecm_tip", "camera"])
        tip, cam = fk["ecm_tip"], fk["camera"]
        np.testing.assert_allclose(cam[:3, 3], tip[:3, 3], atol=TOL)
        np.testing.assert_allclose(cam[:3, 2], tip[:3, 2], atol=TOL)
        np.testing.assert_allclose(cam[:3, 0], -tip[:3, 0], atol=TOL)
        np.testing.assert_allclose(cam[:3, 1], -tip[:3, 1], atol=TOL)
