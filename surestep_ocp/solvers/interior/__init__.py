"""A primal-dual interior-point Newton method for the OCP within the motion limits, built for its
stage structure.

The problem is `newton.py`'s joint-space one (the condensed scalar recursion with the surrogate
Hessian, q_0 and q_T fixed, the interior joints free) plus the rows the IPOPT transcription carries
with `limits.enforce: true`, all local in time: the joint bounds (the RCM distance as the
insertion's lower bound), the means' minimum depth, the played curve's velocity and acceleration
control points (linear in a window of four waypoints of one joint, `model/limits/curve.py`) and the
tool's speeds at points of each step (nonlinear in a window of four waypoints).

Each iteration solves the primal-dual Newton system reduced to the joints, `(H + sum_i (z_i / c_i)
grad c_i grad c_i^T + sum_i z_i Hess(-c_i)) dx = -grad f + sum_i (mu / c_i) grad c_i`, whose matrix
is banded (half-bandwidth four waypoints): a banded Cholesky, linear in T. Barrier parameter:
Mehrotra's probe, re-centred after a short step; direction: with Mehrotra's corrector (the affine
step's second-order complementarity term); steps: fraction to the boundary for the rows (with
second-order corrections for the curved ones) and the multipliers, Armijo on the barrier function
against the decrease the model predicts (the barrier exact on the linearised rows).
It needs a start strictly within every row (the backend tries the straight line at several time
laws, `backends/interior_point.py`). A re-plan may start in motion: the curve's first knot then has
the executed curve's velocity and acceleration (`curve.knot_derivatives(moving=True)`).

The parts, one concept a module:
- `options`: the constants and `InteriorOptions` (a run's options as one frozen object);
- `rows`: the limit rows of one structure, their values at a point, a run's start point;
- `jacobian`: the rows' Jacobian at an iterate (`_RowJacobian`) and the sparse products;
- `band`: the reduced matrix's band layout, its assembly from its parts and its factorisation;
- `kkt`: the derivatives at an iterate, the reduced matrix factorised, the Newton directions;
- `barrier`: Mehrotra's probe and the barrier update, the multipliers' safeguard, the convergence
  test;
- `line_search`: the fraction to the boundary, second-order corrections, Armijo's test;
- `record`: `InteriorRun` and the per-iteration `IterationRecord` (what `verbose` prints);
- `algorithm`: `InteriorNewton` and the loop.
"""

from .algorithm import InteriorNewton
from .jacobian import _csr_dot, _csr_tdot, _RowJacobian
from .line_search import _to_boundary
from .options import (ACCEPTABLE_CHANGE, ACCEPTABLE_ITER, FEASIBLE, KAPPA_SOC, MAX_SOC, MU_FINAL,
                      MU_INIT, MU_PER_DUAL, MU_PER_DUAL_RELAXED, RELAX_TO, RELAXED_MAX, SECANT_GAP,
                      SHORT_STEP, STUCK_ITER, STUCK_STEP, WINDOW, InteriorOptions)
from .record import InteriorRun, IterationRecord

__all__ = ["ACCEPTABLE_CHANGE", "ACCEPTABLE_ITER", "FEASIBLE", "KAPPA_SOC", "MAX_SOC", "MU_FINAL",
           "MU_INIT", "MU_PER_DUAL", "MU_PER_DUAL_RELAXED", "RELAX_TO", "RELAXED_MAX",
           "SECANT_GAP", "SHORT_STEP", "STUCK_ITER", "STUCK_STEP", "WINDOW", "InteriorNewton",
           "InteriorOptions", "InteriorRun", "IterationRecord", "_RowJacobian", "_csr_dot",
           "_csr_tdot", "_to_boundary"]
