"""The simulated Table II per scenario type: grasp success of each method on the paper's
trajectory types.

    .venv/bin/python -m surestep_ocp.evaluation.table2 [--rollouts 500] [--seed 0]
        [--output benchmarks/results/...md]

The paper's Table II is 60 regrasps on the real dVRK over four trajectory types. Here each
type is its problem file (`problems/type*.yaml`: one configuration each, Type 1 easy /
medium / hard, Type 2, Type 3, Type 4), every method plans once, and each plan runs
`--rollouts` noisy closed-loop rollouts per mode with the evaluation's detection model
(`rollout.Detection`) and grasp tolerances (`configs.GRASP_POSITION_M`, `GRASP_ANGLE_RAD`);
Types 3 and 4 roll out through the camera moves (`rollout(..., changes=...)`). Type 4 adds
`ocp-replanned`: every rollout re-plans after each camera move from its own EKF mean and
covariance (`RolloutReplanner`, a `Planner` hook of `rollout`: one Newton solver per remaining
horizon, built once, shared by the rollouts), the paper's protocol; and `ocp-replanned-ml`, the
previous reading: one trajectory re-optimised after each move from the plan's maximum-likelihood
belief (`replan.replan`), executed by every rollout. Rollouts of type k in mode m use
`default_rng([seed, k, m])` for every method (the re-plans draw nothing).
"""

from __future__ import annotations

import argparse
import copy
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import SurestepError
from ..model.grasp import within
from ..model.lie import matrix_to_pose
from ..output.solution import write_text_atomic
from ..problem.load import load_problem
from ..problem.setup import build_setup
from ..problem.spec import GRADIENT_PRESETS, GradientSpec
from ..methods.registry import run_method
from ..methods.planner import Planner
from ..methods.camera_move_replan import replan_after_camera_moves
from .configs import GRASP_ANGLE_RAD, GRASP_POSITION_M
from .closed_loop import ClosedLoop, robot_pace
from .table2_figure import error_figure
from .rollout import MODES, Detection, rollout

TYPES = [("Type 1 easy", "type1_easy.yaml"), ("Type 1 medium", "type1_medium.yaml"),
         ("Type 1 hard (dim light)", "type1_hard.yaml"),
         ("Type 2 (needle arm moves)", "type2_needle_arm_moves.yaml"),
         ("Type 3 (camera moves once)", "type3_camera_moves_once.yaml"),
         ("Type 4 (camera moves 4x, re-planned)", "type4_camera_moves.yaml")]
METHODS = ("baseline", "gradient", "gradient-paper", "gradient-no-pose-loss", "ocp", "ocp-expected")


def plans(setup, methods=METHODS, replanned: bool = False) -> dict:
    """Each method's waypoints, each in its step's camera frame (as `Solution.poses` holds them:
    `evaluate` re-expresses a plan made in the first camera frame); `gradient-paper` is `gradient`
    with `preset: paper`."""
    out = {}
    for m in methods:
        if m == "gradient-paper":
            spec = replace(GradientSpec(), **GRADIENT_PRESETS["paper"], preset="paper")
            s = setup.with_ocp(gradient=spec)
            sol = run_method(s, "gradient")
        else:
            sol = run_method(setup, m)
        out[m] = (np.asarray(sol.poses, float), sol.success)
    if replanned:
        with tempfile.TemporaryDirectory() as d:
            res = replan_after_camera_moves(setup, Path(d))
        out["ocp-replanned-ml"] = (np.asarray(res["executed"].poses, float), True)
    return out


