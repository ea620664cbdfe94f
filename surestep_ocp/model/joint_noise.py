"""Joint-space motion noise: cable stretch and hysteresis act on the joints, not on the tool's pose.

A step from q_t to q_t+1 leaves each joint off by an independent error of standard deviation
`sigma_j |q_t+1,j - q_t,j|` (sigma_j dimensionless: rad per rad, m per m), which the kinematics map
into the belief's coordinates at q_t:

    W_q = J(q_t) diag(sigma^2 (q_t+1 - q_t)^2) J(q_t)^T,   J = d (p, e) / d q

the Jacobian in the belief's tangent (`tangent_jacobian`): the position's and the camera-frame
angular velocity's (the left perturbation `exp(e) R` of the mean `Robot.camera_pose(q, camera)`), so
the planner, the evaluation and the tests use one definition. The matrix is configuration-dependent
and not diagonal in the camera frame; it is added to the paper's pose-space W in every EKF predict
step (`BeliefModel.predict_expr`'s `w`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .belief import unvech, vech
from .lie import quat_tangent
from .robot import CAMERA_PARAMETERS, Robot


def tangent_jacobian(robot: Robot, q, camera):
    """J (6 x nq SX): the mean's derivative in the tangent, `d(p, e)/dq` with
    `R(q + dq) = exp(J_e dq) R(q)` (from the FK quaternion's derivative, `e = 4 E(Q)^T dQ`,
    `lie.quat_tangent`)."""
    m = robot.camera_pose(q, camera)
    Jm = ca.jacobian(m, q)
    return ca.vertcat(Jm[:3, :], 4 * quat_tangent(m[3:7]).T @ Jm[3:7, :])


def joint_noise_factor(robot: Robot, sigma, qa, qb, camera):
    """U (6 x nq SX) with `W_q = U U^T`: column k is `sigma_k (qb_k - qa_k) J_k(qa)`."""
    J = tangent_jacobian(robot, qa, camera)
    return J @ ca.diag(ca.DM(np.asarray(sigma, float)) * (qb - qa))


def joint_noise_expr(robot: Robot, sigma, qa, qb, camera):
    """`W_q` (6x6 SX) of the step qa -> qb for the per-joint `sigma` (nq numbers)."""
    U = joint_noise_factor(robot, sigma, qa, qb, camera)
    return U @ U.T


def weight_matrix(wj):
    """G with `<G, W> = wj . vech(W)` for symmetric W: the weights of vech, halved
    off the diagonal."""
    return 0.5 * (unvech(wj) + ca.diag(ca.diag(unvech(wj))))


def joint_noise_curvature(robot: Robot, sigma, qa, camera, wj):
    """Curvature in (qa, qb) of the surrogate's term `wj . vech(W_q)` with J held
    at qa (2nq x 2nq SX).

    With `G = dS/dW` (from the weights `wj` of vech: halved off the diagonal) the term is
    `sum_k sigma_k^2 dq_k^2 J_k^T G J_k`, quadratic in each joint's step: this is its exact Hessian
    in qb and drops only the variation of J with qa (third derivatives of the kinematics). G is
    positive semidefinite (S is nondecreasing in W), so the block is too.
    """
    nq = robot.nq
    G = weight_matrix(wj)
    J = tangent_jacobian(robot, qa, camera)
    a = ca.vertcat(*[float(sigma[k]) ** 2 * ca.bilin(G, J[:, k], J[:, k]) for k in range(nq)])
    A = ca.diag(2 * a)
    return ca.vertcat(ca.horzcat(A, -A), ca.horzcat(-A, A))


def joint_noise_function(robot: Robot, sigma) -> ca.Function:
    """`(qa, qb, camera) -> vech(W_q)` (built once per robot and sigma)."""
    sigma = tuple(float(v) for v in sigma)
    cache = robot.__dict__.setdefault("_joint_noise_functions", {})
    if sigma not in cache:
        qa, qb = ca.SX.sym("qa", robot.nq), ca.SX.sym("qb", robot.nq)
        cam = ca.SX.sym("camera", CAMERA_PARAMETERS)
        cache[sigma] = ca.Function("joint_noise", [qa, qb, cam],
                                   [vech(joint_noise_expr(robot, sigma, qa, qb, cam))],
                                   ["qa", "qb", "camera"], ["w"])
    return cache[sigma]


def joint_noises(robot: Robot, sigma, q: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(T, 21) vech of `W_q` for each step of the joint trajectory `q` (T+1, nq)."""
    q = np.asarray(q, float)
    T = len(q) - 1
    key = (tuple(float(v) for v in sigma), T)
    maps = robot.__dict__.setdefault("_joint_noise_maps", {})
    if key not in maps:
        maps[key] = joint_noise_function(robot, sigma).map(T)
    out = maps[key](q[:-1].T, q[1:].T, camera)
    return np.asarray(out).T.reshape(T, -1)
