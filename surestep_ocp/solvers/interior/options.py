"""The interior-point method's constants and its options as one typed, frozen object (`run`'s
keyword arguments and the constants, with their defaults)."""

from __future__ import annotations

from dataclasses import dataclass
from ...status import Status

MU_INIT = 0.1  # IPOPT's mu_init (the objective is 1 at the start)
# The last barrier parameter (IPOPT's mu_min): the barrier's optimum is above the problem's by up to
# (rows) x mu, and the problem has thousands of rows (docs/realtime.md)
MU_FINAL = 1e-11
# Converged at the acceptable level when the objective changed by at most this (relative) over
# ACCEPTABLE_ITER iterations with the complementarity at MU_FINAL: the surrogate Hessian converges
# linearly near the optimum (IPOPT's acceptable_obj_change_tol on the enforced NLP,
# nlp_cache.ENFORCED_OPTIONS)
ACCEPTABLE_CHANGE, ACCEPTABLE_ITER = 1e-9, 3
# `feasible_ok`: a run that reaches max_iter with every row kept (not relaxed) ends with this
# status, a success: its plan keeps every limit and reaches the goal, not yet optimal (a re-planning
# loop's iteration budget)
FEASIBLE = Status.FEASIBLE_POINT_FOUND
# with `feasible_ok`, the steps that shrink a relaxation do not count against max_iter, up to this
# many
RELAXED_MAX = 30
# the secant end-game (newton.py's SR1 correction of the surrogate Hessian, the tool rows' exact
# curvature) starts once the average complementarity is this small and no row is relaxed (tuned on
# benchmarks/realtime.py's 101 problems: docs/realtime.md)
SECANT_GAP = 3e-8
# each correction must bring the rows nearer the boundary fraction by this factor (IPOPT's
# kappa_soc), else the step is shortened
KAPPA_SOC = 0.99
MAX_SOC = 4  # second-order corrections per iteration (IPOPT's max_soc), over all its step lengths
# `relax`: a start's rows below this (of their limit) get it as slack, the relaxation then shrinks
RELAX_TO = 1e-2
# relaxed rows: STUCK_ITER steps in a row shorter than STUCK_STEP end the run as (locally)
# infeasible
STUCK_STEP, STUCK_ITER = 1e-3, 3
# a step cut below this fraction: the next barrier parameter re-centres (no Mehrotra decrease)
SHORT_STEP = 0.2
# while the dual error is above the tolerance, the barrier parameter falls no lower than this times
# it, nor than its last value: a complementarity far below the dual error leaves rows with tiny
# slacks and multipliers that the Newton direction ignores and then runs into, 1 % of a step at a
# time (tuned on benchmarks/realtime.py's 101 problems). In a re-plan's few iterations
# (`feasible_ok`) only while rows are relaxed: after that it kept the plans off the optimum and cost
# the closed loop grasps; while relaxed, without it, the slacks fell to ~1e-10 and the relaxation
# (which only a full step removes) then shrank by about half a step for 17 steps (docs/realtime.md).
# Once no row is relaxed the floor is lower (MU_PER_DUAL): fewer iterations, on held-out problems
# too (docs/realtime.md, "The barrier parameter's floor")
MU_PER_DUAL_RELAXED = 1e-5
MU_PER_DUAL = 3e-6
WINDOW = 4  # waypoints each curve piece depends on (t-1 .. t+2)




@dataclass(frozen=True)
class InteriorOptions:
    """One run's options: `InteriorNewton.run`'s keyword arguments (but the start's data: `v0`,
    `a0`, `warm`) and the method's constants above, with the same defaults. (WINDOW is the rows'
    structure and FEASIBLE a status; `_fixed_slacks` gives constant rows RELAX_TO, the module's.)"""

    tol: float = 1e-6  # the dual error's
    max_iter: int = 300
    verbose: bool = False  # print each iteration's record (`IterationRecord.line`)
    mu0: float | None = None  # the barrier parameter to start from (None: mu_init)
    relax: bool = False  # a start outside rows: they get slacks, which then shrink
    reserve: float = 0.0  # the fraction of the velocity, acceleration and tool limits kept back
    feasible_ok: bool = False  # max_iter with every row kept ends as FEASIBLE
    acceptable_change: float = ACCEPTABLE_CHANGE
    use_secant: bool = True  # the secant end-game
    relaxed_max: int = RELAXED_MAX
    mu_init: float = MU_INIT
    mu_final: float = MU_FINAL
    acceptable_iter: int = ACCEPTABLE_ITER
    secant_gap: float = SECANT_GAP
    kappa_soc: float = KAPPA_SOC
    max_soc: int = MAX_SOC
    relax_to: float = RELAX_TO
    stuck_step: float = STUCK_STEP
    stuck_iter: int = STUCK_ITER
    short_step: float = SHORT_STEP
    mu_per_dual_relaxed: float = MU_PER_DUAL_RELAXED
    mu_per_dual: float = MU_PER_DUAL
