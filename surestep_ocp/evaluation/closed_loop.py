"""Belief-space MPC in the rollouts (`ocp-mpc`): every rollout re-plans at every tracker frame from
its own EKF belief, within the motion limits, from the robot's moving state.

`ClosedLoop` is `rollout.rollout`'s `policy`. Each rollout has its own copy of one `Planner` (the
copies share its solvers, built once). At step t each copy re-plans from the executed curve's state
with the camera registered to that rollout's EKF mean (`Planner.replan`, docs/realtime.md); the
robot then runs the current plan's step t -> t+1, which the rollout applies from the estimate (the
planned displacement and body-frame rotation). A re-plan that fails keeps the rollout on its
previous plan, which it runs on (counted in `failures`). The executed motion of each rollout (every
plan from its start until the next one's) is checked against the limits independently
(`executed_motion.violations`) when the rollout reaches its goal.

The rollouts of one plan run at the robot's pace: `robot_pace` turns a problem at the paper's pace
into one the limits allow (twice the steps of the same length, the camera moves at the same times,
the limits enforced).
"""

from __future__ import annotations

import copy
import gc

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import SurestepError
from ..model.lie import matrix_to_pose, pose_to_matrix
from ..problem.spec import Problem
from ..ocp.certificate import NOT_CERTIFIED
from ..methods.registry import closed_loop_unavailable
from ..methods.confidence import at_horizon
from ..methods.planner import MAX_LATE, Planner, without_confidence
from ..methods.registration import GATE
from .executed_motion import stitched, violations


def robot_pace(problem: Problem, factor: int = 2) -> Problem:
    """The problem with `factor` times the steps (of the same length), its camera moves at the same
    fraction of the motion, and the motion limits enforced."""
    tree = problem.source if isinstance(problem.source, dict) else {}
    camera = dict(tree.get("camera", {}))
    if camera.get("moves"):
        camera["moves"] = [{**m, "step": int(m["step"]) * factor} for m in camera["moves"]]
    limits = {**tree.get("limits", {}), "enforce": True}
    return problem.with_sections(horizon=problem.horizon * factor, camera=camera, limits=limits)


