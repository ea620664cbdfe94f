"""A plan's optimality certificate: the typed record of what was measured at it, and its verdict.

Computed after the solve from the problem's own functions (`ocp/certificate.py`), written in
the solution file under `certificate`, checked again by `surestep check` (docs/certificate.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..json_records import JsonRecord

# the levels a certificate grants, best first
OPTIMAL, ACCEPTABLE, FEASIBLE, INFEASIBLE = "optimal", "acceptable", "feasible", "infeasible"


@dataclass(frozen=True)
class Tolerances(JsonRecord):
    """What the plan's measures are held to (the problem's: `solver.tol`, its acceptable level)."""

    feasibility: float  # terminal pose [m, rad], joint bounds [rad, m], depth [m], limit rows [1]
    stationarity: float  # scaled projected gradient of the Lagrangian (objective 1 at the start)
    acceptable: float  # the stationarity of an acceptable-level stop (IPOPT's acceptable_tol)
    complementarity: float  # scaled, as stationarity
    trace: float  # relative disagreement of the independent EKF's Tr(Sigma_T) with the reported


@dataclass(frozen=True)
class Certificate(JsonRecord):
    """The measures at a plan (each the largest over its rows) and the level they grant.

    Stationarity and complementarity are divided by IPOPT's dual scale `s_d` (the multipliers'
    mean magnitude over 100, at least 1), as IPOPT's own optimality error is."""

    terminal_position_m: float  # |p(q_T) - p_goal|
    terminal_angle_rad: float  # angle between the goal's orientation and the plan's last
    bound_violation: float  # joints beyond their bounds or moved where held [rad, m]
    depth_violation: float  # [m] the means below the problem's min_depth
    limit_violation: float | None  # enforced limit rows beyond 1 (normalised); None: not enforced
    stationarity: float  # scaled inf-norm of grad f + J^T lambda, multipliers estimated
    complementarity: float  # scaled largest multiplier x slack of the inequality rows
    dual_scale: float  # s_d
    active_rows: int  # inequality rows carrying a multiplier (chosen by complementarity)
    trace: float  # Tr(Sigma_T) of the planning model by a plain NumPy EKF pass
    trace_error: float  # its relative difference from the reported (and evaluated) trace
    tolerances: Tolerances
    level: str  # optimal | acceptable | feasible | infeasible
    time_s: float  # computing it [s]

    @staticmethod
    def _readers() -> dict:
        return {"tolerances": Tolerances.from_json}

    @property
    def optimal(self) -> bool:
        return self.level == OPTIMAL

    @property
    def certified(self) -> bool:
        """A first-order optimum to the problem's tolerance or its acceptable level."""
        return self.level in (OPTIMAL, ACCEPTABLE)

    def judged(self) -> Certificate:
        """The same measures with `level` recomputed from them and the tolerances."""
        return replace(self, level=level_of(self))

    def failures(self) -> list[str]:
        """One line per criterion not met (empty: certified)."""
        tol, out = self.tolerances, []
        checks = [("terminal position", self.terminal_position_m, tol.feasibility, "m"),
                  ("terminal angle", self.terminal_angle_rad, tol.feasibility, "rad"),
                  ("joint bounds", self.bound_violation, tol.feasibility, "rad or m beyond"),
                  ("depth bound", self.depth_violation, tol.feasibility, "m below min_depth"),
                  ("motion limits", self.limit_violation, tol.feasibility,
                   "of a limit beyond it"),
                  ("stationarity", self.stationarity, tol.acceptable, "(scaled)"),
                  ("complementarity", self.complementarity, tol.acceptable, "(scaled)"),
                  ("trace", self.trace_error, tol.trace, "relative, independent EKF")]
        for name, value, limit, unit in checks:
            if value is not None and not value <= limit:
                out.append(f"{name}: {value:.3g} {unit}, allowed {limit:.3g}")
        return out


def level_of(c: Certificate) -> str:
    """The level the measures of `c` grant under its tolerances."""
    tol = c.tolerances
    primal = [c.terminal_position_m, c.terminal_angle_rad, c.bound_violation, c.depth_violation,
              c.limit_violation or 0.0]
    if not (all(v <= tol.feasibility for v in primal) and c.trace_error <= tol.trace):
        return INFEASIBLE
    if c.stationarity <= tol.stationarity and c.complementarity <= tol.complementarity:
        return OPTIMAL
    return (ACCEPTABLE if max(c.stationarity, c.complementarity) <= tol.acceptable
            else FEASIBLE)
