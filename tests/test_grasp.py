"""The grasp confidence (issue 43): its probability against sampling, the problem's keys, planning
to a confidence (the horizon searched), and the status when the cap cannot reach it.

References are independent of the code under test: Monte Carlo draws of the Gaussian error, and
the plain NumPy EKF (tests/numpy_ekf.py) along a returned plan.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from numpy_ekf import image_offset, information_posterior, motion_noise
from surestep_ocp import cli
from surestep_ocp.evaluation.closed_loop import robot_pace
from surestep_ocp.model.grasp import grasp_probability, nees, within
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.methods.confidence import NOT_REACHED, at_horizon
from surestep_ocp.methods.registry import run_method

REPO = Path(__file__).resolve().parents[1]


def sampled(cov, position, angle, n=400_000, seed=0) -> float:
    e = np.random.default_rng(seed).multivariate_normal(np.zeros(6), cov, size=n)
    return float(within(np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1),
                        position, angle).mean())


def covariances():
    """Isotropic, anisotropic, correlated (position with orientation) and near-singular ones at the
    scales the Table II types reach."""
    rng = np.random.default_rng(3)
    out = [np.diag([4e-6] * 3 + [8e-3] * 3), np.diag([1e-6, 6e-6, 2e-6, 1e-2, 2e-3, 5e-3])]
    for scale in (0.5, 2.0):
        B = np.eye(6) + 0.4 * rng.standard_normal((6, 6))
        out.append(scale * B @ np.diag([2e-6, 3e-6, 1e-6, 4e-3, 1e-2, 6e-3]) @ B.T)
    out.append(np.diag([9e-6, 1e-14, 1e-14, 1e-14, 1e-14, 2e-2]))
    return out


@pytest.mark.parametrize("k", range(5))
def test_the_probability_matches_sampling(k):
    cov = covariances()[k]
    p = grasp_probability(cov, 0.005, 0.2)
    assert abs(p - sampled(cov, 0.005, 0.2, seed=k)) < 0.005  # 0.5 points (sampling's sd < 0.08)


def test_the_probability_of_a_stack_and_of_the_extremes():
    covs = np.array(covariances())
    np.testing.assert_allclose(grasp_probability(covs, 0.004, 0.3),
                               [grasp_probability(c, 0.004, 0.3) for c in covs], atol=1e-12)
    assert grasp_probability(np.zeros((6, 6)), 0.005, 0.2) == 1.0
    assert grasp_probability(np.eye(6), 0.005, 0.2) < 1e-9
    # isotropic blocks: the product of two chi^2_3 CDFs (independent closed form)
    from scipy.stats import chi2
    cov = np.diag([5e-6] * 3 + [1e-2] * 3)
    exact = chi2.cdf(0.005**2 / 5e-6, 3) * chi2.cdf(0.2**2 / 1e-2, 3)
    assert abs(grasp_probability(cov, 0.005, 0.2) - exact) < 2e-3


def test_success_is_within_the_tolerance_boundary_included():
    assert within(0.005, 0.2, 0.005, 0.2) and not within(0.0050001, 0.1, 0.005, 0.2)


def test_nees_is_the_mahalanobis_square():
    cov = np.array(covariances()[2])
    e = np.random.default_rng(0).multivariate_normal(np.zeros(6), cov, size=20000)
    v = nees(e, np.broadcast_to(cov, (len(e), 6, 6)))
    assert abs(v.mean() - 6.0) < 0.15


def tree(name: str, **goal) -> dict:
    t = yaml.safe_load((REPO / "problems" / name).read_text())
    t = copy.deepcopy(t)
    t["goal"].update(goal)
    return t


@pytest.mark.parametrize("edit, key", [
    (lambda t: t["goal"].update(confidence=1.0), "goal.confidence"),
    (lambda t: t["goal"].update(confidence=0), "goal.confidence"),
    (lambda t: t["goal"].update(confidence="high"), "goal.confidence"),
    (lambda t: t["goal"].update(tolerance={"position": 0.0}), "goal.tolerance.position"),
    (lambda t: t["goal"].update(tolerance={"angle": -1}), "goal.tolerance.angle"),
    (lambda t: t["goal"].update(tolerance={"radius": 1}), "goal.tolerance.radius"),
    (lambda t: t.setdefault("timing", {}).update(max_duration=0.5), "timing.max_duration"),
    (lambda t: t["start"].update(confidence=0.9), "start.confidence"),
])
def test_bad_grasp_keys_are_one_line_exit_2(tmp_path, capsys, edit, key):
    t = tree("type1_hard.yaml")
    edit(t)
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(t))
    code = cli.main(["validate", str(path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and key in err[0] and "Traceback" not in err[0], err


def test_the_keys_are_read_with_their_defaults():
    p = load_problem(REPO / "problems" / "type1_hard.yaml")
    assert (p.grasp.position, p.grasp.angle, p.grasp.confidence) == (0.005, 0.2, None)
    assert p.timing.max_steps(p.horizon) == 2 * p.horizon
    q = p.with_sections(goal=tree("type1_hard.yaml", confidence=0.9,
                                  tolerance={"position": 0.004})["goal"],
                        timing={"max_duration": 1.52})
    assert (q.grasp.position, q.grasp.angle, q.grasp.confidence) == (0.004, 0.2, 0.9)
    assert q.timing.max_steps(q.horizon) == 30


@pytest.fixture(scope="module")
def hard_at_robot_pace():
    """Type 1 hard (dim light) at the robot's pace, asking for 0.95."""
    p = robot_pace(load_problem(REPO / "problems" / "type1_hard.yaml"))
    return build_setup(p.with_sections(goal={**p.source["goal"], "confidence": 0.95}))


