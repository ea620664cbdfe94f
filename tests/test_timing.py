"""Time in the model: `timing: {step_s, tracker_hz}`, k = step_s * tracker_hz observations per step.

The package folds the k tracker frames of a step into one observation with covariance V / k
(problems/README.md, "Time in the model"). These tests run a plain NumPy EKF (tests/numpy_ekf.py)
that makes the k updates one after the other, with the file's own V, and compare.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import numpy_ekf as ref
import pytest

from surestep_ocp.ocp.straight_line import straight_line
from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.errors import ProblemError
from surestep_ocp.methods.registry import run_method
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.spec import TimingSpec
from surestep_ocp.problem.setup import build_setup


def sequential_ekf(poses, noise, camera, k, H=None, R=None):
    """Posterior covariances along `poses`: per step one prediction, then k sequential EKF
    updates."""
    I6 = np.eye(6)
    H = I6 if H is None else H
    R = I6 if R is None else R
    sig = np.asarray(noise.Sigma0, float)
    out = [sig]
    for t in range(len(poses) - 1):
        P = sig + ref.motion_noise(poses[t], poses[t + 1], noise)
        V = ref.observation_noise(poses[t + 1], noise, camera, guard=COSINE_GUARD,
                                  band=noise.cut_band)
        for _ in range(k):  # the k frames of the step, each observed with the file's own V
            S = H @ P @ H.T + R @ V @ R.T
            K = P @ H.T @ np.linalg.inv(S)
            P = (I6 - K @ H) @ P
            P = 0.5 * (P + P.T)
        sig = P
        out.append(sig)
    return np.array(out)


def test_defaults_are_the_papers_one_observation_per_waypoint(default_problem):
    assert default_problem.timing == TimingSpec(step_s=0.05, tracker_hz=20.0)
    assert default_problem.timing.frames == 1
    np.testing.assert_array_equal(default_problem.noise.V_d0, 1e-1 * np.eye(6))  # unchanged


@pytest.mark.parametrize(("step_s", "hz", "k"), [(0.1, 20, 2), (0.25, 20, 5), (0.05, 60, 3)])
def test_k_frames_per_step_equal_k_sequential_numpy_updates(write_problem, default_problem, step_s,
                                                            hz, k):
    path = write_problem(lambda t: t.update(timing={"step_s": step_s, "tracker_hz": hz}),
                         name=f"k{k}")
    prob = load_problem(path)
    assert prob.timing.frames == k
    setup = build_setup(prob)
    poses = straight_line(setup.x_start, setup.x_goal, prob.horizon)
    sig, _ = setup.eval_model.propagate(poses)
    # the reference sees the file's constants (k = 1 problem) and makes the k updates itself
    expected = sequential_ekf(poses, default_problem.noise, prob.camera.intrinsics, k)
    assert ref.rel_err(sig, expected) < 1e-9
    # and more frames per step do shrink the final covariance
    single = sequential_ekf(poses, default_problem.noise, prob.camera.intrinsics, 1)
    assert np.trace(sig[-1]) < np.trace(single[-1])


def test_solution_trace_with_frames_matches_the_numpy_ekf(write_problem, default_problem):
    """What a method reports (Solution.trace, evaluated with all components) is the k-update EKF's
    trace."""
    path = write_problem(lambda t: t.update(timing={"step_s": 0.2, "tracker_hz": 20}), name="k4")
    setup = build_setup(load_problem(path))
    sol = run_method(setup, "baseline")
    expected = sequential_ekf(np.asarray(sol.poses), default_problem.noise,
                              setup.ocp.intrinsics, 4)
    np.testing.assert_allclose(sol.trace, np.trace(expected, axis1=1, axis2=2), rtol=1e-9, atol=0)


def test_k_updates_equal_one_with_v_over_k_for_any_fixed_h_and_r():
    """The derivation's claim beyond identity maps: k updates with the same H, R, V are one with V /
    k."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        A = rng.normal(size=(6, 6))
        P = A @ A.T + 1e-3 * np.eye(6)
        H, R = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
        B = rng.normal(size=(6, 6))
        V = B @ B.T + 1e-3 * np.eye(6)
        k = int(rng.integers(2, 9))
        Pk = P.copy()
        for _ in range(k):
            K = Pk @ H.T @ np.linalg.inv(H @ Pk @ H.T + R @ V @ R.T)
            Pk = (np.eye(6) - K @ H) @ Pk
        K1 = P @ H.T @ np.linalg.inv(H @ P @ H.T + R @ (V / k) @ R.T)
        P1 = (np.eye(6) - K1 @ H) @ P
        assert ref.rel_err(Pk, P1) < 1e-8


@pytest.mark.parametrize(("timing", "needle"), [
    ({"step_s": 0.07, "tracker_hz": 20}, "1.4 tracker frames"),
    ({"step_s": 0.01, "tracker_hz": 20}, "0.2 tracker frames"),
    ({"step_s": -1, "tracker_hz": 20}, "timing.step_s"),
    ({"step_s": 0.1, "tracker_hz": "fast"}, "timing.tracker_hz"),
    ({"step_s": 0.1, "rate": 20}, "rate"),
])
def test_bad_timing_is_one_line_naming_the_key(write_problem, timing, needle):
    path = write_problem(lambda t: t.update(timing=timing), name="bad_timing")
    with pytest.raises(ProblemError) as exc:
        load_problem(path)
    assert needle in str(exc.value) and "timing" in str(exc.value) and "\n" not in str(exc.value)
    out = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "validate", str(path)],
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    assert (out.returncode == 2 and needle in out.stderr
            and len(out.stderr.strip().splitlines()) == 1)