class RolloutReplanner:
    """`rollout`'s `replan` hook for Type 4: each rollout re-plans after each camera move from its
    own belief.

    At the move before step t -> t+1, rollout i's EKF mean and covariance (in the new camera frame)
    go to its own copy of one `Planner` (`replan(mean_i, cov_i, camera_pose=C[t+1], step=t)`: warm
    from that rollout's previous plan, over the steps left, the goal's joints kept); the copies
    share the Planner's solvers (one per remaining horizon, built once). The new plan's joints give
    rollout i's waypoints t+1..T, each in its step's camera frame. A re-plan that fails (an
    unreachable mean, a solver failure) keeps that rollout's previous waypoints and is counted in
    `failures`. `times` holds each re-plan's time without builds [s].
    """

    def __init__(self, setup, planner=None):
        self.setup = setup
        self.planner = Planner(setup, prebuild=False) if planner is None else planner
        self.cameras = setup.camera_poses()
        self.times: list[float] = []
        self.failures: list[tuple[int, int, str]] = []  # (step, rollout, why)
        # each rollout's Planner copy (its current plan), after the first move
        self.planners: list | None = None

    def initial_poses(self) -> np.ndarray:
        """(T+1, 6) the first plan (for the first camera pose), each waypoint in its step's camera
        frame."""
        return self.poses_in_step_frames(np.asarray(self.planner.plan.q, float), 0)

    def reset(self) -> None:
        """Start over: the next rollout call's rollouts begin from the first plan."""
        self.planners = None

    def poses_in_step_frames(self, q: np.ndarray, first: int) -> np.ndarray:
        """(len(q), 6) the tracked frame at joints q[j] in the camera frame of step first + j."""
        robot = self.setup.robot
        return np.array([matrix_to_pose(np.linalg.inv(self.cameras[first + j])
                                        @ robot.base_pose @ robot.frame_pose(qj))
                         for j, qj in enumerate(np.asarray(q, float))])

    def __call__(self, t: int, mean: np.ndarray, cov: np.ndarray,
                 waypoints: np.ndarray) -> np.ndarray:
        if self.planners is None or len(self.planners) != len(mean):
            # shallow: the solvers are shared
            self.planners = [copy.copy(self.planner) for _ in range(len(mean))]
        out = np.array(waypoints, float)
        for i, planner in enumerate(self.planners):
            t0 = time.perf_counter()
            try:
                sol = planner.replan(mean[i], cov[i], camera_pose=self.cameras[t + 1], step=t)
            except SurestepError as exc:  # e.g. a mean the arm cannot reach
                self.times.append(time.perf_counter() - t0)
                self.failures.append((t, i, str(exc)))
                continue
            self.times.append(sol.replan.time_s)
            if not sol.success:
                self.failures.append((t, i, f"{sol.run.solver}: {sol.status}"))
                continue
            out[i, t + 1:] = self.poses_in_step_frames(np.asarray(sol.q, float)[1:], t + 1)
        return out


def _record(ro, grasp) -> dict:
    hit = within(ro.pos_err, ro.ori_err, *grasp)
    return {"share": float(np.mean(hit)), "median_mm": float(np.median(ro.pos_err) * 1e3),
            "p90_mm": float(np.percentile(ro.pos_err, 90) * 1e3),
            "max_mm": float(np.max(ro.pos_err) * 1e3)}


def _store(cell: dict, mode: str, ro, grasp) -> None:
    """A rollout run's grasp share and final position errors into a table cell, per mode."""
    r = _record(ro, grasp)
    cell[mode] = r["share"]
    for key in ("median_mm", "p90_mm", "max_mm"):
        cell[f"{mode}_{key}"] = r[key]


def closed_loop_rows(problem, k: int, rollouts: int, seed: int, detection, grasp,
                     keep_paths: bool = False) -> dict:
    """The type at the robot's pace (`closed_loop.robot_pace`): `ocp-robot-pace`, its first plan
    within the limits run once (open loop), and `ocp-mpc`, re-planned at every frame by every
    rollout (`closed_loop.ClosedLoop`), each `rollouts` rollouts per mode with the type's random
    numbers; `ocp-mpc` has its re-plans' figures under "replans" (per mode) and its executed samples
    beyond a limit under "violations"; with `keep_paths`, each row's rollouts under "paths"
    (per mode)."""
    setup = build_setup(robot_pace(problem))
    changes = setup.camera_changes()
    policy = ClosedLoop(setup)
    once = setup.in_step_frames(np.asarray(policy.first_plan.poses, float))
    goal = once[-1]
    rows = {"ocp-robot-pace": {"solved": True, "rollouts": rollouts},
            "ocp-mpc": {"solved": True, "rollouts": rollouts, "replans": {}, "violations": 0}}
    for name, cell in rows.items():
        cell["paths"] = {}
        for mi, mode in enumerate(MODES):
            policy.reset()
            t0 = time.perf_counter()
            ro = rollout(setup.eval_model, once if name == "ocp-robot-pace" else once[[0, -1]],
                         goal, rollouts, np.random.default_rng([seed, k, mi]), mode,
                         detection=detection, changes=changes, keep_paths=keep_paths,
                         policy=policy if name == "ocp-mpc" else None)
            _store(cell, mode, ro, grasp)
            if keep_paths:
                cell["paths"][mode] = ro
            if name == "ocp-mpc":
                summary = policy.summary()
                summary["wall_s"] = time.perf_counter() - t0
                cell["replans"][mode] = summary
                cell["violations"] += summary["violations"]
    return rows