def expected_V(x, P, noise, camera, h=1e-6) -> np.ndarray:
    """V expected under N(x, P), written from surestep_method.md section 8: per term, the squared
    residual plus tr(J P J^T), J by central differences (positions added, rotations perturbed on
    the left, as the rollouts' errors are)."""
    from scipy.spatial.transform import Rotation

    def residuals(y):
        p, r = y[:3], Rotation.from_rotvec(y[3:]).as_rotvec()
        o = np.asarray(noise.o_star, float)
        cos = float(r @ o) / (np.sqrt(r @ r + noise.cosine_guard ** 2) * np.linalg.norm(o))
        u = np.cos(0.5 * np.linalg.norm(r)) / np.sin(0.5 * noise.cut_band)
        cos *= 1.0 if u >= 1 else 0.5 * (3 * u - u**3)
        du, dv = image_offset(p, camera)
        return [np.array([p[2] - noise.depth_star]), np.array([du, dv]), np.array([1.0 - cos])]

    def moved(d):
        y = np.array(x, float)
        y[:3] += d[:3]
        y[3:] = (Rotation.from_rotvec(d[3:]) * Rotation.from_rotvec(x[3:])).as_rotvec()
        return residuals(y)

    e0 = residuals(np.asarray(x, float))
    J = [np.zeros((len(e), 6)) for e in e0]
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        for i, (a, b) in enumerate(zip(moved(d), moved(-d))):
            J[i][:, k] = (a - b) / (2 * h)
    mats = [noise.V_d0, noise.V_f0, noise.V_o0]
    return np.asarray(noise.V_min, float) + sum(
        (e @ e + np.trace(Ji @ P @ Ji.T)) * np.asarray(M, float) for e, Ji, M in zip(e0, J, mats))


def numpy_confidence(setup, sol, seen=None) -> float:
    """The plan's Sigma_T|T-1 by a NumPy EKF with the expected noise (the observations at the
    waypoints `seen` only), its grasp probability by sampling."""
    noise, cam = setup.ocp.noise, setup.ocp.intrinsics
    poses = np.asarray(sol.poses, float)
    sig = np.asarray(noise.Sigma0, float)
    for t in range(len(poses) - 1):
        P = sig + motion_noise(poses[t], poses[t + 1], noise)
        post = information_posterior(P, expected_V(poses[t + 1], P, noise, cam))
        sig = post if seen is None or seen[t + 1] else P
    return sampled(P, 0.005, 0.2, n=300_000), P


