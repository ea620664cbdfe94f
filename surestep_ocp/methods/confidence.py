"""Planning to a grasp confidence: the shortest horizon whose plan makes the grasp as sure as asked.

A plan's confidence is `model.grasp.grasp_probability` of its Sigma_T|T-1, the covariance of the
tool's error at the grasp: the last command moves the estimate onto the goal, so the error is the
estimate's before the last measurement (along the plan's waypoints, every observation component,
the observation noise expected under the belief, only the observations the problem's detector
delivers: `predicted_at_grasp`).

With `goal.confidence` set, the OCP of each horizon T still minimises its objective (Tr(Sigma_T));
the horizon is the decision: the smallest T from the first one after the last camera move up to
`timing.max_duration` whose plan reaches the confidence, found by bisection (more time never
removes a plan: the longer horizon can dwell at the goal under observation, so the reached
confidence grows with T; failed solves count as not reached). Where the cap does not reach it, the
best plan found is returned with the status `Confidence_Not_Reached`, and its confidence and time
are in its `grasp` record.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.belief import BeliefModel, unvech, vech
from ..model.grasp import grasp_probability
from ..model.lie import np_means
from ..output.solution import Solution
from ..problem.setup import Setup
from ..status import Status

NOT_REACHED = Status.CONFIDENCE_NOT_REACHED


def at_horizon(setup: Setup, steps: int) -> Setup:
    """The setup over `steps` steps: the camera's schedule cut or held at its last pose (its moves
    keep their steps; none may lie beyond `steps`)."""
    sched = list(setup.camera_schedule)
    if sched:
        if last_move(setup) > steps:
            raise ValueError(f"at_horizon: the camera moves at step {last_move(setup)} > {steps}")
        sched = sched[:steps + 1] + [sched[-1]] * max(0, steps + 1 - len(sched))
    return replace(setup.with_ocp(horizon=steps), camera_schedule=sched)


def last_move(setup: Setup) -> int:
    """The last step whose waypoint has a new camera pose (0: the camera never moves)."""
    C = setup.camera_schedule
    moved = [t for t in range(1, len(C)) if not np.array_equal(C[t], C[t - 1])]
    return moved[-1] if moved else 0


def confidence_model(setup: Setup) -> BeliefModel:
    """The belief a plan's confidence is computed with: every observation component and the noise
    expected under the belief (V + tr(J P J^T) per term, surestep_method.md section 8), the noise
    a tracker meets off the plan's waypoints. The paper's V at the mean is near zero at the ideal
    pose and made confidences the rollouts did not reach (docs/grasp_confidence.md)."""
    m = setup.eval_model
    return BeliefModel(replace(m.noise, observation_noise="expected"), m.camera, m.components,
                       None if m.identity_maps else m.jacobians)


def predicted_at_grasp(setup: Setup, sol: Solution) -> np.ndarray:
    """(6, 6) Sigma_T|T-1 of a plan of `setup` (the covariance of the error at the grasp) along its
    waypoints, by `confidence_model`. With a detector (`setup.ocp.detection`) a waypoint's
    observation counts with its detection probability (the expected covariance,
    p Sigma_t|t + (1 - p) Sigma_t|t-1): none where the detector cannot see the tool."""
    poses, sigma = np.asarray(sol.poses, float), sol.covariances
    T = len(poses) - 1
    model, detection = confidence_model(setup), setup.ocp.detection
    means = np_means(poses)
    s = vech(sigma[0])
    changes = setup.camera_changes()
    w = np.zeros((T, len(s)))
    if model.joint_noise:
        w = np.asarray(setup.joint_noises(np.asarray(sol.q, float)), float)
    seen = (np.ones(T + 1) if detection is None
            else detection.probability(model.camera, poses[:, :3]))
    for t in range(T):
        x0 = means[t]
        if changes is not None and t < len(changes) and changes[t] is not None:
            x0, s = model.camera_change(x0, s, changes[t])
        post, pred = (np.asarray(v, float).ravel() for v in model.step_pair(x0, means[t + 1], s,
                                                                            w[t]))
        s = seen[t + 1] * post + (1 - seen[t + 1]) * pred
    return unvech(pred)


def plan_confidence(setup: Setup, sol: Solution) -> float:
    """The probability that the plan's grasp is within the problem's tolerance (module
    docstring)."""
    g = setup.ocp.grasp
    return float(grasp_probability(predicted_at_grasp(setup, sol), g.position, g.angle))


def grasp_record(setup: Setup, sol: Solution, searched: list | None = None) -> dict:
    """The solution file's `grasp` record: tolerance, confidence asked (None: none), the plan's
    confidence [probability] and duration [s], whether it reaches the confidence, the horizons
    searched (steps, confidence; failed solves as null)."""
    g, step = setup.ocp.grasp, float(setup.ocp.timing.step_s)
    p = plan_confidence(setup, sol)
    rec = {"tolerance": {"position": g.position, "angle": g.angle}, "confidence": g.confidence,
           "predicted": p, "duration_s": sol.horizon * step,
           "reached": None if g.confidence is None else bool(p >= g.confidence),
           "max_duration_s": setup.ocp.timing.max_steps(setup.ocp.horizon) * step}
    if searched is not None:
        rec["searched"] = [{"steps": T, "confidence": q} for T, q in sorted(searched)]
    return rec


def plan_to_confidence(setup: Setup, solve) -> Solution:
    """The plan of the shortest horizon whose confidence reaches `goal.confidence` (module
    docstring); `solve(setup)` plans one horizon (a method without the confidence). The result's
    `extras["grasp"]` is its `grasp_record`."""
    target = setup.ocp.grasp.confidence
    nominal = setup.ocp.horizon
    cap = setup.ocp.timing.max_steps(nominal)
    low = max(1, last_move(setup))
    tried: dict[int, tuple[Solution, Setup, float | None]] = {}

    def attempt(T: int) -> bool:
        if T not in tried:
            s = at_horizon(setup, T)
            sol = solve(s)
            tried[T] = (sol, s, plan_confidence(s, sol) if sol.success else None)
        p = tried[T][2]
        return p is not None and p >= target

    if attempt(nominal):
        lo, hi = low - 1, nominal  # reached at hi, not known below
    elif attempt(cap):
        lo, hi = nominal, cap
    else:
        lo = hi = None
    while hi is not None and hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if attempt(mid) else (mid, hi)
    if hi is None:  # not reached: the most confident plan that solved (else the cap's)
        ok = [T for T, v in tried.items() if v[2] is not None]
        hi = max(ok, key=lambda T: (tried[T][2], -T)) if ok else cap
    sol, s, _ = tried[hi]
    searched = [(T, v[2]) for T, v in tried.items()]
    grasp = grasp_record(s, sol, searched)
    sol = sol.replaced(extras={**sol.extras, "grasp": grasp})
    if sol.success and not grasp["reached"]:
        sol = sol.replaced(success=False, status=NOT_REACHED)
    return sol
