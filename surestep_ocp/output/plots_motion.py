"""Pictures to look at before running a robot: joints against their limits, the
tool's speed over time.

`plot_plans` (written by `surestep compare` as `motion.png`): every method's plan at its planned
pace (waypoint t at t * step_s), each method in its `plot_styles` look. `plot_trajectory`
(written by `surestep export` as `<name>_motion.png`): the exported trajectory, its waypoints
marked. Both: one row per joint, its position against the position limits (dashed), its velocity
and its acceleration against theirs (a plan's acceleration is the change of its step velocity at
each waypoint, at rest before the first and after the last, as `model/limits/report.py` checks it);
last row the tool's translation and rotation speed.
"""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..model.limits.report import LimitsReport, rotation_angle
from ..model.robot import Robot
from .solution import write_text_atomic
from .plot_styles import style_of, styles_of


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib  # loaded on use: keeps `surestep` start-up light

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: Path, dpi: int = 90) -> Path:
    """`fig` as a PNG at `path`, written whole or not at all."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return write_text_atomic(path, buf.getvalue())


def _joint_limits(urdf: str | Path, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    lim = {}
    for j in ET.parse(str(urdf)).getroot().iter("joint"):
        el = j.find("limit")
        if el is not None and el.get("lower") is not None:
            lim[j.get("name")] = (float(el.get("lower")), float(el.get("upper")))
    lo = np.array([lim.get(n, (-np.inf, np.inf))[0] for n in names])
    hi = np.array([lim.get(n, (-np.inf, np.inf))[1] for n in names])
    return lo, hi


def _axes(plt, n: int):
    fig, axes = plt.subplots(n + 1, 3, figsize=(14, 1.55 * (n + 1) + 0.6), sharex=True,
                             squeeze=False)
    axes[-1, 2].set_axis_off()
    return fig, axes


def _limit_lines(ax, lo, hi):
    for v in (lo, hi):
        if np.isfinite(v):
            ax.axhline(v, color="k", ls="--", lw=0.8)


def plot_plans(solutions: list, urdf: str | Path, path: Path) -> Path | None:
    """`motion.png` for `surestep compare`; uses each solution's `motion_limits` report
    (limits.plan_report; a skipped report draws nothing of its plan)."""
    sols = [s for s in solutions if isinstance(s.motion_limits, LimitsReport)]
    if not sols:
        return None
    plt = pyplot()
    lim = sols[0].motion_limits.limits
    names = list(lim.joint_names)
    lo, hi = _joint_limits(urdf, names)
    vmax, amax = np.asarray(lim.velocity), np.asarray(lim.acceleration)
    fig, axes = _axes(plt, len(names))
    styles = styles_of([s.method for s in sols])
    for s in sols:
        rep = s.motion_limits
        dt = rep.step_s
        q = np.asarray(s.q, float)
        t = dt * np.arange(len(q))
        tm = dt * (np.arange(len(q) - 1) + 0.5)
        st = styles[s.method]
        steps = {"where": "mid", "lw": 0.5 * st.width, "color": st.colour,
                 "linestyle": st.linestyle, "alpha": 0.85}
        v = np.diff(q, axis=0) / dt
        # (T+1, n)
        a = np.diff(np.vstack([np.zeros((1, v.shape[1])), v, np.zeros((1, v.shape[1]))]),
                    axis=0) / dt
        for j in range(len(names)):
            axes[j, 0].plot(t, q[:, j], **st.line(ms=0.5 * st.size, lw=0.5 * st.width,
                                                  label=s.method))
            axes[j, 1].step(tm, v[:, j], **steps)
            axes[j, 2].plot(t, a[:, j], **st.line(ms=0.4 * st.size, lw=0.5 * st.width))
        axes[-1, 0].step(tm, 1e3 * np.asarray(rep.tool_speed_per_step_m_s), **steps)
        axes[-1, 1].step(tm, rep.tool_rotation_per_step_rad_s, **steps)
    _decorate(axes, names, lo, hi, vmax, amax, 1e3 * lim.tool_speed, lim.tool_rotation)
    axes[0, 0].legend(fontsize=6, ncol=2)
    fig.suptitle(f"plans at their planned pace ({sols[0].motion_limits.step_s:g} s "
                 "per step): joints' positions, velocities and accelerations against their limits, "
                 "tool speed", fontsize=9)
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out


def _decorate(axes, names, lo, hi, vmax, amax, tool_mm_s, tool_rad_s):
    for j, n in enumerate(names):
        unit = "m" if n == "insertion" else "rad"
        _limit_lines(axes[j, 0], lo[j], hi[j])
        _limit_lines(axes[j, 1], -vmax[j], vmax[j])
        _limit_lines(axes[j, 2], -amax[j], amax[j])
        axes[j, 0].set_ylabel(f"{n} [{unit}]", fontsize=7)
        axes[j, 1].set_ylabel(f"{n} [{unit}/s]", fontsize=7)
        axes[j, 2].set_ylabel(f"{n} [{unit}/s²]", fontsize=7)
    axes[-1, 0].axhline(tool_mm_s, color="k", ls="--", lw=0.8)
    axes[-1, 1].axhline(tool_rad_s, color="k", ls="--", lw=0.8)
    axes[-1, 0].set_ylabel("tool speed [mm/s]", fontsize=7)
    axes[-1, 1].set_ylabel("tool rotation [rad/s]", fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    axes[0, 0].set_title("position (dashed: limits)", fontsize=8)
    axes[0, 1].set_title("velocity (dashed: limits)", fontsize=8)
    axes[0, 2].set_title("acceleration (dashed: limits)", fontsize=8)
    axes[-2, 2].xaxis.set_tick_params(labelbottom=True)
    axes[-2, 2].set_xlabel("time [s]")
    for ax in axes.ravel():
        ax.tick_params(labelsize=6)
        ax.grid(True, alpha=0.3)


def tool_speeds(urdf: str | Path, frame: str, times: np.ndarray,
                q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool translation [m/s] and rotation [rad/s] speeds between consecutive
    samples (Pinocchio FK)."""
    robot = Robot(urdf, frame=frame)
    T = [robot.frame_pose(qi, frame) for qi in q]
    dt = np.diff(times)
    dp = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in zip(T, T[1:])]) / dt
    dr = np.array([rotation_angle(a[:3, :3], b[:3, :3]) for a, b in zip(T, T[1:])]) / dt
    return dp, dr