def test_a_plan_to_a_confidence_is_the_shortest_that_reaches_it(hard_at_robot_pace):
    s = hard_at_robot_pace
    sol = run_method(s, "ocp")
    rec = sol.extras["grasp"]
    assert sol.success and rec["reached"] and rec["confidence"] == 0.95
    assert sol.horizon > s.ocp.horizon  # more than the nominal 2 s in dim light
    p = numpy_confidence(s, sol)[0]
    assert abs(p - rec["predicted"]) < 0.01 and p > 0.94
    # one step fewer does not reach it (a plain solve of that horizon, checked by NumPy)
    shorter = run_method(at_horizon(s.with_ocp(grasp=s.ocp.grasp.__class__()), sol.horizon - 1),
                         "ocp")
    assert (not shorter.success) or numpy_confidence(s, shorter)[0] < 0.95


def test_a_confidence_the_cap_cannot_reach_is_a_status(tmp_path, capsys):
    t = tree("type1_hard.yaml", confidence=0.999999)
    t["timing"] = {"max_duration": 1.1}
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(t))
    out = tmp_path / "sol.json"
    code = cli.main(["solve", str(path), "--method", "ocp", "--output", str(out)])
    captured = capsys.readouterr()
    assert code == 1 and "Traceback" not in captured.err
    assert NOT_REACHED in captured.out and "confidence" in captured.out
    import json
    rec = json.loads(out.read_text())["grasp"]
    assert rec["reached"] is False and rec["predicted"] < 0.999999
    assert rec["duration_s"] <= 1.1 + 1e-9 and rec["searched"]


def test_the_planner_plans_to_the_confidence():
    """A nominal 1 s is too short for 0.95 on Type 1 medium: the Planner lengthens it to the
    shortest horizon that reaches it, and never shortens the problem's own 2 s."""
    from surestep_ocp.methods.planner import Planner

    p = robot_pace(load_problem(REPO / "problems" / "type1_medium.yaml"))
    medium = build_setup(p.with_sections(goal={**p.source["goal"], "confidence": 0.95}))
    short = medium.with_ocp(horizon=20)
    planner = Planner(short, prebuild=False)
    assert planner.grasp["reached"] and planner.horizon == planner.plan.horizon
    assert 20 < planner.horizon <= 40 and planner.plan.success
    assert numpy_confidence(short, planner.plan)[0] > 0.94
    assert Planner(medium, prebuild=False).horizon == 40


def test_a_plan_counts_only_the_observations_the_detector_delivers():
    """The confidence with a detector equals the NumPy EKF's that skips the updates at waypoints
    outside the detectable region (rollout.Detection's hard edge)."""
    from surestep_ocp.model.detection import Detection
    from surestep_ocp.methods.confidence import predicted_at_grasp

    p = load_problem(REPO / "problems" / "type1_medium.yaml")
    seen = build_setup(p.with_sections(detection={"margin": 0.25}))
    assert seen.ocp.detection == Detection(margin=0.25)
    sol = run_method(build_setup(p), "baseline")
    poses = np.asarray(sol.poses, float)
    ok = Detection(margin=0.25).probability(seen.eval_model.camera, poses[:, :3]) > 0
    assert 0 < ok.sum() < len(ok)  # some waypoints seen, some not
    _, P = numpy_confidence(seen, sol, ok)
    np.testing.assert_allclose(predicted_at_grasp(seen, sol), P, rtol=1e-5, atol=1e-14)
    everywhere = predicted_at_grasp(build_setup(p), sol)
    np.testing.assert_allclose(everywhere, numpy_confidence(seen, sol)[1], rtol=1e-5, atol=1e-14)
    assert np.trace(everywhere) < np.trace(P)  # the missed observations cost confidence


def test_a_detection_section_is_checked():
    p = load_problem(REPO / "problems" / "type1_medium.yaml")
    assert p.detection is None
    with pytest.raises(Exception, match="detection.max_depth"):
        p.with_sections(detection={"min_depth": 0.3, "max_depth": 0.2})
    assert p.with_sections(detection={"enabled": False}).detection is None
