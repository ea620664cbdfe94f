"""Outputs of `surestep evaluate`: table.md, raw.csv, solves.csv and boxplot.png from
per-configuration records.

A record is one line of `progress.jsonl` (see `configuration_record.evaluate_configuration`):
`metrics[mode][method][metric]` absolute values, `solves[method]` the solver's
outcome, `pos_errors[mode][method]` / `ori_errors[mode][method]` the final position /
orientation error of every rollout, `success[mode][method]` the share of rollouts within
the grasp tolerances, `detected[mode][method]` the share of steps with an observation.

Statistics: every relative cell is over configurations of the per-configuration ratio to
the baseline; beside the mean (the paper's statistic) the median and the 90th percentile,
which heavy tails (a few rollouts far off) do not dominate. Pooled figures (absolute table,
boxplot) are over every rollout of every configuration.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from .metrics import relative
from .rollout import METRICS
from ..output.plot_styles import styles_of
from ..output.plots_motion import pyplot
from ..output.solution import write_text_atomic

LABELS = {"pos_err_mean": "pos mean", "pos_err_std": "pos std", "ori_err_mean": "ori mean",
          "ori_err_std": "ori std", "trace_noisy": "Tr noisy", "trace_ml": "Tr ML",
          "entropy_noisy": "H noisy", "entropy_ml": "H ML"}
# The paper's Table I (relative to the baseline), rows matched to our methods.
PAPER = {
    "gradient": ("SURESTEP (all)",
                 (0.4272, 0.5425, 0.1747, 0.4633, 0.1597, 0.1819, 0.3677, 0.5078)),
    "gradient-no-pose-loss": ("no pose loss",
                              (0.412, 0.5205, 0.16, 0.3622, 0.1494, 0.1401, 0.3265, 0.4311)),
    "gradient-no-depth": ("no depth noise",
                          (0.5019, 0.553, 0.2419, 0.4994, 0.2188, 0.3183, 0.5046, 0.6658)),
    "gradient-no-fov": ("no FOV noise",
                        (0.4743, 0.5771, 0.2136, 0.5098, 0.2033, 0.246, 0.4636, 0.6016)),
    "gradient-no-orientation": ("no orientation noise",
                                (0.9862, 0.978, 0.8929, 0.9425, 0.9375, 0.9441, 0.9723, 0.9773)),
}
MODE_TEXT = {"model": "v_t ~ N(0, V(mu_t|t-1)), the noise the tracker's model expects at "
                      "its estimate",
             "true": "v_t ~ N(0, V(x_true)), the noise the detector has at the true pose"}


def _values(records, mode, method, metric) -> np.ndarray:
    return np.array([r["metrics"].get(mode, {}).get(method, {}).get(metric, math.nan)
                     for r in records], float)


# The paper's Table II (real robot, 60 needle regrasps over the four trajectory types): success
# rates.
PAPER_SUCCESS = {"gradient": 0.82, "baseline": 0.18}
# metrics with median / p90 columns in the main table
ROBUST = ("pos_err_mean", "ori_err_mean", "trace_ml")


def _ratios(records, mode, method, metric) -> np.ndarray:
    y, b = _values(records, mode, method, metric), _values(records, mode, "baseline", metric)
    r = np.array([relative(yi, bi) if np.isfinite(yi) and np.isfinite(bi) else math.nan
                  for yi, bi in zip(y, b)])
    return r[np.isfinite(r)]


def relative_stats(records, methods, modes) -> dict:
    """st[mode][method][metric] = {mean, median, p90, n} of the per-configuration ratios to the
    baseline."""
    out: dict = {}
    for mode in modes:
        out[mode] = {}
        for m in methods:
            out[mode][m] = {}
            for k in METRICS:
                r = _ratios(records, mode, m, k)
                out[mode][m][k] = {"mean": float(np.mean(r)) if len(r) else math.nan,
                                   "median": float(np.median(r)) if len(r) else math.nan,
                                   "p90": float(np.percentile(r, 90)) if len(r) else math.nan,
                                   "n": len(r)}
    return out


def pooled(records, key: str, mode: str, method: str) -> np.ndarray:
    """Every rollout's value of `key` (pos_errors / ori_errors) for a method and mode, all
    configurations."""
    return np.array([e for r in records for e in r.get(key, {}).get(mode, {}).get(method, [])],
                    float)


def success_share(records, mode: str, method: str) -> tuple[float, int]:
    """(share of rollouts within the grasp tolerances, configurations counted); equal rollouts per
    configuration."""
    v = [r["success"][mode][method] for r in records
         if method in r.get("success", {}).get(mode, {})]
    return (float(np.mean(v)) if v else math.nan), len(v)


def relative_means(records, methods, modes) -> dict:
    """rel[mode][method][metric] = (mean over configurations of relative(y_c, b_c), configurations
    used)."""
    st = relative_stats(records, methods, modes)
    return {mode: {m: {k: (v["mean"], v["n"]) for k, v in st[mode][m].items()} for m in methods}
            for mode in modes}


def _fmt(v: float, f: str = "{:.3f}") -> str:
    return "n/a" if v is None or not np.isfinite(v) else f.format(v)


def _solve_stats(records, methods) -> dict:
    st = {}
    for m in methods:
        s = [r["solves"][m] for r in records if m in r["solves"]]
        st[m] = {"failed": sum(not x["success"] for x in s),
                 "no_plan": sum(not x["evaluated"] for x in s),
                 "kept": sum("kept_start" in x for x in s),
                 "time": float(np.mean([x["solve_time_s"] for x in s])) if s else math.nan,
                 "iters": float(np.median([x["iterations"] for x in s])) if s else math.nan}
    return st


def markdown(records, methods, modes, header, spec) -> str:
    """table.md: how the run was made and how to read it, then per rollout mode the relative table,
    the paper's Table I beside it and the absolute values; the simulated Table II; the closed
    loop's re-plans."""
    rel, st = relative_stats(records, methods, modes), _solve_stats(records, methods)
    gp, ga = getattr(spec, "grasp_position", math.nan), getattr(spec, "grasp_angle", math.nan)
    lines = _introduction(records, methods, header, spec, gp, ga)
    cols = _relative_columns()
    plain = [LABELS[k] for k in METRICS]
    for mode in modes:
        lines += _relative_table(records, methods, mode, rel, st, cols)
        lines += _beside_paper(methods, mode, rel, plain)
        lines += _absolute_table(records, methods, mode, plain)
    lines += table2(records, methods, modes, gp, ga)
    lines += closed_loop(records, methods, modes)
    return "\n".join(lines)


