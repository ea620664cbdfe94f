"""Re-planning after each camera move (the paper's Type 4 trajectories).

A plan made at the start assumes the camera stays where it is. When the ECM moves
(the schedule in `camera.moves`), the rest of the trajectory is re-optimised from
the current belief: the executed joints so far, the covariance carried into the
new camera frame (with the camera's own motion noise), the goal re-expressed in
the new frame (a `Planner`: warm-started from the previous plan, over the steps left).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..model.belief import unvech, vech
from ..errors import SurestepError
from ..model.lie import matrix_to_pose, np_means, np_poses
from .registry import run_method
from ..output.files import check_finite
from .planner import Planner
from ..problem.setup import Setup
from ..output.solution import Solution, write_json_atomic, write_text_atomic
from ..ocp.plan_evaluation import evaluate


def _belief_after_move(setup: Setup, q_exec: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The belief at waypoint k-1 (mean, covariance) once the camera has moved to its pose for step
    k, in the new camera frame: the EKF along the executed joints, then the camera's move (with its
    own motion noise)."""
    C = setup.camera_poses()
    changes = setup.camera_changes()
    poses = np.array([matrix_to_pose(np.linalg.inv(C[t]) @ setup.robot.base_pose
                                     @ setup.robot.frame_pose(q))
                      for t, q in enumerate(q_exec[:k])])
    sig, _ = setup.eval_model.propagate(poses, changes[: k - 1] if k > 1 else None)
    m_new, s_new = setup.eval_model.camera_change(np_means(poses[-1])[0], vech(sig[-1]),
                                                  changes[k - 1])
    return np_poses(m_new, flip_w=0.0)[0], unvech(s_new)  # the principal vector


def replan_after_camera_moves(setup: Setup, out_dir: Path, progress=None) -> dict:
    """Plan once, then re-plan after every camera move; write the plans and the executed trajectory.

    One `Planner` makes every plan: each re-plan starts from the previous plan's rest (warm), over
    the steps left; its solvers are built once per horizon, and their build time is reported apart
    from the solve time.
    """
    changes = setup.camera_changes()
    if not changes or not any(c is not None for c in changes):
        raise SurestepError(f"{setup.ocp.source}: camera.moves: the camera never moves; nothing "
                            "to re-plan")
    out_dir = Path(out_dir)
    baseline = run_method(setup, "baseline")
    planner = Planner(setup, prebuild=False)
    first = planner.plan  # planned for the first camera pose, evaluated below with the camera moves
    once = evaluate(setup, "ocp-once", np.array(first.poses), first.q, success=first.success,
                    status=first.status, solve_time_s=first.solve_time_s,
                    iterations=first.iterations, objective=first.objective,
                    run=first.run, extras=first.extras)
    once = once.replaced(motion_limits=first.motion_limits)
    q_exec = np.array(once.q, dtype=float)
    plans: list[Solution] = []
    total_time, total_iter = once.solve_time_s, once.iterations
    C = setup.camera_poses()
    for k in [t + 1 for t, c in enumerate(changes) if c is not None]:
        if progress:
            progress(k)
        mean, sigma = _belief_after_move(setup, q_exec, k)
        plan = planner.replan(mean, sigma, camera_pose=C[k], step=k - 1).replaced(
            method=f"ocp-replan-{k}")
        if not plan.success:
            raise SurestepError(f"re-plan at step {k}: {plan.run.solver} "
                                f"status {plan.status}")
        plans.append(plan)
        total_time += plan.replan.time_s
        total_iter += plan.iterations
        q_exec[k - 1 :] = np.array(plan.q)
    poses0 = np.array([setup.pose_of(q) for q in q_exec])  # first camera frame
    executed = evaluate(setup, "ocp-replanned", poses0, list(q_exec), success=True,
                        status=f"{len(plans)} re-plans", solve_time_s=total_time,
                        iterations=total_iter, objective=np.nan,
                        extras={"replans_at_steps": [int(p.method.rsplit('-', 1)[1])
                                                     for p in plans]})
    executed = executed.replaced(objective=executed.trace_final)
    solutions = (baseline, once, executed, *plans)
    # every solution checked before any file is written: the set is written whole or not at all
    for sol in solutions:
        check_finite(sol.to_dict(), f"the {sol.method} solution")
    for sol in solutions:
        sol.save(out_dir / f"{sol.method}.json")
    rows = [(s.method, s.trace_final, s.terminal_error[0], s.solve_time_s, s.iterations)
            for s in (baseline, once, executed)]
    lines = [("| trajectory | Tr(Σ_T) with the camera moves | terminal error [m] | solve time "
              "[s] | iterations |"),
             "|---|---|---|---|---|"]
    lines += [f"| {m} | {tr:.3e} | {e:.1e} | {t:.2f} | {it} |" for m, tr, e, t, it in rows]
    table = "\n".join(lines)
    write_text_atomic(out_dir / "replan.md",
                      f"# Re-planning on `{setup.ocp.source}`\n\n`ocp-once`: planned at the start "
                      "for a fixed camera, executed while the camera moves. `ocp-replanned`: "
                      f"re-optimised after each camera move from the current belief.\n\n{table}\n")
    write_json_atomic(out_dir / "replan.json", {"problem": str(setup.ocp.source), "rows": [
        {"method": m, "trace_final": tr, "terminal_error_m": e, "solve_time_s": t, "iterations": it}
        for m, tr, e, t, it in rows]})
    return {"table": table, "executed": executed, "once": once, "plans": plans,
            "build_time_s": planner.build_time_s, "solve_time_s": total_time,
            "builds": planner.builds}