def plot_trajectory(traj, sol: dict, urdf: str | Path, path: Path) -> Path:
    """`<name>_motion.png` for `surestep export`: the exported trajectory against its limits."""
    plt = pyplot()
    names = traj.joint_names
    lo, hi = _joint_limits(urdf, names)
    fig, axes = _axes(plt, len(names))
    c = style_of(str(sol.get("method", ""))).colour
    t = traj.times
    for j in range(len(names)):
        axes[j, 0].plot(t, traj.q[:, j], lw=1, color=c)
        axes[j, 0].plot(traj.waypoint_times, traj.q[traj.waypoint_rows, j], "o", ms=2.5, color=c)
        axes[j, 1].plot(t, traj.qd[:, j], lw=1, color=c)
        axes[j, 2].plot(t, traj.qdd[:, j], lw=1, color=c)
    dp, dr = tool_speeds(urdf, sol["robot"].get("frame") or "tool", t, traj.q)
    tm = 0.5 * (t[1:] + t[:-1])
    axes[-1, 0].plot(tm, 1e3 * dp, lw=1, color=c)
    axes[-1, 1].plot(tm, dr, lw=1, color=c)
    lim = traj.limits
    _decorate(axes, names, lo, hi, lim.velocity, lim.acceleration, 1e3 * lim.tool_speed,
              lim.tool_rotation)
    fig.suptitle(f"{sol.get('method', 'plan')} exported: {traj.duration:.2f} s "
                 f"(planned {traj.step_s * (len(traj.waypoint_times) - 1):.2f} s), dots: the "
                 "planned waypoints", fontsize=9)
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out
