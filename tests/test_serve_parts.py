"""The node's parts without DDS: the played curve's switches at waypoints, the estimate moved along
the kinematics (the registration it gives, checked with 4x4 matrices), the message's conversion,
the watchdog, the ROS 2 name checks."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surestep_ocp.errors import SurestepError
from surestep_ocp.model.limits import evaluate_curve
from surestep_ocp.ros.faults import FaultLimits, Watchdog
from surestep_ocp.ros.names import check_domain, check_topic
from surestep_ocp.ros.played import PlayedCurve

DT = 0.05


def _plan(rng, n=12, nq=3):
    return np.cumsum(rng.normal(0, 0.01, (n + 1, nq)), axis=0)


def test_a_plan_switches_at_its_waypoint_with_the_same_state():
    rng = np.random.default_rng(0)
    old = _plan(rng)
    curve = PlayedCurve(DT, old)
    k = 4
    p, v, a = evaluate_curve(old, DT, np.array([k * DT]))
    new = np.vstack([p, p + _plan(rng, 8)[1:] - _plan(rng, 8)[:1]])  # from the state at k
    assert curve.add(k, new, (v[0], a[0]))
    before, after = curve.sample(k * DT - 1e-6), curve.sample(k * DT)
    assert before[2] == 0 and after[2] == k
    # the old curve at k is the new one's start: position and velocity
    assert np.allclose(p[0], after[0], atol=1e-12) and np.allclose(v[0], after[1], atol=1e-12)
    # the acceleration too: the new curve's start state is the old one's
    _, _, a_new = evaluate_curve(new, DT, np.array([0.0]), start=(v[0], a[0]))
    assert np.allclose(a_new[0], a[0])
    # after its end: the goal at rest
    q, vel, _ = curve.sample(100.0)
    assert np.array_equal(q, new[-1]) and not vel.any()
    assert curve.end_time == pytest.approx((k + len(new) - 1) * DT)


def test_a_plan_is_refused_once_a_set_point_after_its_waypoint_was_sent():
    rng = np.random.default_rng(1)
    curve = PlayedCurve(DT, _plan(rng))
    curve.sample(3 * DT, commit=True)  # the waypoint itself: either plan gives it
    assert curve.add(3, _plan(rng, 5), None)
    curve.sample(3 * DT + 0.005, commit=True)
    assert not curve.add(3, _plan(rng, 5), None)
    assert curve.add(4, _plan(rng, 5), None)


def _T(x):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rotation.from_rotvec(x[3:]).as_matrix(), x[:3]
    return T


def test_the_moved_estimate_gives_the_stamps_registration():
    """The camera registered from (joints at k, moved estimate) is the one from (joints at the
    stamp, estimate): C T(q_s) inv(T_mean) = C T(q_k) inv(T_mean_k)."""
    from surestep_ocp.ros.estimate import moved

    rng = np.random.default_rng(2)
    for i in range(60):
        mean, then, at_k = (np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 1, 3)] for _ in range(3))
        if i % 3 == 1:  # rotations of pi and near it, and none
            mean[3:] *= (np.pi - 10.0 ** -(i % 9)) / np.linalg.norm(mean[3:])
            at_k[3:] = then[3:] * (0 if i % 2 else 1)
        mk = moved(mean, then, at_k)
        assert np.allclose(_T(then) @ np.linalg.inv(_T(mean)), _T(at_k) @ np.linalg.inv(_T(mk)),
                           atol=1e-12)
        assert np.linalg.norm(mk[3:]) <= np.pi + 1e-12


def test_message_to_mean_and_covariance():
    pytest.importorskip("cyclonedds")
    from surestep_ocp.ros import messages as m
    from surestep_ocp.ros.estimate import from_message, quaternion

    rv = np.array([0.3, -0.2, 1.1])
    q = quaternion(rv)
    cov = np.diag(np.arange(1.0, 7.0))
    msg = m.PoseWithCovarianceStamped(pose=m.PoseWithCovariance(
        pose=m.Pose(m.Point(0.01, 0.02, 0.1), m.Quaternion(*q)), covariance=cov.ravel().tolist()))
    mean, c, ok = from_message(msg)
    assert ok and np.allclose(mean, np.r_[0.01, 0.02, 0.1, rv]) and np.array_equal(c, cov)
    msg.pose.pose.position.x = float("nan")
    assert not from_message(msg)[2]


def test_watchdog():
    wd = Watchdog(FaultLimits(estimate_timeout_s=0.5, tolerance_rad=0.05, tolerance_m=0.005,
                              window_s=0.1, max_failures=3), np.array([False, True]))
    assert not wd.check_silence(1.0, 0.6, 0.9) and wd.reason is None
    for t in np.arange(0, 0.2, 0.005):
        wd.commanded(t, [0.1 * t, 0.0])
    assert not wd.check_tracking(0.2, [0.015, 0.004])  # near a recent set-point
    assert wd.check_tracking(0.2, [0.015, 0.006]) and "joint 1" in wd.reason
    wd.clear()
    assert not wd.replan_failed("x", 0) and not wd.replan_failed("x", 0)
    assert wd.replan_failed("Infeasible", 0) and "3 re-plans in a row" in wd.reason
    wd.clear()
    assert wd.check_silence(2.0, 1.4, 1.9) and wd.reason.startswith("tracker silent")


@pytest.mark.parametrize("name", ["/PSM1/servo_jp", "PSM1/tracker/pose", "/a_b/c1"])
def test_ros2_topic_names(name):
    assert check_topic(name, "--x").startswith("/")


@pytest.mark.parametrize("name", ["", "/", "/a//b", "/a/", "/1a", "/a b", "/a__b", "/a-b", "~/a"])
def test_not_ros2_topic_names(name):
    with pytest.raises(SurestepError, match="--x"):
        check_topic(name, "--x")


def test_domain_ids():
    assert check_domain("0") == 0 and check_domain(232) == 232
    for bad in ("233", "-1", "x", "1.5", ""):
        with pytest.raises(SurestepError, match="--domain-id"):
            check_domain(bad)


def test_the_core_and_the_cli_without_cyclonedds():
    """Without the ros extra: the package and every other command load; serve says what to
    install (exit 2, one line)."""
    import subprocess
    import sys
    from pathlib import Path

    problem = str(Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp.yaml")
    code = ("import sys; sys.modules['cyclonedds'] = None\n"
            "import surestep_ocp\n"
            "from surestep_ocp.cli import main\n"
            "assert main(['validate', sys.argv[1]]) == 0\n"
            "sys.exit(main(['serve', sys.argv[1]]))\n")
    r = subprocess.run([sys.executable, "-c", code, problem], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'surestep_ocp[ros]'" in lines[0]
