"""`surestep serve --continuous` against `surestep sim-robot` over loopback DDS (one process pair,
tests/serve_dds.py): a silent tracker holds, the node resumes once it is back, reaches the goal and
holds it; an unreachable goal on /surestep/goal is refused (one line, status) and the node holds
where it is; a reachable one is planned from the held goal and reached; SIGTERM in the loop ends
it with exit 0. Every message decoded by rosbags; the set-points checked against the limits."""

import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from serve_dds import (assert_servo_process_ended, assert_stretch_within_limits,  # noqa: E402
                       run_pair, set_points, stamps)

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = str(ROOT / "problems" / "needle_regrasp.yaml")
HZ = 200.0
FAR = [0.5, 0.5, 0.3, 0.6, 0.1, 1.4]  # 0.6 m away: out of the arm's reach
NEW = [0.035, -0.010, 0.110, 0.6, 0.1, 1.4]  # README's example goal


def _statuses(rec):
    return [raw for _, raw in rec.samples["/surestep/status"]]


class Script:
    """Goals published as the node's status allows: after a hold and the goal held again, the
    unreachable goal; once refused, the new one; once that is held, done (SIGTERM)."""

    def __init__(self):
        self.stage, self.writer, self.refused_at = 0, None, None

    def publish(self, domain, x):
        from surestep_ocp.ros import messages as m
        from surestep_ocp.ros.dds import Bus
        from surestep_ocp.ros.estimate import quaternion

        if self.writer is None:
            self.writer = Bus(domain).writer("/surestep/goal", m.PoseStamped)
            time.sleep(0.5)  # matched
        q = quaternion(np.array(x[3:]))
        self.writer.write(m.PoseStamped(
            header=m.Header(stamp=m.stamp(time.time_ns()), frame_id="camera"),
            pose=m.Pose(m.Point(*map(float, x[:3])), m.Quaternion(*map(float, q)))))

    def __call__(self, rec, serve, domain) -> bool:
        rec.poll()
        st = _statuses(rec)
        held = [i for i, s in enumerate(st) if b"goal reached; holding" in s]
        hold = [i for i, s in enumerate(st) if b"hold: tracker silent" in s]
        if self.stage == 0 and hold and held and held[-1] > hold[0]:
            self.publish(domain, FAR)
            self.stage = 1
        elif self.stage == 1 and any(b"goal refused" in s for s in st):
            self.refused_at = len(rec.samples["/PSM1/servo_jp"])
            time.sleep(0.3)
            self.publish(domain, NEW)
            self.stage, self.mark = 2, len(st)
        elif self.stage == 2:
            moving = [i for i, s in enumerate(st) if i >= self.mark and b"moving" in s]
            return bool(moving) and any(b"goal reached; holding" in s for s in st[moving[0]:])
        return False


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    script = Script()
    r = run_pair(tmp_path_factory.mktemp("resume"), PROBLEM,
                 ["--continuous", "--estimate-timeout", "0.3"],
                 ["--fault", "tracker-silent@0.6+0.5"], script, timeout_s=300)
    r["script"] = script
    return r


def test_sigterm_in_the_loop_exits_0(run):
    assert run["script"].stage == 2, run["err"][-3000:]
    assert run["code"] == 0, run["err"][-3000:]
    assert "Traceback" not in run["err"] + run["sim_err"]
    lines = run["out"].strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("serve: stopped (SIGTERM)"), lines
    assert_servo_process_ended(run["log"])  # held, flushed, exit 0: no orphan
    status = [s.data for _, s in run["rec"].decoded("/surestep/status", "std_msgs/msg/String")]
    assert status[-1].startswith("stopped")


def test_the_hold_resumes_once_the_tracker_is_back(run):
    log = run["log"]
    (h,) = log["holds"]
    assert h["reason"].startswith("tracker silent")
    assert h["at"] - (h["last_estimate"] + 0.3) < 0.1  # the bound
    assert h["resumed"] is not None and h["first_command"] is not None
    assert h["cleared"] <= h["resumed"] <= h["first_command"]
    assert "serve: resumed: a new motion from rest" in run["err"]
    # nothing sent while holding: no stamp between the hold and the resume
    servo = run["rec"].decoded("/PSM1/servo_jp", "sensor_msgs/msg/JointState")
    t = stamps(servo) - log["t0_wall"]
    assert not np.any((t > h["at"] + 1 / HZ + 1e-6) & (t < h["resumed"] - 1e-3))
    assert np.any(t >= h["resumed"] - 1e-3)
    status = [s.data for _, s in run["rec"].decoded("/surestep/status", "std_msgs/msg/String")]
    i = next(i for i, s in enumerate(status) if s.startswith("hold: tracker silent"))
    assert any(s.startswith("resuming:") for s in status[i:])
    assert any(s.startswith("moving") for s in status[i:])


