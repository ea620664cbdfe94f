"""An executed joint motion checked against the motion limits, independently of the planner's rows.

The stitched joint curve (each plan from its start until the next one's) is sampled every
millisecond, its velocities and accelerations taken by finite differences, the tool's speeds from
Pinocchio's kinematics of the samples, and compared with the limit values of the problem.
"""

import numpy as np

from surestep_ocp.model.limits import evaluate_curve, problem_limits

H = 1e-3  # [s] sampling of the executed curve


def stitched(pieces, dt):
    """Joint samples every H seconds of the executed motion: each plan (start step, joints, start
    state or None) from its start until the next one's."""
    out = []
    for i, (k, q, start) in enumerate(pieces):
        end = pieces[i + 1][0] if i + 1 < len(pieces) else k + len(q) - 1
        t = np.arange(round((end - k) * dt / H) + (i + 1 == len(pieces))) * H
        out.append(evaluate_curve(q, dt, t, start=start)[0])
    return np.vstack(out)


def assert_within_limits(setup, q) -> float:
    """Assert every limit on the samples q (every H seconds); returns the peak tool speed [m/s]."""
    lim, robot = problem_limits(setup), setup.robot
    assert np.all(q >= robot.lower - 1e-9) and np.all(q <= robot.upper + 1e-9)
    v = np.diff(q, axis=0) / H
    a = np.diff(q, n=2, axis=0) / H**2
    mov = robot.supporting_joints()
    # finite differences of a curve whose jerk is bounded: within 1 % of the limits plus the
    # differencing error
    assert np.all(np.abs(v[:, mov]) <= lim.velocity[mov] * 1.001 + 1e-6)
    assert np.all(np.abs(a[:, mov]) <= lim.acceleration[mov] * 1.01 + 1e-3)
    # every 5 ms; the tool's frame without a needle offset (as the limits define it)
    poses = np.array([robot.frame_pose(qi, robot.frame) for qi in q[::5]])
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / (5 * H)
    assert speed.max() <= lim.tool_speed * 1.001
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    angle = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)) / (5 * H)
    assert angle.max() <= lim.tool_rotation * 1.001
    return float(speed.max())


def assert_tool_gradients_match(rows, q, h=1e-6):
    """The certificate's tool rows' gradients at the joints q against central differences of the
    rows' own values (each joint of each waypoint moved by +-h)."""
    _, tool, Jz = rows.values(q, False, [0.0])
    G = rows.tool_gradients(np.arange(len(tool)), Jz)
    D = np.zeros_like(G)
    for i in range(q.size):
        e = np.zeros(q.size)
        e[i] = h
        up = rows.values(q + e.reshape(q.shape), False, [0.0])[1]
        down = rows.values(q - e.reshape(q.shape), False, [0.0])[1]
        D[:, i] = (up - down) / (2 * h)
    np.testing.assert_allclose(G, D, atol=1e-5 * max(1.0, np.abs(D).max()))
