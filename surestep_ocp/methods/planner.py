"""A re-planning handle for a tracker loop: the OCP's solvers built once, each plan warm-started
from the last.

At every tracker frame the tool's estimate (mean pose and 6x6 covariance, camera frame) and the
camera pose come in, and the rest of the motion to the same goal is planned again over the steps
left: the horizon shrinks by one step per waypoint reached, so the goal is reached at the planned
time.

The horizon shrinks without building an NLP per re-plan: one projected Newton solver per number of
steps left, built once (all of them when the Planner is made, by default) and kept. A single NLP of
fixed T with the executed steps pinned or padded was not used: a padded step still observes the
tool, which changes Tr(Sigma_T), so its plan would not be the one a cold solve of the remaining
problem finds. A plan is evaluated by one compiled call (the EKF over the steps left) instead of a
CasADi call per step.

Where the projected Newton solver does not apply (IPOPT's models, enforced motion limits, 6x6
recursions) or does not converge, a re-plan runs `solve_ocp_warm`'s whole strategy from the previous
plan instead (its NLPs are cached per horizon too, but built inside the solve). Here: the public
API, the first plans and the full re-plans within the limits; apart: the checks of its inputs
(replan_inputs.py), its solvers (replan_solvers.py), the real-time iteration's feedback
(real_time_iteration.py), re-plans without limits (replan_without_limits.py).
"""

from __future__ import annotations

import gc
import time
from dataclasses import replace

import numpy as np

from ..arguments import whole_number
from ..errors import SurestepError
from ..model.limits import enforce as enforce_limits
from ..model.limits import evaluate_curve
from ..ocp.certificate import NOT_CERTIFIED, certify
from .confidence import at_horizon, plan_to_confidence
from ..ocp.iterate import InitialGuess
from ..model.robot import CAMERA_PARAMETERS
from ..solvers.backends import Backend, Context, ReplanOptions
from ..solvers.strategy import first_backend, replan_backend, replan_strategy
from .ocp import ocp_initial_guess, resolved_solver, solve_ocp_warm
from ..problem.spec import Problem
from ..problem.setup import Setup, build_setup
from ..output.certificate import INFEASIBLE
from ..output.solution import Solution
from ..output.solution_records import ReplanAttempt, ReplanRecord
from .real_time_iteration import Prepared, RealTimeIteration
from .registration import register
from .replan_inputs import (checked_camera_pose, checked_estimate, checked_goal,
                            checked_rest_joints, whole_step)
from .replan_solvers import CERTIFIED_SETUP as _SETUP
from .replan_solvers import replan_solution
from .replan_without_limits import remaining_problem, replan_without_limits
from ..status import Status

# a re-plan's first barrier parameter: its few iterations end well inside the rows, which leaves the
# next frame's correction room (measured against 1e-4 and others: docs/realtime.md)
REPLAN_MU = 3e-3
# within the limits: a re-plan's iteration budget (its last iterate, within every limit, is the
# plan: the next frame improves it) and the objective change (relative, over 3 iterations) at which
# it stops early
REPLAN_ITERATIONS, REPLAN_ACCEPTABLE = 4, 1e-7
# a real-time iteration's preparation: its iterations (relaxed ones apart, as REPLAN_BUDGET counts)
RTI_ITERATIONS = 1
# within the limits: the iterations (relaxed ones included) of all a re-plan's attempts together;
# past them it fails and the previous plan runs on, so a frame's work is bounded (a correction that
# does not fit ran four attempts of up to 34 iterations each, then failed all the same); the value
# trades the worst re-plan against the closed loop's grasps (docs/realtime.md)
REPLAN_BUDGET = 40
# re-plans keep this fraction of the velocity, acceleration and tool-speed limits for corrections
RESERVE = 0.02
EXTEND = 2  # steps a re-plan may add when the correction does not fit in the time left
# ... and the goal at most this many steps later in all (past it, the previous plan is kept)
MAX_LATE = 10
# a re-plan's (reserve, steps added), in order
ATTEMPTS = ((RESERVE, 0), (0.0, 0), (RESERVE, EXTEND), (0.0, 2 * EXTEND))