def _detection_text(spec) -> str:
    """When the rollouts observe (the evaluation file's `detection`)."""
    det = getattr(spec, "detection", None)
    return ("every step observes (detection disabled)" if det is None else
            "a step observes only when the true pose is detectable: depth in "
            f"({det.min_depth:g}, {det.max_depth:g}) m and inside the image less a "
            f"{det.margin:g} margin"
            + (f", probability ramping over {det.falloff:g}" if det.falloff else "")
            + ", and the measurement too (gating); otherwise the EKF only predicts")


def _gradient_text(spec) -> str:
    """The gradient variant's settings (the base problem's `gradient`)."""
    grad = spec.base.gradient
    return (f"gradient variant: {grad.optimizer} L-BFGS"
            + (f", {grad.steps} step() calls of up to {grad.max_iter} iterations, line search "
               f"{grad.line_search}" if grad.optimizer == "torch"
               else f", {grad.iterations} iterations")
            + f", trace_scale {grad.trace_scale:g}, pose_loss_weight {grad.pose_loss_weight:g}"
            + (f" (preset {grad.preset})" if grad.preset else ""))


def _pace_text(records, methods, spec) -> str:
    """How the plans were executed (`execution.pace`), with the rollout steps per plan."""
    pace = getattr(spec, "pace", "planned")
    if pace == "limits":
        steps = {m: [r["solves"][m]["rollout_steps"] for r in records
                     if "rollout_steps" in r["solves"].get(m, {})] for m in methods}
        pace_text = ("**Execution**: each plan run no faster than the tool's speed limits "
                     "(`execution.pace: limits`, `pacing.py`: a step over them split into equal "
                     "rollout steps, one observation each); rollout steps per plan, "
                     "median / max: " + "; ".join(
                         f"{m} {np.median(v):.0f} / {max(v)}" for m, v in steps.items() if v) + ".")
    else:
        pace_text = ("**Execution**: every plan at its planned pace, one rollout step (one "
                     "observation) per plan step however large (`execution.pace: planned`, the "
                     "paper's protocol).")
    return pace_text


