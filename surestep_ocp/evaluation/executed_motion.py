"""The motion a re-planning loop executes, and an independent check of it against the limits.

A loop's executed motion is each plan's curve (the exported one, `model/limits/curve.py`) from its
start until the next plan's start. The check does not use the planner's rows: the stitched joint
curve is sampled every `H` seconds, its velocities and accelerations taken by finite differences,
the tool's speeds from Pinocchio's kinematics of the samples, and compared with the limit values.
"""

from __future__ import annotations

import numpy as np

from ..model.limits import evaluate_curve, problem_limits

H = 1e-3  # [s] sampling of the executed motion


def stitched(pieces, dt: float) -> np.ndarray:
    """Joint samples every H seconds of the executed motion.

    pieces: (start step, joints (n+1, nq), start state (velocity, acceleration) or None at rest) of
    each plan that was current, in order; the last one runs to its end."""
    out = []
    for i, (k, q, start) in enumerate(pieces):
        end = pieces[i + 1][0] if i + 1 < len(pieces) else k + len(q) - 1
        t = np.arange(round((end - k) * dt / H) + (i + 1 == len(pieces))) * H
        out.append(evaluate_curve(np.asarray(q, float), dt, t, start=start)[0])
    return np.vstack(out)


def violations(setup, q: np.ndarray) -> int:
    """Samples of the executed joints `q` (every H seconds) beyond a limit: joint bounds, joint
    velocities and accelerations (finite differences), the tool's speed and rotation speed
    (Pinocchio's kinematics every 5 ms); each beyond by more than the differencing error (0.1 % of
    the velocity limits, 1 % of the acceleration ones). The tool is the robot's frame without a
    needle offset (as the limits define it, `plan_report`)."""
    lim, robot = problem_limits(setup), setup.robot
    mov = robot.supporting_joints()
    v = np.diff(q, axis=0)[:, mov] / H
    a = np.diff(q, n=2, axis=0)[:, mov] / H**2
    poses = np.array([robot.frame_pose(qi, robot.frame) for qi in q[::5]])
    speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / (5 * H)
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    turn = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)) / (5 * H)
    return int(np.sum((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))
               + np.sum(np.abs(v) > lim.velocity[mov] * 1.001 + 1e-6)
               + np.sum(np.abs(a) > lim.acceleration[mov] * 1.01 + 1e-3)
               + np.sum(speed > lim.tool_speed * 1.001) + np.sum(turn > lim.tool_rotation * 1.001))
