"""Outputs of `surestep evaluate`: table.md, raw.csv, solves.csv and boxplot.png from per-configuration records.

A record is one line of `progress.jsonl` (see `evaluation.evaluate_configuration`):
`metrics[mode][method][metric]` absolute values, `solves[method]` the solver's
outcome, `pos_errors[mode][method]` the final position error of every rollout.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from .metrics import relative
from .rollout import METRICS
from .solution import write_text_atomic

LABELS = {"pos_err_mean": "pos mean", "pos_err_std": "pos std", "ori_err_mean": "ori mean",
          "ori_err_std": "ori std", "trace_noisy": "Tr noisy", "trace_ml": "Tr ML", "entropy_noisy": "H noisy",
          "entropy_ml": "H ML"}
# The paper's Table I (relative to the baseline), rows matched to our methods.
PAPER = {
    "gradient": ("SURESTEP (all)", (0.4272, 0.5425, 0.1747, 0.4633, 0.1597, 0.1819, 0.3677, 0.5078)),
    "gradient-no-pose-loss": ("no pose loss", (0.412, 0.5205, 0.16, 0.3622, 0.1494, 0.1401, 0.3265, 0.4311)),
    "gradient-no-depth": ("no depth noise", (0.5019, 0.553, 0.2419, 0.4994, 0.2188, 0.3183, 0.5046, 0.6658)),
    "gradient-no-fov": ("no FOV noise", (0.4743, 0.5771, 0.2136, 0.5098, 0.2033, 0.246, 0.4636, 0.6016)),
    "gradient-no-orientation": ("no orientation noise",
                                (0.9862, 0.978, 0.8929, 0.9425, 0.9375, 0.9441, 0.9723, 0.9773)),
}
MODE_TEXT = {"model": "v_t ~ N(0, V(mu_t|t-1)), the noise the tracker's model expects at its estimate",
             "true": "v_t ~ N(0, V(x_true)), the noise the detector has at the true pose"}


def _values(records, mode, method, metric) -> np.ndarray:
    return np.array([r["metrics"].get(mode, {}).get(method, {}).get(metric, math.nan) for r in records], float)


def relative_means(records, methods, modes) -> dict:
    """rel[mode][method][metric] = (mean over configurations of relative(y_c, b_c), configurations used)."""
    rel: dict = {}
    for mode in modes:
        rel[mode] = {}
        for m in methods:
            rel[mode][m] = {}
            for k in METRICS:
                y, b = _values(records, mode, m, k), _values(records, mode, "baseline", k)
                r = np.array([relative(yi, bi) if np.isfinite(yi) and np.isfinite(bi) else math.nan
                              for yi, bi in zip(y, b)])
                ok = np.isfinite(r)
                rel[mode][m][k] = (float(np.mean(r[ok])) if ok.any() else math.nan, int(ok.sum()))
    return rel


def _fmt(v: float, f: str = "{:.3f}") -> str:
    return "n/a" if v is None or not np.isfinite(v) else f.format(v)


def _solve_stats(records, methods) -> dict:
    st = {}
    for m in methods:
        s = [r["solves"][m] for r in records if m in r["solves"]]
        st[m] = {"failed": sum(not x["success"] for x in s), "no_plan": sum(not x["evaluated"] for x in s),
                 "time": float(np.mean([x["solve_time_s"] for x in s])) if s else math.nan,
                 "iters": float(np.median([x["iterations"] for x in s])) if s else math.nan}
    return st


def markdown(records, methods, modes, header, spec) -> str:
    rel, st = relative_means(records, methods, modes), _solve_stats(records, methods)
    n = len(records)
    lines = [f"# Evaluation on `{spec.path}`", "",
             f"{n} random configurations (seed {header['seed']}, base problem `{spec.base_path.name}`, horizon "
             f"T = {spec.horizon}), {header['rollouts']} noisy closed-loop rollouts per plan and rollout mode; "
             "every plan evaluated with all observation components.", "",
             "**How the relative numbers are made.** For configuration c, method m and metric k, let y = the "
             "method's absolute value and b = the baseline's on the same configuration (same rollout noise "
             "draws). The per-configuration ratio is the paper's scaling (`metrics.relative`): y / b when both "
             "are positive, 1 - (y - b) / b when both are negative (entropies), undefined (excluded) for mixed "
             "signs. Each cell is the mean of these ratios over configurations (lower is better, baseline = 1). "
             "pos/ori = final position error ||p_T^true - p^G|| and geodesic orientation error "
             "angle(R_T^true, R^G), mean and sample std over the rollouts of one configuration; Tr noisy and "
             "H noisy = Tr(Sigma_T) and Gaussian entropy of the rollouts' EKF, mean over rollouts; Tr ML and "
             "H ML = the plan's own maximum-likelihood Sigma_T.", "",
             "**Failed solves** are counted in the `failed` column and are not dropped: a plan whose solver "
             "reported failure is still rolled out and averaged in; only a method that produced no plan at all "
             "(`no plan`) is left out of that configuration's averages (`n` = configurations averaged).", ""]
    cols = [LABELS[k] for k in METRICS]
    for mode in modes:
        lines += [f"## Rollout mode `{mode}`: {MODE_TEXT[mode]}", "",
                  "| method | " + " | ".join(cols) + " | n | failed | no plan | solve time [s] | iters (median) |",
                  "|---" * (len(cols) + 6) + "|"]
        for m in methods:
            cells = [_fmt(rel[mode][m][k][0]) for k in METRICS]
            used = min(rel[mode][m][k][1] for k in METRICS)
            lines.append(f"| {m} | " + " | ".join(cells) + f" | {used} | {st[m]['failed']} | {st[m]['no_plan']} | "
                         f"{_fmt(st[m]['time'], '{:.2f}')} | {_fmt(st[m]['iters'], '{:.0f}')} |")
        lines += ["", f"Beside the paper's Table I (cells: ours / paper), mode `{mode}`:", "",
                  "| ours | paper | " + " | ".join(cols) + " |", "|---" * (len(cols) + 2) + "|"]
        for m, (label, vals) in PAPER.items():
            if m in methods:
                cells = [f"{_fmt(rel[mode][m][k][0])} / {p:.3f}" for k, p in zip(METRICS, vals)]
                lines.append(f"| {m} | {label} | " + " | ".join(cells) + " |")
        lines += ["", f"Absolute values, mean over configurations, mode `{mode}` (pos in mm, ori in mrad):", "",
                  "| method | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
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
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def write_outputs(records, out: Path, methods, modes, header, spec) -> str:
    """Write table.md, raw.csv, solves.csv and boxplot.png from the finished records."""
    table = markdown(records, methods, modes, header, spec)
    write_text_atomic(out / "table.md", table + "\n")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["config", "mode", "method", "metric", "value"])
    for r in records:
        for mode in modes:
            for m in methods:
                vals = r["metrics"].get(mode, {}).get(m, {})
                for k in METRICS:
                    w.writerow([r["config"], mode, m, k, repr(float(vals.get(k, math.nan)))])
    write_text_atomic(out / "raw.csv", buf.getvalue())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["config", "method", "success", "status", "solve_time_s", "iterations"])
    for r in records:
        for m in methods:
            s = r["solves"][m]
            w.writerow([r["config"], m, s["success"], s["status"], f"{s['solve_time_s']:.4f}", s["iterations"]])
    write_text_atomic(out / "solves.csv", buf.getvalue())
    boxplot(records, methods, modes, out / "boxplot.png", header.get("rollouts"))
    return table


def boxplot(records, methods, modes, path: Path, rollouts: int | None = None) -> None:
    """Final position errors [mm] of every rollout of every configuration, per method and mode.

    Tick labels count the method's failed solves (their plans are in the boxes too).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(modes), figsize=(1.0 + 0.75 * len(methods) * len(modes), 4.6), squeeze=False,
                             sharey=True)
    for ax, mode in zip(axes[0], modes):
        data = [np.array([e for r in records for e in r["pos_errors"].get(mode, {}).get(m, [])]) * 1e3
                for m in methods]
        ax.boxplot([d if len(d) else [math.nan] for d in data], showfliers=True, flierprops={"markersize": 2})
        st = _solve_stats(records, methods)
        labels = [m + (f" ({st[m]['failed']} failed)" if st[m]["failed"] else "") for m in methods]
        ax.set_xticks(range(1, len(methods) + 1), labels, rotation=45, ha="right", fontsize=8)
        ax.set_yscale("log")
        ax.set_title(f"rollout mode '{mode}'")
        ax.grid(True, axis="y", which="both", alpha=0.3)
    axes[0][0].set_ylabel("final position error ||p_T - p^G|| [mm]")
    per = f"{rollouts} rollouts" if rollouts else "rollouts"
    fig.suptitle(f"final position errors, {len(records)} configurations x {per}, pooled")
    fig.tight_layout()
    b = io.BytesIO()
    fig.savefig(b, format="png", dpi=110)
    plt.close(fig)
    write_text_atomic(path, b.getvalue())