def success_table(problems_dir: Path, rollouts: int = 500, seed: int = 0,
                  detection: Detection | None = Detection(),
                  grasp=(GRASP_POSITION_M, GRASP_ANGLE_RAD), types=TYPES, methods=METHODS,
                  replan_rollouts: int | None = None, closed_loop_rollouts: int | None = None,
                  keep_paths: bool = False) -> tuple[str, dict]:
    """(Markdown tables, results[type][method][mode] = success share) over the scenario types.

    `replan_rollouts`: rollouts per mode of Type 4's per-rollout re-planning (`ocp-replanned`;
    default `rollouts`; 0 leaves it out); results[type]["ocp-replanned"]["replans"] has its
    re-plans' count, failures and times. `closed_loop_rollouts`: rollouts per mode of every type at
    the robot's pace (`closed_loop_rows`: `ocp-robot-pace` and `ocp-mpc`; default `rollouts`; 0
    leaves them out). Each cell also has the final position errors' median and 90th percentile
    (`<mode>_median_mm`, `<mode>_p90_mm`).
    """
    replan_rollouts = rollouts if replan_rollouts is None else replan_rollouts
    closed_loop_rollouts = rollouts if closed_loop_rollouts is None else closed_loop_rollouts
    res: dict = {}
    for k, (label, fname) in enumerate(types):
        problem = load_problem(problems_dir / fname)
        setup = build_setup(problem)
        changes = setup.camera_changes()
        type4 = fname.startswith("type4")
        res[label] = {}
        for m, (poses, ok) in plans(setup, methods, replanned=type4).items():
            # (step frames already: re-expressing them again, as before, moved every waypoint after
            # a camera move and the goal by the camera's motion on Types 3 and 4)
            res[label][m] = {"solved": ok}
            for mi, mode in enumerate(MODES):
                ro = rollout(setup.eval_model, poses, poses[-1], rollouts,
                             np.random.default_rng([seed, k, mi]), mode, detection=detection,
                             changes=changes, keep_paths=keep_paths)
                _store(res[label][m], mode, ro, grasp)
                if keep_paths:
                    res[label][m].setdefault("paths", {})[mode] = ro
        if type4 and replan_rollouts > 0:
            hook = RolloutReplanner(setup)
            poses = hook.initial_poses()
            res[label]["ocp-replanned"] = {"solved": hook.planner.plan.success,
                                           "rollouts": replan_rollouts}
            t0 = time.perf_counter()
            for mi, mode in enumerate(MODES):
                hook.reset()
                ro = rollout(setup.eval_model, poses, poses[-1], replan_rollouts,
                             np.random.default_rng([seed, k, mi]), mode, detection=detection,
                             changes=changes, replan=hook)
                _store(res[label]["ocp-replanned"], mode, ro, grasp)
            times = np.asarray(hook.times)
            res[label]["ocp-replanned"]["replans"] = {
                "count": len(times), "failed": len(hook.failures),
                "wall_s": time.perf_counter() - t0, "median_ms": float(np.median(times) * 1e3),
                "p95_ms": float(np.percentile(times, 95) * 1e3),
                "max_ms": float(times.max() * 1e3), "build_s": hook.planner.build_time_s,
                "failures": hook.failures[:5]}
        if closed_loop_rollouts > 0:
            res[label].update(closed_loop_rows(problem, k, closed_loop_rollouts, seed, detection,
                                               grasp, keep_paths=keep_paths))
    return _tables(res, rollouts, grasp), res


