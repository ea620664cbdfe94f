"""The figures of `surestep compare`: `trace.png` (the covariance along each plan) and `path.png`.

Every method in its `plot_styles` look, in the given order (later on top). Methods that coincide
(ocp and ocp-from-gradient often do) stay apart: ocp is wide with large markers, ocp-from-gradient
dashed and thin over it, all slightly transparent. The figure builders return the matplotlib Figure,
so tests can read axes and legends before anything is written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model.camera import Intrinsics
from .plots_motion import pyplot, save_png
from .plot_styles import GOAL_COLOUR, START_COLOUR, styles_of


def draw_kwargs(solutions: list, k: int) -> dict:
    """`Axes.plot` keywords of the k-th of `solutions`: its style, drawn over the ones before it."""
    style = styles_of([s.method for s in solutions])[solutions[k].method]
    return style.line(zorder=2 + k, label=solutions[k].method)


def trace_figure(solutions: list):
    """Tr(Sigma_t|t) split into its position [m^2] and orientation [rad^2] blocks (log
    scale), one panel each."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, s in enumerate(solutions):
        S = np.asarray(s.sigma, float)
        diag = np.diagonal(S, axis1=1, axis2=2)
        t = np.arange(len(S))
        axes[0].semilogy(t, diag[:, :3].sum(axis=1), **draw_kwargs(solutions, k))
        axes[1].semilogy(t, diag[:, 3:].sum(axis=1), **draw_kwargs(solutions, k))
    axes[0].set_ylabel("position Tr(Σ_pp,t|t) [m²]")
    axes[1].set_ylabel("orientation Tr(Σ_rr,t|t) [rad²]")
    axes[0].set_title("position uncertainty")
    axes[1].set_title("orientation uncertainty (axis-angle)")
    for ax in axes:
        _step_axis(ax)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("EKF covariance after each observation; Tr(Σ_t|t) in the tables is the sum of the "
                 "two panels",
                 fontsize=9)
    fig.tight_layout()
    return fig


def path_figure(solutions: list):
    """Left: the tool's image projections [px] with start, goal, image border and centre;
    right: depth [mm]."""
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    intr = Intrinsics(**solutions[0].camera)
    ax1.add_patch(plt.Rectangle((0, 0), intr.width, intr.height, fill=False, color="k", lw=0.8,
                                label=f"image border ({intr.width:g} x {intr.height:g} px)"))
    ax1.plot(intr.width / 2, intr.height / 2, "k+", ms=12, zorder=20, label="image centre")
    for k, s in enumerate(solutions):
        P = np.asarray(s.poses, float)
        uv = intr.project(P[:, :3])
        ax1.plot(uv[:, 0], uv[:, 1], **draw_kwargs(solutions, k))
        ax2.plot(range(len(P)), P[:, 2] * 1e3, **draw_kwargs(solutions, k))
    start, goal = np.asarray(solutions[0].poses[0], float), np.asarray(solutions[0].goal, float)
    marks = {"start": {"marker": "o", "ms": 11, "mfc": "none", "mec": START_COLOUR, "mew": 1.6,
                       "ls": "none", "zorder": 20},
             "goal": {"marker": "*", "ms": 14, "color": GOAL_COLOUR, "ls": "none", "zorder": 20}}
    ax1.plot(*intr.project(start[:3]), label="start", **marks["start"])
    ax1.plot(*intr.project(goal[:3]), label="goal", **marks["goal"])
    ax2.plot(0, start[2] * 1e3, **marks["start"])
    for end in sorted({len(s.poses) - 1 for s in solutions}):  # each plan's end
        ax2.plot(end, goal[2] * 1e3, **marks["goal"])
    ax1.set_xlim(-0.1 * intr.width, 1.1 * intr.width)
    ax1.set_ylim(1.1 * intr.height, -0.1 * intr.height)
    ax1.set_aspect("equal")
    ax1.set_xlabel("image u [px] (right)")
    ax1.set_ylabel("image v [px] (down)")
    ax1.set_title("tool position projected into the endoscope image")
    ax1.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    ax2.axhline(float(solutions[0].noise["depth_star"]) * 1e3, color="k", ls="--", lw=1,
                label="d* (ideal depth)")
    _step_axis(ax2)
    ax2.set_ylabel("depth z [mm]")
    ax2.set_title("depth along the path (camera z)")
    ax2.legend(handles=ax2.get_lines()[-1:], fontsize=7)
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    return fig


def _step_axis(ax) -> None:
    """The x axis of the waypoint index t (a count: whole ticks, no unit)."""
    from matplotlib.ticker import MaxNLocator  # loaded on use, as in `pyplot`

    ax.set_xlabel("step t")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def write_figures(solutions: list, out_dir: Path) -> None:
    """`trace.png` and `path.png` in `out_dir`, each written whole or not at all."""
    plt = pyplot()
    for name, build in (("trace.png", trace_figure), ("path.png", path_figure)):
        fig = build(solutions)
        save_png(fig, Path(out_dir) / name, dpi=110)
        plt.close(fig)
