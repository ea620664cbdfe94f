"""The solvers a Planner's re-plans run, built once per number of steps left and kept, and the
Solution a re-plan's run becomes.

Without enforced limits a re-plan runs projected Newton's solver of its horizon; within them the
interior-point one of its horizon, from a moving start. Each comes with the model's EKF compiled
over that horizon, which evaluates a plan in one call instead of a CasADi call per step. Their
build times are kept apart from the plans' (`builds`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import casadi as ca
import numpy as np

from ..buffered import Buffered
from ..model.belief import NV, NX, BeliefModel, unvech, vech
from ..model.lie import pose_mean
from ..ocp.certificate import prepare_replans
from ..ocp.iterate import InitialGuess
from ..output.solution import Solution
from ..output.solution_records import StartState
from ..problem.setup import Setup
from ..solvers.backends import Backend

UNVECH = unvech(np.arange(NV, dtype=float)).astype(int)  # (6, 6) positions of each entry in vech
CERTIFIED_SETUP = "_certified_setup"  # a re-plan's setup, kept in its extras until it is certified


class ReplanSolvers:
    """A Planner's solvers per horizon (a base of `Planner`): the methods below keep them in
    `self._solvers` (steps left -> projected Newton's solver and EKF; minus the steps left -> the
    interior-point solver and EKF) and their build times in `self.builds`, and build them from
    `self.setup`."""

    setup: Setup
    builds: dict[int, float]
    _solvers: dict[int, tuple]
    _backend: Backend | None  # within enforced limits: the backend re-planning from a moving start
    _first: Backend | None  # without: the first backend (its solvers built ahead)

    @property
    def build_time_s(self) -> float:
        """Seconds spent building solvers so far (not counted in any plan's time)."""
        return sum(self.builds.values())

    def _interior(self, sub: Setup) -> tuple:
        """(interior-point solver, compiled EKF or None) of a re-plan over `sub`'s horizon from a
        moving start, built on first use (its build time in `builds`, keyed by minus the horizon).
        The EKF evaluates a plan in one call (`compiled_ekf`); None for a model with joint-space
        noise, which needs the joints (`evaluate`). The re-plan's certificate is made ready with
        it (`prepare_replans`: compiled now, not in the loop)."""
        t0, n = time.perf_counter(), sub.ocp.horizon
        if -n not in self._solvers:  # a re-plan's structure is its horizon's (no cache key made)
            self._solvers[-n] = (self._backend.replan_solver(sub),
                                 None if self.setup.model.joint_noise
                                 else Buffered(compiled_ekf(self.setup.eval_model, n)))
            prepare_replans(sub)
            self.builds[-n] = time.perf_counter() - t0
        return self._solvers[-n]

    def _solver(self, n: int, background: bool = False) -> tuple:
        """(projected Newton solver, compiled EKF over n steps) for n steps left, built on first
        use; `background`: its C compiled in a background thread (loaded, and waited for if need be,
        when it is first used: the wait counts as build time, not as a plan's)."""
        if n not in self._solvers:
            t0 = time.perf_counter()
            sub = self.setup.with_ocp(horizon=n)
            self._solvers[n] = (self._first.prebuild(sub, background=background),
                                compiled_ekf(self.setup.eval_model, n))
            self.builds[n] = time.perf_counter() - t0
        if not background:
            self.builds[n] += self._solvers[n][0].ready()
        return self._solvers[n]


def compiled_ekf(model: BeliefModel, n: int) -> ca.Function:
    """`(poses (6, n+1), vech(Sigma_0)) -> vech(Sigma_t|t) (21, n+1)`: the model's EKF step unrolled
    (one call)."""
    X, s0 = ca.SX.sym("X", NX, n + 1), ca.SX.sym("sigma0", NV)
    out = [s0]
    for t in range(n):
        out.append(model.step(pose_mean(X[:, t]), pose_mean(X[:, t + 1]), out[-1]))
    return ca.Function("propagation", [X, s0], [ca.horzcat(*out)])


def replan_solution(sub: Setup, propagation, solver, warm: InitialGuess, run, cov, v0,
                    a0) -> Solution:
    """A re-plan's Solution from its interior-point run: evaluated by the compiled EKF
    `propagation` where there is one; `sub` kept in its extras (CERTIFIED_SETUP) for the
    certificate."""
    # (in place: the buffer's values are copied out by the indexing)
    sigma = (None if propagation is None else
             propagation(run.poses.T, vech(cov))[0].reshape(-1, NV)[:, UNVECH])
    sol = solver.solution(sub, "ocp-replan", warm, run, sigma=sigma)
    run_record = replace(sol.run, start_state=StartState(v0.tolist(), a0.tolist()),
                         warm_start_q=np.asarray(warm.q, float).tolist())
    # (the certificate's problem; taken out before it is returned)
    return sol.replaced(run=run_record, extras={**sol.extras, CERTIFIED_SETUP: sub})