class Planner(RealTimeIteration):
    """Plans a problem once, then re-plans from each new tracker estimate over the steps left.

    With `goal.confidence` set, the horizon is the shortest whose plan reaches it, but not shorter
    than the problem's own (`grasp` holds that plan's grasp record, else None); a closed loop then
    dwells at the goal until its own belief is sure (evaluation/grasp_rule.py). A re-plan at the
    shortest horizon runs at the edge of what the limits allow and often fails where the estimate
    moved (Type 1 hard at the robot's pace: 26 steps, 42 % of re-plans failed, 15 % grasps in 20
    rollouts; 40 steps: 2 %, 65 %; docs/grasp_confidence.md).

    Args:
        problem: a Problem (or a built Setup); its camera moves, if any, are ignored (give the
            camera pose to `replan`).
        prebuild: build the solvers of every remaining horizon now: the first one compiled now, the
            others' C compiled in a background thread while the loop runs, each loaded when first
            needed (else each built when first needed); their build times, waits included, are in
            `builds`, never in a plan's time (the IPOPT path builds its NLPs inside the solve).
        replan_iterations: within enforced limits, a full re-plan's iteration budget: its last
            iterate keeps every limit and reaches the goal (status `Feasible_Point_Found` when it
            is not yet optimal), and the next frame's re-plan continues from it.
        rti: within enforced limits, re-plan by real-time iterations (`prepare`, then the
            feedback in `replan`; a full re-plan where the prepared iterate does not fit the
            measurement); False: every re-plan a full one.
    """

    def __init__(self, problem: Problem | Setup, prebuild: bool = True,
                 replan_iterations: int = REPLAN_ITERATIONS, rti: bool = True):
        replan_iterations = whole_number(replan_iterations, "Planner: replan_iterations")
        if not isinstance(rti, (bool, np.bool_)):
            raise SurestepError(f"Planner: rti must be True or False, got {rti!r}")
        self.rti = bool(rti)
        setup = problem if isinstance(problem, Setup) else build_setup(problem)
        # the problem as asked (its confidence, its own horizon): `restart` plans it again
        self._asked = setup
        setup, self.grasp = _horizon_for(setup)
        # planned for a fixed camera (`replan` takes its pose): without the schedule, the plans
        # stay in one camera frame and their solutions record no camera moves
        self.setup = replace(setup, camera_schedule=[])
        self.horizon = setup.ocp.horizon
        self.replan_iterations = replan_iterations
        # steps left -> seconds spent building its solver and evaluator
        self.builds: dict[int, float] = {}
        # steps left -> its solvers (minus the steps left: the interior-point one within limits)
        self._solvers: dict[int, tuple] = {}
        ctx = Context(self.setup, resolved_solver(self.setup), "ocp-replan", {})
        # without limits: the first backend's re-plan attempts (projected Newton's) where it takes
        # them, its solvers built ahead
        self._first = first_backend(ctx)
        self.fast = (bool(replan_strategy(ctx, moved=False)) and not setup.ocp.limits.enforce
                     and self.setup.model.scalar)
        # within enforced limits, the backend declaring re-plans from a moving start, where it
        # applies (`solver.name` auto or its own): it re-plans from the executed curve's state
        # (docs/realtime.md); else a re-plan runs the whole strategy
        self._backend: Backend | None = replan_backend(ctx)
        self.limited = self._backend is not None
        for n in (range(self.horizon, 0, -1) if prebuild else [self.horizon]) if self.fast else ():
            self._solver(n, background=n != self.horizon)  # timed apart from the solves
        # every re-plan's structure
        for n in range(self.horizon, 0, -1) if self.limited and prebuild else ():
            self._interior(self.setup.with_ocp(horizon=n))
        self._camera = (self.setup.camera_pose.tobytes(), self.setup)
        self._begin(first_plan(self.setup))
        # what is built so far (solvers, compiled functions, the first plan) leaves the cyclic
        # collector's generations: a full collection within a re-plan would scan it all (24 ms in
        # a 20 Hz loop, docs/realtime.md); reference counting still frees it
        gc.collect()
        gc.freeze()

    def _begin(self, plan: Solution) -> None:
        """`plan` (from rest, waypoint 0) as the current plan of a new motion."""
        self.plan = plan
        self.step = 0  # the waypoint the current plan starts at
        self._q = np.array(plan.q, float)
        # the current plan's curve starts at rest, or in motion: (velocity, acceleration)
        self._start = None
        # within the limits: the current plan's camera registration, as a correction of the given
        # camera pose (the first plan's: none)
        self._registration = np.eye(4)
        # within the limits: the real-time iteration prepared for the next re-plan (`prepare`),
        # and the last estimate's covariance (the prediction a preparation plans with)
        self._prepared: Prepared | None = None
        self._cov = self.setup.ocp.sigma0

    def restart(self, joints, goal=None) -> Solution:
        """A new motion from rest at `joints` (the arm held still: after a fault cleared, or for a
        new goal), planned as the first plan was, from waypoint 0, in the camera as last given,
        with no registration yet (the next `replan` registers).

        Args:
            joints: the arm's joints at rest [rad, m], within their bounds.
            goal: a new goal pose `[px, py, pz, rx, ry, rz]` in the camera frame (position [m],
                axis-angle [rad]); default: the same goal joints.

        Returns:
            The new plan (also `plan`); with `goal.confidence` its horizon is searched again (the
            solvers already built are kept). A plan that fails raises (the old motion is over
            either way): SurestepError carrying its status, the Planner unchanged.
        """
        base = self._camera[1]
        q = checked_rest_joints(joints, base)
        asked = replace(self._asked, camera_pose=base.camera_pose, q_start=q)
        if goal is not None:
            x = checked_goal(goal, base)
            q_goal, res_m, res_rad = asked.joints_for(x, base.q_goal, raise_on_fail=False)
            if res_m > 1e-6 or res_rad > 1e-5:
                raise SurestepError(f"restart: goal {np.round(x, 4).tolist()} is not reachable "
                                    f"within the joint bounds (IK residual {res_m * 1e3:.3f} mm, "
                                    f"{res_rad:.4f} rad)")
            asked = replace(asked, q_goal=q_goal)
        asked.x_start, asked.x_goal = asked.pose_of(asked.q_start), asked.pose_of(asked.q_goal)
        setup, grasp = _horizon_for(asked)
        setup = replace(setup, camera_schedule=[])
        plan = first_plan(setup)
        if not plan.success:
            raise SurestepError(f"restart: no plan from the joints given ({plan.status})")
        self._asked, self.setup, self.horizon, self.grasp = asked, setup, setup.ocp.horizon, grasp
        self._camera = (setup.camera_pose.tobytes(), setup)
        self._begin(plan)
        return plan

    def replan(self, mean, covariance, camera_pose=None, step: int | None = None) -> Solution:
        """The plan from the tracker's estimate to the goal over the steps left.

        Args:
            mean: (6,) the tool's estimated pose `[px, py, pz, rx, ry, rz]` (position [m],
                axis-angle [rad]) in the camera frame.
            covariance: (6, 6) its covariance [m^2, m rad, rad^2], the plan's Sigma_0.
            camera_pose: (4, 4) camera in world [m] (default: as in the last call). The goal stays
                where it is in the world (its joints are kept).
            step: the waypoint index the tool is at now (default: one more than the last plan's
                start); the plan has `horizon - step` steps.

        Returns:
            A Solution starting at waypoint `step` (its `horizon` is the steps left);
            `replan` (a ReplanRecord) has the time of the whole call without builds (`time_s`) and
            the solver that made it. A successful one becomes `plan` (and `step`); after a failure
            (check `success`) the previous plan stays current.
        """
        t0, builds_before = time.perf_counter(), self.build_time_s
        step = self.step + 1 if step is None else whole_step(step)
        self._check_step(step)
        mean, cov = checked_estimate(mean, covariance, self.setup.ocp.min_depth)
        camera = self._camera
        base, moved = self._seen_from(camera_pose)
        try:
            return self._replan(mean, cov, base, moved, step, t0, builds_before)
        except BaseException:
            # a rejected call changes nothing: the camera of the last plan stays
            self._camera = camera
            raise

    def _replan(self, mean, cov, base: Setup, moved: bool, step: int, t0: float,
                builds_before: float) -> Solution:
        """`replan` with checked inputs (its docstring)."""
        if self.limited:
            return self._replan_within_limits(mean, cov, base, step, t0, builds_before)
        n = self.horizon - step
        sub, warm = remaining_problem(base, mean, cov, self._q[step - self.step:], n)
        built = self._solver(n) if self.fast and sub.model.scalar else None
        sol, certificate_s = _certified(sub, replan_without_limits(sub, warm, cov, moved, built))
        built_s = sum(self.builds.values()) - builds_before
        record = ReplanRecord(step, time.perf_counter() - t0 - built_s, sol.run.solver, built_s,
                              certificate_s=certificate_s)
        sol = sol.replaced(replan=record)
        if sol.success:  # else the previous plan stays current
            self.plan, self.step, self._q = sol, step, np.array(sol.q, float)
        return sol

    def executed_state(self, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(joints, velocities, accelerations) of the curve being executed (the current plan's,
        played at its pace) at waypoint `step`."""
        dt = self.setup.ocp.timing.step_s
        p, v, a = evaluate_curve(self._q, dt, np.array([(step - self.step) * dt]),
                                 start=self._start)
        return p[0], v[0], a[0]

    def prepare(self, step: int | None = None) -> float:
        """The real-time iteration's preparation of the re-plan at waypoint `step` (default: the
        next one), done before the tracker's estimate arrives (acados' RTI preparation phase):
        one interior-point iteration from the current plan shifted to the executed curve's state
        there, with the current camera registration and the last estimate's covariance (the
        predicted measurement). `replan` at that step then only registers the estimate, shifts
        the prepared plan's goal to it and checks every row (the feedback phase), or re-plans in
        full where that fails (said in `replan.rti`). Returns its seconds (builds apart); 0.0
        where re-plans are not real-time iterations (no enforced limits, or `rti=False`)."""
        if not (self.limited and self.rti):
            return 0.0
        step = self.step + 1 if step is None else whole_step(step)
        self._check_step(step)
        self._prepared = self._prepare(step, self._camera)
        return self._prepared.time_s

    def _check_step(self, step: int) -> None:
        if not self.step <= step < self.horizon:
            raise SurestepError(f"replan: step {step} is not in [{self.step}, {self.horizon - 1}] "
                                f"(the current plan starts at waypoint {self.step}; "
                                f"the goal is waypoint {self.horizon})")

    def _prepare(self, step: int, camera: tuple) -> Prepared:
        """`prepare` for waypoint `step` as seen from `camera` (bytes, setup)."""
        t0, builds_before = time.perf_counter(), self.build_time_s
        base = camera[1]
        q0, v0, a0 = self.executed_state(step)
        registered = replace(base, camera_pose=base.camera_pose @ self._registration)
        q = np.array(self._q[step - self.step:], float)
        q[0] = q0
        sub = replace(registered.with_ocp(horizon=len(q) - 1, sigma0=self._cov), q_start=q0,
                      q_goal=q[-1])
        sub.x_start, sub.x_goal = sub.poses_of(q[[0, -1]])
        warm = InitialGuess(q, "previous plan (real-time iteration)")
        spec = self.setup.ocp.solver
        solver = self._interior(sub)[0]
        run = solver.replan(sub, warm, ReplanOptions(
            v0, a0, spec.tol, REPLAN_MU, min(RTI_ITERATIONS, spec.max_iter), RESERVE,
            acceptable_change=REPLAN_ACCEPTABLE, relaxed_max=REPLAN_BUDGET))
        P = solver.parameters(sub)
        P[CAMERA_PARAMETERS] = run.initial_trace
        built = self.build_time_s - builds_before
        return Prepared(self.plan, step, camera[0], q0, v0, a0, warm, run, solver, P,
                        time.perf_counter() - t0 - built, RESERVE)

    def _replan_within_limits(self, mean, cov, base: Setup, step: int, t0: float,
                              builds_before: float) -> Solution:
        """A re-plan within the enforced limits: from the executed curve's state at `step` (joints,
        velocity, acceleration: the commanded motion stays twice continuously differentiable), with
        the camera registered to the tracker (the kinematics at those joints see the tool at the
        tracker's mean), to the goal where the camera sees it. Where that registration puts the
        goal out of reach (the tracker's IK residual in `extras["goal_ik_residual"]`), the nearest
        estimate its belief allows that reaches it is registered instead
        (`replan.registration_constrained`), else the current plan's registration holds
        (`replan.registration_held`; methods/registration.py). With `rti`, the prepared iterate
        with its goal moved (`_feedback`), else (or where that breaks a row) the interior-point
        method from the previous plan (`_full`). A failure keeps the previous plan
        (`replan.kept_previous`)."""
        prep, self._prepared = self._prepared, None
        ahead = (prep is not None and prep.plan is self.plan and prep.step == step
                 and prep.camera == self._camera[0])
        if self.rti and not ahead:
            prep = self._prepare(step, self._camera)
        # the feedback phase's clock: from the call, its preparation apart when made in it
        t_feedback = t0 + (0.0 if ahead or prep is None else
                           prep.time_s + self.build_time_s - builds_before)
        q0 = self.executed_state(step)[0] if prep is None else prep.q0
        reg = register(base, q0, mean, cov, self._registration, self._q[-1])
        registered, q_goal, reachable = reg.setup, reg.q_goal, reg.reachable
        sol, rti, start = None, None, None
        if self.rti:
            if reachable and prep.run.success:
                sol, start = self._feedback(prep, registered, q_goal, cov, t_feedback)
                rti = "feedback" if sol is not None else "full: a row broken"
            else:
                rti = "full: " + ("goal unreachable" if not reachable
                                  else f"preparation {prep.run.status}")
        if sol is None:
            sol = self._full(cov, registered, q_goal, reachable, step, start)
            if not reachable:  # no plan tried (the goal's IK residual is in the log)
                sol = sol.replaced(success=False, status=Status.GOAL_UNREACHABLE,
                                   extras={**sol.extras, "goal_ik_residual": reg.unreached})
        if reg.unreached is not None and reachable:
            sol = sol.replaced(extras={**sol.extras, "goal_ik_residual": reg.unreached})
        # what the re-plan's record takes out of the extras
        extras = dict(sol.extras)
        sub, feedback_s = extras.pop(_SETUP), extras.pop("feedback_s", None)
        tried = extras.pop("attempts_tried", None)
        # the certificate (docs/certificate.md): a plan it finds infeasible is not run
        sol, certificate_s = _certified(sub, sol.replaced(extras=extras))
        verdict, built_s = time.perf_counter(), self.build_time_s - builds_before
        sol = sol.replaced(replan=ReplanRecord(
            step, time.perf_counter() - t0 - built_s, "interior", built_s, not sol.success,
            tried, registration_held=reg.held and reachable,
            registration_constrained=reg.constrained, rti=rti,
            feedback_s=feedback_s, prepare_s=None if prep is None else prep.time_s,
            prepared_ahead=None if prep is None else ahead, certificate_s=certificate_s,
            verdict_s=None if feedback_s is None else verdict - t_feedback))
        if sol.success:
            self.plan, self.step, self._q = sol, step, np.array(sol.q, float)
            self._start = tuple(np.array(v, float) for v in (sol.run.start_state.velocity,
                                                              sol.run.start_state.acceleration))
            self.horizon += sol.extras["extended_steps"]
            # the camera's correction from its given pose, held when a later estimate is unusable
            self._registration = np.linalg.solve(base.camera_pose, registered.camera_pose)
            self._cov = cov
        return sol

    def _full(self, cov, registered: Setup, q_goal: np.ndarray, reachable: bool,
              step: int, start: np.ndarray | None = None) -> Solution:
        """A full re-plan: the interior-point method from `start` (the real-time iteration's
        moved iterate, when one broke a row), else from the previous plan with its goal shifted
        to `q_goal`, within the limits less RESERVE, else the limits themselves, else EXTEND
        steps later (`ATTEMPTS`), within REPLAN_BUDGET iterations in all; no iteration where the
        goal is not `reachable`."""
        q0, v0, a0 = self.executed_state(step)
        n = self.horizon - step
        if start is None:
            tail = np.array(self._q[step - self.step:], float)
            # the goal's shift, eased in and out (no velocity or acceleration added at either end)
            s = np.linspace(0.0, 1.0, n + 1)
            tail += (10 * s**3 - 15 * s**4 + 6 * s**5)[:, None] * (q_goal - tail[-1])[None]
            tail[0] = q0
        else:
            tail = start
        spec = self.setup.ocp.solver
        # within the limits less RESERVE (room for the next corrections), else within the limits
        # themselves, else (the correction too large for the time left) EXTEND steps later; from the
        # previous plan with the rows it breaks relaxed (the goal's shift, the active rows it sits
        # on)
        tried = []  # (reserve, steps added, status, iterations, relaxed iterations) of each attempt
        late = self.horizon - self.setup.ocp.horizon  # steps the goal has moved later so far
        attempts = ([a for a in ATTEMPTS
                     if not a[1] or late + a[1] <= MAX_LATE]
                    if reachable else ATTEMPTS[:1])
        budget = REPLAN_BUDGET
        for reserve, extra in attempts:
            if budget <= 0:
                break
            sub = replace(registered.with_ocp(horizon=n + extra, sigma0=cov), q_start=q0,
                          q_goal=q_goal)
            sub.x_start, sub.x_goal = sub.poses_of(np.vstack([q0, q_goal]))
            warm = InitialGuess(np.vstack([tail, np.repeat(tail[-1:], extra, axis=0)]),
                                "previous plan"
                                + (f", {extra} steps at the goal added" if extra else ""))
            solver, propagation = self._interior(sub)
            run = solver.replan(sub, warm, ReplanOptions(
                v0=v0, a0=a0, tol=spec.tol, mu0=REPLAN_MU, reserve=reserve,
                max_iter=(min(self.replan_iterations, spec.max_iter, budget) if reachable else 0),
                acceptable_change=REPLAN_ACCEPTABLE, relaxed_max=budget))
            budget -= run.iterations
            tried.append(ReplanAttempt(reserve=reserve, steps_added=extra, status=run.status,
                                       iterations=run.iterations,
                                       relaxed_iterations=run.relaxed_iterations))
            if run.success:
                break
        sol = replan_solution(sub, propagation, solver, warm, run, cov, v0, a0)
        return sol.replaced(extras={**sol.extras, "reserve": reserve, "extended_steps": extra,
                                    "attempts_tried": tried})

    def _seen_from(self, camera_pose) -> tuple[Setup, bool]:
        """The setup seen from `camera_pose` (None: the last one), and whether the camera moved
        since the last plan."""
        moved = False
        if camera_pose is not None:
            C = checked_camera_pose(camera_pose)
            if C.tobytes() != self._camera[0]:
                self._camera, moved = (C.tobytes(), self.setup.seen_from(C)), True
        return self._camera[1], moved


def _certified(sub: Setup, sol: Solution) -> tuple[Solution, float]:
    """The re-plan `sol` of `sub` certified (ocp/certificate.py: from the problem's functions, not
    the solver's rows) with the re-plan's meaning of success: a plan the robot can run, so one the
    certificate finds infeasible (or cannot certify) is `Not_Certified`, not run (the previous plan
    stays current; the solver's words in `backend_status`, `backend_success`); and its seconds."""
    t0 = time.perf_counter()
    cert = certify(sub, sol, padded=True)
    verdict = dict(backend_status=sol.status, backend_success=sol.success, certificate=cert)
    if sol.success and (cert is None or cert.level == INFEASIBLE):
        verdict.update(success=False, status=NOT_CERTIFIED)
    return sol.replaced(**verdict), time.perf_counter() - t0


def _horizon_for(setup: Setup) -> tuple[Setup, dict | None]:
    """(`setup` over a Planner's horizon, the grasp record): with `goal.confidence`, the shortest
    horizon whose plan reaches it (methods/confidence.py) but not below the problem's own, and
    that plan's record; else the problem's horizon and None."""
    if setup.ocp.grasp.confidence is None:
        return setup, None
    chosen = plan_to_confidence(setup, first_plan)
    return (at_horizon(without_confidence(setup), max(chosen.horizon, setup.ocp.horizon)),
            chosen.extras["grasp"])


def without_confidence(setup: Setup) -> Setup:
    """The setup planning its horizon as given (no `goal.confidence`)."""
    return setup.with_ocp(grasp=replace(setup.ocp.grasp, confidence=None))


def first_plan(setup: Setup) -> Solution:
    """A Planner's first plan of `setup` (its horizon as given): the OCP from the straight line,
    within enforced limits again within the limits less RESERVE (`within_reserve`)."""
    setup = without_confidence(setup)
    plan, _ = solve_ocp_warm(setup, ocp_initial_guess(setup))
    backend = replan_backend(Context(setup, resolved_solver(setup), "ocp", {}))
    return within_reserve(setup, plan, backend) if backend and plan.success else plan


def within_reserve(setup: Setup, plan: Solution, backend: Backend) -> Solution:
    """The plan again within the limits less RESERVE (from the plan within the limits, the rows it
    breaks relaxed) by the re-planning `backend`, from rest, so that the re-plans have room for
    corrections; the plan itself if that fails."""
    spec = setup.ocp.solver
    solver = backend.replan_solver(setup, moving=False)
    start = InitialGuess(np.array(plan.q, float), "the plan within the limits")
    run = solver.replan(setup, start, ReplanOptions(  # from rest
        None, None, spec.tol, REPLAN_MU, min(spec.surrogate_max_iter, spec.max_iter), RESERVE,
        feasible_ok=False))
    if not run.success:
        return plan
    sol = solver.solution(setup, plan.method, start, run)
    sol = enforce_limits(setup, sol.replaced(
        solve_time_s=sol.solve_time_s + plan.solve_time_s,
        extras={**sol.extras, "reserve": RESERVE, "attempts_within_limits": plan.attempts}))
    return sol if sol.success else plan
