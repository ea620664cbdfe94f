"""The simulated Table II's figure: one rollout's executed error against time, per method.

Two panels: the true tool position's distance to the goal, and the tracker's error (true position
minus the EKF mean), both [mm], against time [s] (each step `STEP_S`: the type files' and the
robot's pace share the step length; the robot's pace has twice the steps). One rollout (the first)
of each method that kept its paths (`success_table(..., keep_paths=True)`), in one mode.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..output.plot_styles import styles_of
from ..output.plots_motion import pyplot, save_png

STEP_S = 0.05  # [s] the type files' step (timing.step_s's default)
TYPE = "Type 1 medium"


def error_figure(res: dict, path: Path, label: str = TYPE, mode: str = "true", rollout: int = 0):
    """Write the figure of `res[label]` (success_table's results kept with paths) to `path`."""
    row = {m: cell["paths"][mode] for m, cell in res[label].items() if cell.get("paths")}
    if not row:
        raise ValueError(f"no rollout paths kept for {label}: success_table(..., keep_paths=True)")
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    looks = styles_of(list(row))
    for k, (m, ro) in enumerate(row.items()):
        true, est = ro.true_path[rollout], ro.estimate_path[rollout]
        # up to its end (a closed-loop rollout holds still after it)
        moved = np.flatnonzero(np.any(np.diff(true, axis=0) != 0, axis=1))
        true, est = true[:moved[-1] + 2], est[:moved[-1] + 2]
        t = np.arange(len(true)) * STEP_S
        look = looks[m].line(zorder=2 + k, label=m, ms=3)
        axes[0].plot(t, np.linalg.norm(true[:, :3] - ro.goal[:3], axis=1) * 1e3, **look)
        # (from the first step: the start is known exactly)
        axes[1].plot(t[1:], np.linalg.norm(true[1:, :3] - est[1:, :3], axis=1) * 1e3, **look)
    axes[0].set_ylabel("true position to goal [mm]")
    axes[1].set_ylabel("tracker error |p_true - p_mean| [mm]")
    axes[0].set_yscale("log")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("time [s]")
        ax.grid(True, alpha=0.3)
    axes[0].set_title(f"{label}, rollout {rollout}, mode {mode}: executed")
    axes[1].set_title("what the tracker believes")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    save_png(fig, path)
    plt.close(fig)
