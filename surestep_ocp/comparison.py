"""`surestep compare`: every method on one problem, side by side (files, table, plots)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from .errors import SurestepError
from .methods.gradient import JOINT_NOISE_UNSUPPORTED
from .method_grammar import split_name
from .methods.baseline import LENGTHENED, duration_note
from .methods.registry import COMPARE_METHODS, run_method
from .evaluation.metrics import comparison_rows, markdown_table
from .model.limits.enforcement import enforce
from .model.limits.report import (
    UNREACHABLE,
    LimitsReport,
    PlayedCurve,
    SkippedReport,
    markdown_rows,
    plan_report,
    summary_row,
)
from .model.limits.values import problem_limits
from .problem.paths import resolve_urdf
from .model.limits.retiming import planned_curve
from .output.plots_compare import write_figures
from .output.plots_motion import plot_plans
from .problem.setup import Setup
from .output.files import written_together
from .output.solution import Solution, write_json_atomic, write_text_atomic


def run_comparison(setup: Setup, methods: tuple[str, ...] = COMPARE_METHODS,
                   progress=None) -> list[Solution]:
    """Solve with each method in turn (a gradient solution is reused by `ocp-from-gradient`)."""
    if setup.model.joint_noise and any("gradient" in split_name(m)[0] for m in methods):
        raise SurestepError(JOINT_NOISE_UNSUPPORTED)  # checked before any solve
    cache: dict[str, Solution] = {}
    for name in methods:
        if progress:
            progress(name)
        cache[name] = run_method(setup, name, cache)
    return [with_motion_limits(setup, cache[m]) for m in methods]


def with_motion_limits(setup: Setup, sol: Solution) -> Solution:
    """`sol` with its plan's motion-limit report (limits.plan_report, with the problem's `limits:`
    overrides) as `motion_limits` (with `limits.enforce: true` also a failure over a limit,
    `limits.enforce`), with the peaks of the curve the robot plays through the waypoints
    (`played_curve`: what `surestep export` checks)."""
    if any(q is None for q in sol.q):
        sol = sol.replaced(motion_limits=SkippedReport(UNREACHABLE))
        return enforce(setup, sol) if setup.ocp.limits.enforce else sol
    q, step, limits = np.array(sol.q, float), setup.ocp.timing.step_s, problem_limits(setup)
    if setup.ocp.limits.enforce:
        sol = enforce(setup, sol, limits)
    else:
        sol = sol.replaced(motion_limits=plan_report(setup.robot, q, step, limits,
                                                     tool_frame=setup.robot.frame))
    played = planned_curve(q, step, limits, 1.0 / step, setup.robot, setup.robot.frame)[1]
    return sol.replaced(motion_limits=replace(sol.motion_limits,
                                              played_curve=PlayedCurve(**played)))


def write_comparison(solutions: list[Solution], out_dir: Path, problem_path: str) -> str:
    """Write `<method>.json`, `comparison.md`, `comparison.json`, `trace.png`, `path.png`,
    `motion.png`, all or none (`files.written_together`: Ctrl-C while they were written left some);
    return the tables (the comparison, then the motion limits at the planned pace)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [f"{s.method}.json" for s in solutions] + ["comparison.json", "comparison.md",
                                                         "trace.png", "path.png", "motion.png"]
    with written_together([out_dir / n for n in names], "the comparison") as staged:
        return _write_comparison(solutions, staged[out_dir / names[0]].parent, problem_path)


def _write_comparison(solutions: list[Solution], out_dir: Path, problem_path: str) -> str:
    for s in solutions:
        s.save(out_dir / f"{s.method}.json")
    rows = finite_or_null(comparison_rows(solutions))
    table = markdown_table([{k: "" if v is None else v for k, v in r.items()} for r in rows])
    write_json_atomic(out_dir / "comparison.json", {"problem": problem_path, "methods": rows})
    text = (f"# Comparison on `{problem_path}`\n\n"
            "Every method evaluated by the same EKF (all observation components) along its own "
            "waypoints; `rel.` is relative to the straight-line baseline with the paper's scaling "
            f"(lower is better). {NULL_NOTE}\n\n{table}\n")
    limits_text = limits_table(solutions)
    if limits_text:
        text += f"\n{limits_text}\n"
    write_text_atomic(out_dir / "comparison.md", text)
    write_figures(solutions, out_dir)
    urdf = _robot_urdf(solutions)
    if urdf is not None:
        plot_plans(solutions, urdf, out_dir / "motion.png")
    return table + (f"\n\n{limits_text}" if limits_text else "")


# a figure with no finite value: a singular Sigma_T (no observation noise) has entropy -inf, and
# its `rel.` or one of mixed signs has none
NULL_NOTE = ("A figure with no finite value (the entropy of a singular Σ_T, a `rel.` of it or of "
             "mixed signs) is an empty cell here and `null` in comparison.json.")


def finite_or_null(rows: list[dict]) -> list[dict]:
    """`rows` with every NaN or infinite number as None (JSON `null`, NULL_NOTE): comparison.json
    holds no NaN or Infinity, which JSON does not have."""
    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    return [{k: clean(v) for k, v in r.items()} for r in rows]


def _robot_urdf(solutions: list[Solution]):
    p = resolve_urdf(str(solutions[0].robot.get("urdf", ""))) if solutions else None
    return p if p is not None and p.is_file() else None


def limits_table(solutions: list[Solution]) -> str:
    """Markdown: each method's motion limits at the planned pace (docs/motion_limits_and_export.md;
    not enforced by the planners)."""
    reps = [(s.method, s.motion_limits) for s in solutions]
    rows = [summary_row(m, r) for m, r in reps if isinstance(r, LimitsReport)]
    if not rows:
        return ""
    step = next(r for _, r in reps if isinstance(r, LimitsReport)).step_s
    skipped = [m for m, r in reps if isinstance(r, SkippedReport)]
    note = f" (not checked: {', '.join(skipped)}, unreachable waypoints)" if skipped else ""
    enforced = any(r is not None and r.enforced for _, r in reps)
    how = ("enforced (`limits.enforce: true`: the OCP's constraints and the baseline's time law; "
           "their plan over a limit is a failure, status Motion_Limits_Violated; the gradient "
           "variants' violations are reported)" if enforced else
           "reported, not enforced (`limits.enforce: false`)")
    return (f"Motion limits at the planned pace ({step:g} s per step; {how}; `surestep export` "
            f"plays a plan within the limits at its planned times and retimes any other){note}:\n\n"
            f"{markdown_rows(rows)}{_duration_notes(solutions)}")


def _duration_notes(solutions: list[Solution]) -> str:
    """Below the limits table: each baseline lengthened to keep within the limits (or that cannot),
    by how much."""
    said = [s for s in solutions
            if s.status == LENGTHENED or (s.extras.get("time_law") or {}).get("not_within")]
    text = "".join(f"\n\n{s.method}: {duration_note(s)}." for s in said)
    if any(s.status == LENGTHENED for s in said):
        text += (" Its Tr(Σ_T) is after its own steps' observations (more than the other plans'), "
                 "and `rel.` is relative to it.")
    return text