def test_set_points_on_one_clock_within_the_limits(run):
    """Stamps on the servo clock across restarts; bounds; divided differences within the velocity
    and acceleration limits in each stretch between holds (the restart to the new goal, from the
    held goal at rest, is inside a stretch: no step there). The hold is the gap the node's log
    says; any other gap (the servo process starved on a loaded machine: timing is the
    benchmark's, not this test's) is inside a stretch, whose samples are of one played curve."""
    from surestep_ocp.model.limits import joint_bounds, problem_limits
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    setup = build_setup(load_problem(PROBLEM))
    lim = problem_limits(setup)
    lower, upper = joint_bounds(setup.robot, lim.rcm_min_distance)
    t, q, _, _ = set_points(run["rec"])
    assert np.all(np.diff(t) > 0)
    ticks = (t - t[0]) * HZ
    assert np.abs(ticks - np.round(ticks)).max() < 1e-3
    assert np.all(q >= lower - 1e-6) and np.all(q <= upper + 1e-6)
    (h,) = run["log"]["holds"]
    rel = t - run["log"]["t0_wall"]
    gaps = np.flatnonzero(np.diff(t) > 0.1)
    cut = [c for c in gaps if rel[c] <= h["at"] + 0.1 and rel[c + 1] >= h["resumed"] - 1e-3]
    assert len(cut) == 1, (gaps, rel[gaps], h)  # the hold
    for a, b in ((0, cut[0] + 1), (cut[0] + 1, len(t))):
        assert_stretch_within_limits(lim, t[a:b], q[a:b])


def test_goals_refused_and_reached(run):
    """The unreachable goal: one line, the status; the node held the goal it was at (every
    set-point between the refusal and the next goal the same, at rest). The reachable one: its
    plan from rest at the held goal ends at the new goal by the kinematics; the re-plans after it
    register the camera to the tracker: the tracker's tool ends at the new goal."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    refused = [ln for ln in run["err"].splitlines() if "goal refused" in ln]
    assert len(refused) == 1 and "not reachable" in refused[0], refused
    status = [s.data for _, s in run["rec"].decoded("/surestep/status", "std_msgs/msg/String")]
    assert any(s.startswith("goal refused: ") and "not reachable" in s for s in status)
    goals = run["rec"].decoded("/surestep/goal", "geometry_msgs/msg/PoseStamped")
    assert [round(g.pose.position.x, 6) for _, g in goals] == [FAR[0], NEW[0]]
    servo = run["rec"].decoded("/PSM1/servo_jp", "sensor_msgs/msg/JointState")
    at = run["script"].refused_at
    held = np.array([m.position for _, m in servo[at - 5:at + 20]])
    vel = np.array([m.velocity for _, m in servo[at - 5:at + 20]])
    assert np.ptp(held, axis=0).max() == 0 and not vel.any()
    plans = [p for _, p in run["rec"].decoded("/surestep/plan",
                                              "trajectory_msgs/msg/JointTrajectory")]
    assert np.allclose(servo[-1][1].position, plans[-1].points[-1].positions[:6], atol=1e-9)
    restart = [p for p in plans if np.allclose(p.points[0].positions[:6], held[0], atol=1e-12)
               and not np.any(p.points[0].velocities)]
    # the first from rest at the goal it held before (a re-plan from the new waypoint 0, also at
    # rest there, may follow: registered to the tracker)
    assert restart
    setup = build_setup(load_problem(PROBLEM))
    x = setup.pose_of(np.array(restart[0].points[-1].positions))
    assert np.abs(x[:3] - NEW[:3]).max() < 1e-6
    # the tracker's last estimate (the sim's tool, its drift included) at the new goal
    est = run["rec"].decoded("/PSM1/tracker/pose", "geometry_msgs/msg/PoseWithCovarianceStamped")
    p = est[-1][1].pose.pose.position
    assert np.linalg.norm(np.array([p.x, p.y, p.z]) - NEW[:3]) < 0.002