def _introduction(records, methods, header, spec, gp: float, ga: float) -> list[str]:
    """The lines before the tables: the run, how the relative numbers are made, failed solves,
    the execution and the kept starts."""
    n = len(records)
    det_text, grad_text = _detection_text(spec), _gradient_text(spec)
    kept = [f"configuration {r['config']} ({m}: {r['solves'][m]['kept_start']})" for r in records
            for m in methods if "kept_start" in r["solves"].get(m, {})]
    pace_text = _pace_text(records, methods, spec)
    return [f"# Evaluation on `{spec.path}`", "",
            (f"{n} random configurations (seed {header['seed']}, base problem "
             f"`{spec.base_path.name}`, horizon T = {spec.horizon}), {header['rollouts']} noisy "
             "closed-loop rollouts per plan and rollout mode; every plan evaluated with all "
             f"observation components; {det_text}; {grad_text}."), "",
            ("**How the relative numbers are made.** For configuration c, method m and metric k, "
             "let y = the method's absolute value and b = the baseline's on the same "
             "configuration (same rollout noise draws). The per-configuration ratio is the "
             "paper's scaling (`metrics.relative`): y / b when both are positive, 1 - (y - b) / "
             "b when both are negative (entropies), undefined (excluded) for mixed signs. `mean` "
             "cells are the mean of these ratios over configurations (the paper's statistic; "
             "lower is better, baseline = 1); `med` and `p90` are their median and 90th "
             "percentile. pos/ori = final position error ||p_T^true - p^G|| and geodesic "
             "orientation error angle(R_T^true, R^G), mean and sample std over the rollouts of "
             "one configuration; Tr noisy and H noisy = Tr(Sigma_T) and Gaussian entropy of the "
             "rollouts' EKF, mean over rollouts; Tr ML and H ML = the plan's own "
             "maximum-likelihood Sigma_T. `grasp` = share of all rollouts whose final true pose "
             f"is within {gp * 1e3:g} mm and {ga:g} rad of the goal (the simulated Table II; "
             "absolute, not relative)."), "",
            ("**Failed solves** are counted in the `failed` column and are not dropped: a plan "
             "whose solver reported failure is still rolled out and averaged in; only a method "
             "that produced no plan at all (`no plan`) is left out of that configuration's "
             "averages (`n` = configurations averaged)."), "",
            pace_text, "",
            "`kept start`: the OCP's solvers ended above the straight line they started from, "
            "which is then the plan; the attempts' statuses "
            "say why: " + ("; ".join(kept) if kept else "none") + ".",
            ""]


def _relative_columns() -> list[str]:
    """The relative table's metric columns (with median and p90 columns for ROBUST metrics)."""
    cols = []
    for k in METRICS:
        cols.append("Tr ML mean" if k == "trace_ml" else LABELS[k])
        if k in ROBUST:
            cols += [LABELS[k].split()[0] + " med" if k != "trace_ml" else "Tr ML med",
                     LABELS[k].split()[0] + " p90" if k != "trace_ml" else "Tr ML p90"]
    return cols


def _relative_table(records, methods, mode: str, rel: dict, st: dict, cols) -> list[str]:
    """The relative table of one rollout mode (ratios to the baseline, grasp share, solves)."""
    lines = [f"## Rollout mode `{mode}`: {MODE_TEXT[mode]}", "",
             "| method | " + " | ".join(cols)
             + " | grasp | n | failed | no plan | kept start | solve time [s] | "
             "iters (median) |", "|---" * (len(cols) + 8) + "|"]
    for m in methods:
        cells = []
        for k in METRICS:
            cells.append(_fmt(rel[mode][m][k]["mean"]))
            if k in ROBUST:
                cells += [_fmt(rel[mode][m][k]["median"]), _fmt(rel[mode][m][k]["p90"])]
        used = min(rel[mode][m][k]["n"] for k in METRICS)
        succ, _ = success_share(records, mode, m)
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {_fmt(succ, '{:.0%}')} | {used} | "
                     f"{st[m]['failed']} | {st[m]['no_plan']} | {st[m]['kept']} | "
                     f"{_fmt(st[m]['time'], '{:.2f}')} | {_fmt(st[m]['iters'], '{:.0f}')} |")
    return lines


def _beside_paper(methods, mode: str, rel: dict, plain) -> list[str]:
    """Our relative means beside the paper's Table I, one rollout mode."""
    lines = ["",
             ("Beside the paper's Table I (cells: our mean / paper; the paper gives means "
              f"only), mode `{mode}`:"), "",
             "| ours | paper | " + " | ".join(plain) + " |", "|---" * (len(plain) + 2) + "|"]
    for m, (label, vals) in PAPER.items():
        if m in methods:
            cells = [f"{_fmt(rel[mode][m][k]['mean'])} / {p:.3f}"
                     for k, p in zip(METRICS, vals)]
            lines.append(f"| {m} | {label} | " + " | ".join(cells) + " |")
    return lines


