"""Grasping on evidence in the rollouts: a rollout grasps at the first step that brings it onto the
goal with its tracker's belief sure enough, or at the cap.

At step t the rollout's command moves its estimate to the next waypoint; when that waypoint is the
goal (the plan's last step, or a dwell at the goal once the plan has ended) the error at the grasp
is the estimate's error plus the step's motion noise, N(0, Sigma_t + W): its probability of being
within the tolerance (`model.grasp.grasp_probability`) is the rollout's predicted success. The
rollout grasps after that step when the prediction reaches `confidence`; else it dwells at the goal
under observation (commands from its estimate onto the goal, the camera still moving at its
scheduled times) and decides again. At `max_steps` it grasps wherever it is (counted as capped).
Without a confidence (None) it grasps on the clock: when the plan ends, as the paper does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.grasp import grasp_probability


@dataclass(frozen=True)
class GraspRule:
    """When the rollouts grasp: the tolerance [m, rad], the confidence asked (None: at the plan's
    end) and the cap (the most steps a rollout runs, dwell included)."""

    position: float = 0.005
    angle: float = 0.2
    confidence: float | None = None
    max_steps: int | None = None  # None: the plan's steps (no dwell)

    @classmethod
    def of(cls, setup, confidence: float | None = ..., max_steps: int | None = ...) -> GraspRule:
        """The rule of a setup's `goal.tolerance`, `goal.confidence` and `timing.max_duration`
        (either overridden when given)."""
        g, ocp = setup.ocp.grasp, setup.ocp
        conf = g.confidence if confidence is ... else confidence
        cap = ocp.timing.max_steps(ocp.horizon) if max_steps is ... else max_steps
        return cls(g.position, g.angle, conf, cap)


class Grasping:
    """The rollouts' grasp decisions as they run: `done`, the step after which each grasped
    (`step`), its predicted success then (`predicted`) and whether the cap made it (`capped`)."""

    def __init__(self, rule: GraspRule, n: int, plan_steps: int):
        self.rule = rule
        self.cap = plan_steps if rule.max_steps is None or rule.confidence is None \
            else max(int(rule.max_steps), 1)
        self.done = np.zeros(n, bool)
        self.step = np.full(n, self.cap, int)
        self.predicted = np.full(n, np.nan)
        self.capped = np.zeros(n, bool)

    def decide(self, t: int, arriving: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(N,) which rollouts grasp after step t -> t+1: `arriving` ones (whose step ends on the
        goal) sure enough under `P` (N, 6, 6, the error's covariance after the step), and all at
        the cap."""
        last = t + 1 >= self.cap
        ask = ~self.done & (arriving | last)
        now = np.zeros_like(ask)
        if ask.any():
            p = np.asarray(grasp_probability(P[ask], self.rule.position, self.rule.angle))
            sure = np.ones_like(p, bool) if self.rule.confidence is None \
                else p >= self.rule.confidence
            now[ask] = sure | last
            self.predicted[ask] = np.where(now[ask], p, self.predicted[ask])
            self.capped[ask] = ~sure & last
        self.step[now] = t + 1
        self.done |= now
        return now
