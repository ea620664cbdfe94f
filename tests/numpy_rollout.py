"""One closed-loop rollout in plain NumPy, written from surestep_method.md section 7 and
`rollout.Detection`'s rule.

Independent of `surestep_ocp.evaluation.rollout`: one rollout at a time, the noise formulas of
numpy_ekf.py, scipy rotations, the detection region written out in pixels. It is driven by the
rollout's own standard normals (per step: 6 for the motion noise, then 6 for the observation noise),
so it must give the same paths. Noise constants must be multiples of the 6x6 identity (the paper's):
then W = c I and a draw is sqrt(c) z.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

import numpy_ekf


def pixel(p, cam) -> tuple[float, float]:
    """Pinhole pixel of camera-frame point p as fractions of the image width and height."""
    return (cam.fx * p[0] / p[2] + cam.cx) / cam.width, (cam.fy * p[1] / p[2] + cam.cy) / cam.height


def detectable(p, cam, margin: float, min_depth: float, max_depth: float) -> bool:
    """Depth strictly inside (min_depth, max_depth) and the pixel inside the image less `margin` at
    each border."""
    if not min_depth < p[2] < max_depth:
        return False
    u, v = pixel(p, cam)
    return margin <= u <= 1 - margin and margin <= v <= 1 - margin


def _scalar(M) -> float:
    M = np.asarray(M, float)
    c = M[0, 0]
    assert np.allclose(M, c * np.eye(6), rtol=1e-12, atol=0), ("noise constants must be "
                                                               "multiples of I")
    return c


def replay(poses, noise, cam, mode: str, z_w, z_v, detection=None, target=None,
           steps: int | None = None) -> list[dict]:
    """Per step t -> t+1, a record of one rollout of `poses` ((T+1, 6), camera frame) from normals
    z_w, z_v (T, 6).

    detection: (margin, min_depth, max_depth) or None (every step observed). target: None (the
    waypoints), or a closed loop's `target(t, estimate)` -> the (6,) pose to command at step t;
    `steps`: how many steps to run (default T). Records: the commanded
    step `dp` and rotation `angle` (from the estimate to the waypoint), the motion-noise variance
    `cW` (W = cW I) and its draw `w`, the true pose `true` and estimate `est` after the step,
    `true_seen` (the true pose detectable), `seen` (and the measurement too: the EKF updated), the
    observation-noise variance `cV` used for the draw and the measurement's position `z_p`, and the
    covariance `sigma`.
    """
    poses = np.asarray(poses, float)
    guard, band = noise.cosine_guard**2, noise.cut_band
    p_mu, R_mu = poses[0, :3].copy(), Rotation.from_rotvec(poses[0, 3:])
    p_tr, R_tr = p_mu.copy(), R_mu
    sig = np.asarray(noise.Sigma0, float).copy()
    rows = []
    for t in range(len(poses) - 1 if steps is None else steps):
        goal = (poses[t + 1] if target is None
                else np.asarray(target(t, np.hstack([p_mu, R_mu.as_rotvec()])), float))
        tgt_p, tgt_R = goal[:3], Rotation.from_rotvec(goal[3:])
        dp = tgt_p - p_mu
        D = R_mu.inv() * tgt_R  # the commanded rotation, body frame of the estimate
        cW = _scalar(numpy_ekf.motion_noise(np.hstack([p_mu, R_mu.as_rotvec()]), goal, noise))
        w = np.sqrt(cW) * np.asarray(z_w[t], float)
        p_tr = p_tr + dp + w[:3]
        R_tr = Rotation.from_rotvec(w[3:]) * R_tr * D
        x_tr = np.hstack([p_tr, R_tr.as_rotvec()])
        P = sig + cW * np.eye(6)
        V_ekf = numpy_ekf.observation_noise(goal, noise, cam, guard=guard, band=band)
        seen = True if detection is None else detectable(p_tr, cam, *detection)
        true_seen = seen
        at = x_tr if (mode == "true" and seen) else goal
        cV = _scalar(numpy_ekf.observation_noise(at, noise, cam, guard=guard, band=band))
        v = np.sqrt(cV) * np.asarray(z_v[t], float)
        z_p, z_R = p_tr + v[:3], Rotation.from_rotvec(v[3:]) * R_tr
        if detection is not None:
            seen = seen and detectable(z_p, cam, *detection)
        if seen:
            K = P @ np.linalg.inv(P + V_ekf)
            dx = K @ np.hstack([z_p - tgt_p, (z_R * tgt_R.inv()).as_rotvec()])
            p_mu, R_mu = tgt_p + dx[:3], Rotation.from_rotvec(dx[3:]) * tgt_R
            sig = (np.eye(6) - K) @ P
            sig = 0.5 * (sig + sig.T)
        else:
            p_mu, R_mu, sig = tgt_p.copy(), tgt_R, P
        rows.append(dict(t=t, true_seen=true_seen, dp=dp, angle=D.magnitude(), cW=cW, w=w,
                         true=x_tr, seen=seen, cV=cV, cV_ekf=V_ekf[0, 0],
                         gain=(P @ np.linalg.inv(P + V_ekf))[0, 0], z_p=z_p,
                         est=np.hstack([p_mu, R_mu.as_rotvec()]), sigma=sig.copy()))
    return rows


def draws(rng: np.random.Generator, n: int, T: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rollout k's normals (T, 6) each for w and v, from the n x 6 + n x 6 draws per step of
    `rollout`'s rng."""
    z_w, z_v = np.zeros((T, 6)), np.zeros((T, 6))
    for t in range(T):
        z_w[t] = rng.standard_normal((n, 6))[k]
        z_v[t] = rng.standard_normal((n, 6))[k]
    return z_w, z_v
