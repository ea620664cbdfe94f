"""Motion limits of a plan: what a dVRK would refuse or struggle with; reported, and enforced on
request.

A problem's `limits:` section (problems/README.md, "Motion limits") gives overrides; with
`limits.enforce: true` the OCP (IPOPT's condensed transcription) carries them as constraints, and
every method's plan that breaks one is not a success (`enforce`, status `Motion_Limits_Violated`).

- `values`: the limits themselves (defaults, `MotionLimits`, the URDF's velocities, overrides);
- `curve`: the curve played at the planned pace (quintic Hermite) and the linear rows bounding it;
- `report`: a plan measured against the limits (`plan_report`, a `LimitsReport`) and the compare
  table's rows;
- `enforcement`: `enforce`, which turns a successful Solution over a limit into a failure.

Every public name is importable from here too.
"""

from .curve import (
    CURVE_NAME,
    CURVE_PIECES,
    TOOL_MARGIN,
    TOOL_POINTS,
    curve_coefficients,
    curve_control_rows,
    curve_limit_rows,
    curve_position_rows,
    curve_point_weights,
    tool_point_windows,
    derivative_power,
    evaluate_curve,
    knot_derivatives,
)
from .enforcement import enforce
from .report import (
    UNREACHABLE,
    LimitsReport,
    PlayedCurve,
    SkippedReport,
    Violation,
    markdown_rows,
    plan_report,
    read_report,
    rotation_angle,
    summary_row,
    worst_violations,
)
from .values import (
    DEFAULT_ACCEL_PER_VELOCITY,
    DEFAULT_ACCELERATION,
    INSERTION,
    JAW,
    PROBLEM_SOURCE,
    RCM_FRAME,
    RCM_MIN_DISTANCE_M,
    RCM_ROOT,
    REL_TOL,
    TOOL_ROTATION_RAD_S,
    TOOL_SPEED_M_S,
    VIOLATED,
    MotionLimits,
    is_psm,
    motion_limits,
    parse_overrides,
    problem_limits,
    rcm_insertion_bound,
    joint_bounds,
    recorded_limits,
    urdf_velocity_limits,
)

# The OCP's limit rows: "curve" (the played curve's, `curve.py`) or "steps" (finite differences,
# before). A switch read here when an NLP is built (solvers/nlp_cache.py, transcription.py);
# tests set it here (the two measured against each other: docs/findings.md, "rows on the played
# curve").
CURVE_ROWS = "curve"

__all__ = [
    "CURVE_NAME", "CURVE_PIECES", "CURVE_ROWS", "DEFAULT_ACCELERATION",
    "DEFAULT_ACCEL_PER_VELOCITY", "INSERTION", "JAW", "PROBLEM_SOURCE", "RCM_FRAME",
    "RCM_MIN_DISTANCE_M", "RCM_ROOT", "REL_TOL", "TOOL_MARGIN", "TOOL_POINTS",
    "TOOL_ROTATION_RAD_S", "TOOL_SPEED_M_S", "UNREACHABLE", "VIOLATED", "LimitsReport",
    "MotionLimits", "PlayedCurve", "SkippedReport", "Violation", "curve_coefficients",
    "curve_control_rows", "curve_limit_rows", "curve_point_weights", "tool_point_windows",
    "curve_position_rows", "derivative_power",
    "enforce", "evaluate_curve",
    "is_psm", "knot_derivatives", "markdown_rows", "motion_limits", "parse_overrides",
    "plan_report", "problem_limits", "read_report", "rcm_insertion_bound", "joint_bounds",
    "recorded_limits", "rotation_angle",
    "summary_row", "urdf_velocity_limits", "worst_violations",
]
