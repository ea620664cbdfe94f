"""Per-solution figures for tables, and the paper's relative scaling against the baseline."""

from __future__ import annotations

import math

import numpy as np

from ..model.camera import Intrinsics
from ..model.lie import np_angle
from ..output.solution import Solution


def relative(y: float, b: float) -> float:
    """The paper's scaling: `y / b` for positive metrics, `1 - (y - b) / b` where both are negative.

    Lower is better in both cases. Mixed signs have no defined scaling: NaN.
    """
    if y > 0 and b > 0:
        return y / b
    if y < 0 and b < 0:
        return 1 - (y - b) / b
    if y == b:
        return 1.0
    return math.nan


def solution_metrics(sol: Solution) -> dict:
    """Figures of one plan: final covariance, terminal error, clipping step, worst depth and image
    offset."""
    poses = np.asarray(sol.poses)
    intr = Intrinsics(**sol.camera)
    d_star = float(sol.noise["depth_star"])
    inner = poses[1:-1] if len(poses) > 2 else poses  # start and goal are shared by every method
    offsets = [np.hypot(*intr.offset(p)) for p in inner[:, :3]]
    err_m, err_rad = sol.terminal_error
    reach = sol.extras.get("reachability", {})
    unreachable = sum(q is None for q in sol.q)
    return {
        "method": sol.method,
        "success": sol.success,
        "status": sol.status,
        "trace_final": sol.trace_final,
        "entropy_final": sol.entropy_final,
        "terminal_error_m": err_m,
        "terminal_error_rad": err_rad,
        "final_step_m": float(np.linalg.norm(poses[-1, :3] - poses[-2, :3])),
        "final_step_rad": np_angle(poses[-2, 3:], poses[-1, 3:]),
        "worst_depth_error_m": float(np.max(np.abs(inner[:, 2] - d_star))),
        # normalised image plane [-], interior waypoints
        "worst_image_offset": float(np.max(offsets)),
        "unreachable_waypoints": int(reach.get("unreachable", unreachable)),
        "solve_time_s": sol.solve_time_s,
        "iterations": sol.iterations,
    }


def comparison_rows(solutions: list[Solution]) -> list[dict]:
    """Metrics of each solution plus their values relative to the baseline (if present)."""
    rows = [solution_metrics(s) for s in solutions]
    base = next((r for r in rows if r["method"] == "baseline"), None)
    for r in rows:
        if base is not None:
            r["trace_rel"] = relative(r["trace_final"], base["trace_final"])
            r["entropy_rel"] = relative(r["entropy_final"], base["entropy_final"])
    return rows


_COLUMNS = [
    ("method", "method", "{}"),
    ("Tr(Σ_T)", "trace_final", "{:.3e}"),
    ("rel.", "trace_rel", "{:.3f}"),
    ("H(Σ_T)", "entropy_final", "{:.2f}"),
    ("rel.", "entropy_rel", "{:.3f}"),
    ("term. err [m]", "terminal_error_m", "{:.1e}"),
    ("term. err [rad]", "terminal_error_rad", "{:.1e}"),
    ("final step [mm]", "final_step_m", "{:.2f}"),
    ("final step [rad]", "final_step_rad", "{:.3f}"),
    ("worst depth error [mm]", "worst_depth_error_m", "{:.1f}"),
    ("worst img offset", "worst_image_offset", "{:.3f}"),
    ("unreachable", "unreachable_waypoints", "{}"),
    ("time [s]", "solve_time_s", "{:.2f}"),
    ("iters", "iterations", "{}"),
    ("status", "status", "{}"),
]


def markdown_table(rows: list[dict]) -> str:
    """The comparison as a Markdown table (mm for the step and depth columns)."""
    head = "| " + " | ".join(c[0] for c in _COLUMNS) + " |"
    sep = "|" + "|".join("---" for _ in _COLUMNS) + "|"
    lines = [head, sep]
    for r in rows:
        cells = []
        for _, key, fmt in _COLUMNS:
            v = r.get(key, "")
            if key in ("final_step_m", "worst_depth_error_m"):
                v = v * 1e3
            cells.append(fmt.format(v) if v != "" else "")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