def _absolute_table(records, methods, mode: str, plain) -> list[str]:
    """The absolute values of one rollout mode: the metrics' means, the pooled final errors and
    the share of steps observed."""
    lines = ["",
             (f"Absolute values, mode `{mode}`: means over configurations (pos in mm, ori in "
              "mrad), then the pooled final errors of every rollout (median, 90th "
              "percentile, maximum) and the share of steps with an observation:"), "",
             "| method | " + " | ".join(plain)
             + " | pos med [mm] | pos p90 [mm] | pos max [mm] | "
             "ori med [mrad] | ori p90 [mrad] | ori max [mrad] | observed |",
             "|---" * (len(plain) + 8) + "|"]
    for m in methods:
        cells = []
        for k in METRICS:
            v = _values(records, mode, m, k)
            v = v[np.isfinite(v)]
            mean = float(np.mean(v)) if len(v) else math.nan
            if k.startswith(("pos", "ori")):
                cells.append(_fmt(mean * 1e3, "{:.2f}"))
            elif k.startswith("trace"):
                cells.append(_fmt(mean, "{:.3e}"))
            else:
                cells.append(_fmt(mean, "{:.2f}"))
        for key in ("pos_errors", "ori_errors"):
            e = pooled(records, key, mode, m) * 1e3
            cells += [_fmt(float(np.median(e)) if len(e) else math.nan, "{:.2f}"),
                      _fmt(float(np.percentile(e, 90)) if len(e) else math.nan, "{:.2f}"),
                      _fmt(float(np.max(e)) if len(e) else math.nan, "{:.1f}")]
        obs = [r["detected"][mode][m] for r in records
               if m in r.get("detected", {}).get(mode, {})]
        cells.append(_fmt(float(np.mean(obs)) if obs else math.nan, "{:.1%}"))
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def closed_loop(records, methods, modes) -> list[str]:
    """The closed-loop methods' re-plans over every configuration and rollout, per mode: count,
    kept the previous plan, longer than a step, the median of the configurations' median times, the
    worst time, the most steps the goal moved later, executed samples beyond a limit."""
    rows = []
    for m in methods:
        for mode in modes:
            rp = [r["solves"][m]["replans"][mode] for r in records
                  if mode in r["solves"].get(m, {}).get("replans", {})]
            if not rp:
                continue
            med = [x["median_ms"] for x in rp if x["median_ms"] is not None]
            worst = [x["worst_ms"] for x in rp if x["worst_ms"] is not None]
            rows.append(f"| {m} | `{mode}` | {sum(x['replans'] for x in rp)} | "
                        f"{sum(x['failed'] for x in rp)} | "
                        f"{sum(x.get('late_replans', 0) for x in rp)} | "
                        f"{_fmt(float(np.median(med)) if med else math.nan, '{:.1f}')} | "
                        f"{_fmt(max(worst) if worst else math.nan, '{:.1f}')} | "
                        f"{max(x['late_worst'] for x in rp)} | "
                        f"{sum(x['violations'] for x in rp)} |")
    if not rows:
        return []
    return ["## The closed loop's re-plans", "",
            ("Every rollout of a closed-loop method re-plans at every step from its own belief "
             "within the limits (surestep_ocp/evaluation/closed_loop.py); its executed motion is "
             "checked against the limits by finite differences and Pinocchio's kinematics."), "",
            "| method | mode | re-plans | kept the previous plan | longer than a step | median ms "
            "(median over configurations) | worst ms | most steps later | executed samples beyond "
            "a limit |", "|---|---|---|---|---|---|---|---|---|", *rows, ""]


def table2(records, methods, modes, gp: float, ga: float) -> list[str]:
    """The simulated Table II: grasp success share per method and rollout mode, beside the paper's
    real-robot rates."""
    lines = ["## Simulated Table II: grasp success", "",
             (f"Share of rollouts whose final true pose is within {gp * 1e3:g} mm and {ga:g} rad "
              "of the goal (over all configurations and rollouts). The paper's Table II is 60 "
              "real needle regrasps on the dVRK over four trajectory types: SURESTEP 82 %, the "
              "straight-line baseline 18 %."), "",
             "| method | " + " | ".join(f"grasp `{m}`" for m in modes) + " | paper (real robot) |",
             "|---" * (len(modes) + 2) + "|"]
    for m in methods:
        cells = [_fmt(success_share(records, mode, m)[0], "{:.1%}") for mode in modes]
        paper = {"gradient": "82 % (SURESTEP)", "baseline": "18 %"}.get(m, "")
        lines.append(f"| {m} | " + " | ".join(cells) + f" | {paper} |")
    lines.append("")
    return lines