class ClosedLoop:
    """`rollout`'s policy: per rollout, a re-plan at every step from its own belief (module
    docstring).

    Args:
        setup: the problem within enforced limits (`robot_pace`), solved by the interior point
            (`solver.name` auto or interior); its camera schedule, if any, is the rollouts'; with
            `goal.confidence`, over the Planner's horizon (the shortest that reaches it).
        planner: a Planner of `setup` (default: made here; its first plan is every rollout's).
        keep_pieces: keep each rollout's executed pieces (start step, joints, start state) in
            `pieces` after its check (by default freed).
        deadline_s: a re-plan that takes longer than this [s] (builds apart) is late: the rollout
            keeps its previous plan, as a real-time loop would. None (the default): no re-plan is
            discarded for its time, so the rollouts do not depend on the machine's speed; the late
            ones (longer than a step, `timing.step_s`) are counted all the same (`late_replans`).

    After a rollout call: `times` (each re-plan's time without builds [s], its preparation between
    frames included), `feedback` (the real-time iterations' feedback times [s]), `failures` ((step,
    rollout, status) of each re-plan that kept the previous plan; `Not_Certified`: a plan its
    certificate found infeasible, docs/certificate.md), `held` ((step, rollout) of each
    re-plan that kept the previous camera registration), `constrained` ((step, rollout, squared
    Mahalanobis distance) of each that registered the nearest estimate within reach), `late`
    (steps each rollout's goal moved later), `violations` (executed samples beyond a limit, per
    rollout).
    """

    def __init__(self, setup, planner: Planner | None = None, keep_pieces: bool = False,
                 deadline_s: float | None = None):
        why = closed_loop_unavailable(setup)
        if why:
            raise SurestepError(why)
        self.planner = Planner(setup) if planner is None else planner
        if not self.planner.plan.success:
            raise SurestepError(f"ocp-mpc: the first plan failed ({self.planner.plan.status})")
        if self.planner.horizon != setup.ocp.horizon:  # planned to `goal.confidence`
            setup = at_horizon(without_confidence(setup), self.planner.horizon)
        self.setup = setup
        self.dt = setup.ocp.timing.step_s
        self.cameras = setup.camera_poses()
        self.steps = setup.ocp.horizon + MAX_LATE
        self.keep_pieces, self.deadline_s = keep_pieces, deadline_s
        self.reset()

    @property
    def first_plan(self):
        """The plan every rollout starts with (a Solution, first camera frame)."""
        return self.planner.plan

    def start_and_goal(self) -> tuple[np.ndarray, np.ndarray]:
        """(start pose in the first camera frame, goal in the last camera frame), (6,) each."""
        poses = self.setup.in_step_frames(np.asarray(self.first_plan.poses, float))
        return poses[0], poses[-1]

    def reset(self) -> None:
        """Start over: the next rollout call's rollouts begin with the first plan."""
        self.planners: list[Planner] | None = None
        self.pieces: list[list] = []
        self.checked: list[bool] = []
        self.times: list[float] = []
        self.feedback: list[float] = []  # real-time iterations' feedback times [s]
        self.failures: list[tuple[int, int, str]] = []
        # (step, rollout) of the re-plans that held the registration
        self.held: list[tuple[int, int]] = []
        # (step, rollout, squared Mahalanobis distance) of those that registered the nearest
        # estimate reaching the goal (methods/registration.py)
        self.constrained: list[tuple[int, int, float]] = []
        self.late: list[int] = []
        self.violations: list[int] = []

    def __call__(self, t: int, mean: np.ndarray, cov: np.ndarray):
        # the cyclic collector runs between frames, not inside a re-plan: the rollouts' planners,
        # plans and pieces make a heap whose full collection takes 30-50 ms (Type 1 easy, 20
        # rollouts), which a re-plan would otherwise be timed with (one robot's loop has no such
        # heap)
        gc.disable()
        try:
            return self._frame(t, mean, cov)
        finally:
            gc.enable()
            gc.collect()

    def _frame(self, t: int, mean: np.ndarray, cov: np.ndarray):
        """Every rollout's re-plan at step t (`__call__`)."""
        n = len(mean)
        if self.planners is None:
            self.planners = [copy.copy(self.planner) for _ in range(n)]
            self.pieces = [[(0, np.array(self.planner.plan.q, float), None)] for _ in range(n)]
            self._prepared_s = [0.0] * n  # each rollout's last preparation [s]
            self.late, self.violations, self.checked = [0] * n, [0] * n, [False] * n
        # a rollout at its goal holds still: its target is where it is (finite, not used)
        targets, moving = np.array(mean, float), np.zeros(n, bool)
        self.arriving = np.zeros(n, bool)  # whose step t -> t+1 ends its plan (`rollout` reads it)
        camera = self._camera(t)
        for i, planner in enumerate(self.planners):
            if t >= planner.horizon:
                if t == planner.horizon:  # at its goal: check what it executed
                    self._finish(i, planner)
                continue
            if t > 0:
                planner = self._replan(i, planner, t, mean[i], cov[i], camera)
            targets[i] = self._target(planner, t, mean[i])
            if t + 1 < planner.horizon:
                # between frames: the next re-plan's real-time iteration (its time in `times`)
                self._prepared_s[i] = planner.prepare(t + 1)
            moving[i] = True
            self.arriving[i] = t + 1 == planner.horizon
        return targets, moving

    def _replan(self, i: int, planner: Planner, t: int, mean, cov, camera) -> Planner:
        """Rollout i's re-plan at step t on a copy of its Planner; the copy if it is kept, else the
        Planner as it was (its previous plan runs on)."""
        trial = copy.copy(planner)
        try:
            sol = trial.replan(mean, cov, camera_pose=camera, step=t)
        except SurestepError as exc:  # e.g. an estimate the checks reject
            self.failures.append((t, i, str(exc)))
            return planner
        took = sol.replan.time_s
        # the frame's work: the call, and its preparation between frames
        self.times.append(took + (self._prepared_s[i] if sol.replan.prepared_ahead else 0.0))
        if sol.replan.feedback_s is not None:
            self.feedback.append(sol.replan.feedback_s)
        if not sol.success:
            self.failures.append((t, i, sol.status))
            return planner
        if self.deadline_s is not None and took > self.deadline_s:  # too late to run
            self.failures.append((t, i, f"late ({took * 1e3:.1f} ms)"))
            return planner
        if sol.replan is not None and sol.replan.registration_held:
            self.held.append((t, i))
        if sol.replan is not None and sol.replan.registration_constrained is not None:
            self.constrained.append((t, i, sol.replan.registration_constrained))
        st = sol.run.start_state
        self.pieces[i].append((t, np.array(sol.q, float),
                               (np.array(st.velocity), np.array(st.acceleration))))
        self.planners[i] = trial
        return trial

    def _target(self, planner: Planner, t: int, mean: np.ndarray) -> np.ndarray:
        """The current plan's step t -> t+1 applied from the estimate: its displacement (turned by
        the camera's moves since the plan was made) and its body-frame rotation; the plan's last
        step goes onto its goal (seen from the current camera)."""
        poses = np.asarray(planner.plan.poses, float)
        j = t - planner.step
        # the camera a plan was made in: the first camera for the first plan
        made_in = self.cameras[0] if planner.step == 0 else self._camera(planner.step)
        move = np.linalg.inv(self._camera(t)) @ made_in
        if j + 2 == len(poses):
            return matrix_to_pose(move @ pose_to_matrix(poses[-1]))
        turn = move[:3, :3]
        R0, R1 = Rotation.from_rotvec(poses[j, 3:]), Rotation.from_rotvec(poses[j + 1, 3:])
        R = Rotation.from_rotvec(mean[3:]) * R0.inv() * R1
        return np.hstack([mean[:3] + turn @ (poses[j + 1, :3] - poses[j, :3]), R.as_rotvec()])

    def _camera(self, t: int) -> np.ndarray:
        """The camera whose frame the rollout's poses are in when the policy is called at step t:
        a move at entry t of the schedule's changes has happened (the camera of waypoint t + 1)."""
        return self.cameras[min(t + 1, len(self.cameras) - 1)]

    def _finish(self, i: int, planner: Planner) -> None:
        self.late[i] = planner.horizon - self.setup.ocp.horizon
        self.violations[i] = violations(planner.setup, stitched(self.pieces[i], self.dt))
        self.checked[i] = True
        if not self.keep_pieces:
            self.pieces[i] = []

    def finish(self) -> None:
        """Check the rollouts that had not reached their goal when the rollout call ended (none
        when it ran `steps` steps)."""
        for i, planner in enumerate(self.planners or []):
            if not self.checked[i]:
                self._finish(i, planner)

    def summary(self) -> dict:
        """Re-plans (count, failures, those not certified, those longer than a step, median, p90
        and worst time [ms], every time), the steps the goal moved later (median, worst) and the
        executed samples beyond a limit, over the last rollout call."""
        self.finish()
        ms = np.asarray(self.times) * 1e3
        return {"replans": len(ms), "failed": len(self.failures),
                "not_certified": sum(why == NOT_CERTIFIED for _, _, why in self.failures),
                "held": len(self.held),
                "constrained": len(self.constrained),
                "constrained_d2_max": max((d for _, _, d in self.constrained), default=None),
                # of them, estimates the belief rules out (beyond the chi-square 99 % gate)
                "constrained_beyond_gate": sum(d > GATE for _, _, d in self.constrained),
                "rollouts_failed": sorted({i for _, i, _ in self.failures}),
                "rollouts_held": sorted({i for _, i in self.held}),
                "late_replans": int(np.sum(ms > self.dt * 1e3)),
                "median_ms": float(np.median(ms)) if len(ms) else None,
                "p90_ms": float(np.percentile(ms, 90)) if len(ms) else None,
                "worst_ms": float(ms.max()) if len(ms) else None,
                "late_median": float(np.median(self.late)) if self.late else 0.0,
                "late_worst": int(max(self.late)) if self.late else 0,
                "violations": int(sum(self.violations)), "build_s": self.planner.build_time_s,
                "failures": self.failures[:5], "times_ms": ms.tolist(),
                "feedback_ms": (np.asarray(self.feedback) * 1e3).tolist()}