def _tables(res: dict, rollouts: int, grasp) -> str:
    """The Markdown of `success_table`'s results: grasp shares, final position errors, notes."""
    all_methods = list(dict.fromkeys(m for t in res.values() for m in t))
    head = ["| type | " + " | ".join(all_methods) + " |", "|---" * (len(all_methods) + 1) + "|"]
    lines = [(f"Grasp success (final true pose within {grasp[0] * 1e3:g} mm and {grasp[1]:g} rad "
              f"of the goal), {rollouts} rollouts per plan and mode, cells `model` / `true`:"), "",
             *head]
    for label, row in res.items():
        cells = ["" if row.get(m) is None
                 else f"{row[m]['model']:.0%} / {row[m]['true']:.0%}"
                 + ("" if row[m]["solved"] else " (failed)") for m in all_methods]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    mean = {m: [np.mean([row[m][mode] for row in res.values()]) for mode in MODES]
            for m in all_methods if all(m in row for row in res.values())}
    lines.append("| mean over types | "
                 + " | ".join(f"{mean[m][0]:.0%} / {mean[m][1]:.0%}" if m in mean else ""
                              for m in all_methods) + " |")
    lines += ["", "Final position error [mm], median / 90th percentile, `model`; `true`:", "",
              *head]
    for label, row in res.items():
        cells = ["" if row.get(m) is None else "; ".join(
            f"{row[m][f'{mode}_median_mm']:.1f} / {row[m][f'{mode}_p90_mm']:.1f}"
            for mode in MODES) for m in all_methods]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["",
              ("Paper (Table II, real dVRK, 60 regrasps over the four types): SURESTEP "
               "82 %, baseline 18 %.")]
    for mode in MODES:
        worst = max((row[m][f"{mode}_max_mm"], label, m) for label, row in res.items() for m in row)
        lines += ["",
                  (f"Worst final position error of any rollout, mode `{mode}`: {worst[0]:.1f} mm "
                   f"({worst[1]}, {worst[2]}).")]
    for label, row in res.items():
        rp = row.get("ocp-replanned", {}).get("replans")
        if rp:
            lines += ["",
                      (f"{label}, `ocp-replanned`: every rollout re-plans after each camera move "
                       f"from its own EKF mean and covariance ({row['ocp-replanned']['rollouts']} "
                       "rollouts per mode); `ocp-replanned-ml`: one trajectory re-planned from "
                       f"the maximum-likelihood belief, run by every rollout. {rp['count']} "
                       f"re-plans, {rp['failed']} failed (previous plan kept); per re-plan "
                       f"{rp['median_ms']:.1f} ms median, {rp['p95_ms']:.1f} ms p95, "
                       f"{rp['max_ms']:.1f} ms worst (builds apart: {rp['build_s']:.1f} s); "
                       f"{rp['wall_s']:.0f} s for both modes' rollouts.")]
            lines += [f"  failed: step {t}, rollout {i}: {why}" for t, i, why in rp["failures"]]
    mpc = {label: row["ocp-mpc"] for label, row in res.items() if "ocp-mpc" in row}
    if mpc:
        lines += ["", ("`ocp-robot-pace` and `ocp-mpc`: the type at the robot's pace (twice the "
                       "steps of 0.05 s, the camera moves at the same times, the limits enforced); "
                       "`ocp-robot-pace` runs its first plan once, `ocp-mpc` re-plans at every "
                       "frame from each rollout's own belief within the limits "
                       "(surestep_ocp/evaluation/closed_loop.py). Its re-plans (both modes):"), "",
                  "| type | re-plans | failed (previous plan kept) | longer than a step "
                  "| median ms | p90 ms | worst ms | steps later (median, worst) "
                  "| executed samples beyond a limit |", "|---|---|---|---|---|---|---|---|---|"]
        for label, cell in mpc.items():
            r = list(cell["replans"].values())
            lines.append(f"| {label} | {sum(x['replans'] for x in r)} | "
                         f"{sum(x['failed'] for x in r)} | {sum(x['late_replans'] for x in r)} | "
                         f"{max(x['median_ms'] for x in r):.1f} | {max(x['p90_ms'] for x in r):.1f}"
                         f" | {max(x['worst_ms'] for x in r):.1f} | "
                         f"{max(x['late_median'] for x in r):g}, {max(x['late_worst'] for x in r)}"
                         f" | {cell['violations']} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    root = Path(__file__).resolve().parents[2]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default=str(root / "problems"))
    ap.add_argument("--rollouts", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--replan-rollouts", type=int, default=None,
                    help="rollouts per mode of Type 4's per-rollout re-planning (default "
                         "--rollouts; 0: leave out)")
    ap.add_argument("--closed-loop-rollouts", type=int, default=None,
                    help="rollouts per mode of every type at the robot's pace (ocp-robot-pace, "
                         "ocp-mpc; default --rollouts; 0: leave out)")
    ap.add_argument("--figure", default=None,
                    help="also write a PNG of one rollout's executed error against time per method "
                         "(Type 1 medium, mode true)")
    ap.add_argument("--output", default=str(root / "benchmarks" / "results"
                                            / "evaluation_table2_types.md"))
    args = ap.parse_args(argv)
    table, res = success_table(Path(args.problems), args.rollouts, args.seed,
                               replan_rollouts=args.replan_rollouts,
                               closed_loop_rollouts=args.closed_loop_rollouts,
                               keep_paths=args.figure is not None)
    extra = "".join(f" --{k.replace('_', '-')} {v}" for k, v in vars(args).items()
                    if k in ("replan_rollouts", "closed_loop_rollouts", "figure")
                    and v is not None)
    if args.figure:
        error_figure(res, Path(args.figure))
    cmd = (f"`.venv/bin/python -m surestep_ocp.evaluation.table2 --rollouts {args.rollouts} --seed "
           f"{args.seed}{extra}`")
    write_text_atomic(Path(args.output),
                      f"# Simulated Table II per scenario type\n\n{cmd}\n\n{table}\n")
    print(table)


if __name__ == "__main__":
    main()