def write_outputs(records, out: Path, methods, modes, header, spec) -> str:
    """Write table.md, raw.csv, solves.csv and boxplot.png from the finished records."""
    table = markdown(records, methods, modes, header, spec)
    write_text_atomic(out / "table.md", table + "\n")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    # a method without a plan (or whose rollouts failed) has empty values and its status in
    # `missing`, not a NaN
    w.writerow(["config", "mode", "method", "metric", "value", "missing"])
    for r in records:
        for mode in modes:
            for m in methods:
                vals = r["metrics"].get(mode, {}).get(m, {})
                why = "" if vals else r["solves"].get(m, {}).get("status", "not run")
                for k in METRICS:
                    w.writerow([r["config"], mode, m, k, repr(float(vals[k])) if k in vals else "",
                                why])
                for k, key in (("grasp_success", "success"), ("observed", "detected")):
                    v = r.get(key, {}).get(mode, {}).get(m)
                    w.writerow([r["config"], mode, m, k, "" if v is None else repr(float(v)), why])
    write_text_atomic(out / "raw.csv", buf.getvalue())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["config", "method", "success", "status", "solve_time_s", "iterations"])
    for r in records:
        for m in methods:
            s = r["solves"][m]
            w.writerow([r["config"], m, s["success"], s["status"], f"{s['solve_time_s']:.4f}",
                        s["iterations"]])
    write_text_atomic(out / "solves.csv", buf.getvalue())
    gp = getattr(spec, "grasp_position", None)
    boxplot(records, methods, modes, out / "boxplot.png", header.get("rollouts"),
            gp * 1e3 if gp else None)
    return table


def boxplot(records, methods, modes, path: Path, rollouts: int | None = None,
            grasp_mm: float | None = None) -> None:
    """Final position errors [mm] of every rollout of every configuration, per method and mode.

    Tick labels count the method's failed solves (their plans are in the boxes too).
    """
    plt = pyplot()  # (matplotlib loaded on use: keeps `surestep` start-up light)
    fig, axes = plt.subplots(1, len(modes), figsize=(1.0 + 0.75 * len(methods) * len(modes), 4.6),
                             squeeze=False, sharey=True)
    for ax, mode in zip(axes[0], modes):
        data = [np.array([e for r in records for e in r["pos_errors"].get(mode, {}).get(m, [])])
                * 1e3
                for m in methods]
        boxes = ax.boxplot([d if len(d) else [math.nan] for d in data], whis=(5, 95),
                           showfliers=True, patch_artist=True, medianprops={"color": "k"},
                           flierprops={"markersize": 1.5, "alpha": 0.4})
        # colour, line style, hollow: as in the plots
        for box, st in zip(boxes["boxes"], styles_of(methods).values()):
            box.set(facecolor=st.colour, alpha=0.6, edgecolor="k", linewidth=1.1,
                    linestyle=st.linestyle, hatch=None if st.filled else "//")
        st = _solve_stats(records, methods)
        labels = [m + (f" ({st[m]['failed']} failed)" if st[m]["failed"] else "") for m in methods]
        ax.set_xticks(range(1, len(methods) + 1), labels, rotation=45, ha="right", fontsize=8)
        ax.set_yscale("log")
        if grasp_mm:
            ax.axhline(grasp_mm, color="tab:green", linestyle="--", linewidth=1)
        ax.set_title(f"rollout mode '{mode}'")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0][0].set_ylabel("final position error ||p_T - p^G|| [mm]")
    per = f"{rollouts} rollouts" if rollouts else "rollouts"
    fig.suptitle(f"final position errors, {len(records)} configurations x {per}, pooled\n"
                 "box: quartiles (line: median), whiskers: 5th-95th percentile, dots: the "
                 "10 % beyond"
                 + ("; dashed: grasp tolerance" if grasp_mm else ""), fontsize=10)
    fig.tight_layout()
    b = io.BytesIO()
    fig.savefig(b, format="png", dpi=110)
    plt.close(fig)
    write_text_atomic(path, b.getvalue())
