"""Re-planning after each camera move (the paper's Type 4 trajectories).

A plan made at the start assumes the camera stays where it is. When the ECM moves
(the schedule in `camera.moves`), the rest of the trajectory is re-optimised from
the current belief: the executed joints so far, the covariance carried into the
new camera frame (with the camera's own motion noise), the goal re-expressed in
the new frame (started from the straight line in that frame; see `replan`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from .belief import unvech, vech
from .errors import SurestepError
from .lie import matrix_to_pose, pose_to_matrix
from .methods import ocp_initial_guess, run_method
from .ocp import solve_ocp
from .setup import Setup
from .solution import Solution, evaluate, write_json_atomic, write_text_atomic


def _remaining_setup(setup: Setup, q_exec: np.ndarray, k: int) -> Setup:
    """The problem left at waypoint k-1 once the camera has moved to its pose for step k."""
    C = setup.camera_poses()
    changes = setup.camera_changes()
    poses = np.array([matrix_to_pose(np.linalg.inv(C[t]) @ setup.robot.base_pose @ setup.robot.frame_pose(q))
                      for t, q in enumerate(q_exec[:k])])
    sig, _ = setup.eval_model.propagate(poses, changes[: k - 1] if k > 1 else None)
    x_new, s_new = setup.eval_model.camera_change(poses[-1], vech(sig[-1]), changes[k - 1])
    sigma = unvech(np.asarray(s_new).ravel())
    goal = matrix_to_pose(np.linalg.inv(C[k]) @ C[0] @ pose_to_matrix(setup.x_goal))
    prob = setup.problem
    problem = replace(prob, horizon=prob.horizon - (k - 1), noise=replace(prob.noise, Sigma0=sigma),
                      camera=replace(prob.camera, moves=()))
    return replace(setup, problem=problem, camera_pose=C[k], q_start=q_exec[k - 1],
                   x_start=np.asarray(x_new).ravel(), x_goal=goal, camera_schedule=[])


def replan(setup: Setup, out_dir: Path, progress=None) -> dict:
    """Plan once, then re-plan after every camera move; write the plans and the executed trajectory."""
    changes = setup.camera_changes()
    if not changes or not any(c is not None for c in changes):
        raise SurestepError(f"{setup.problem.path}: camera.moves: the camera never moves; nothing to re-plan")
    out_dir = Path(out_dir)
    baseline = run_method(setup, "baseline")
    once = run_method(setup, "ocp")
    once.method = "ocp-once"
    q_exec = np.array(once.q, dtype=float)
    plans: list[Solution] = []
    total_time, total_iter = once.solve_time_s, once.iterations
    for k in [t + 1 for t, c in enumerate(changes) if c is not None]:
        if progress:
            progress(k)
        sub = _remaining_setup(setup, q_exec, k)
        # Started from the straight line in the new frame: warm starts from the remaining previous plan
        # were measured to be far worse (3000+ iterations, failures on type4_camera_moves): that plan
        # hugs the old camera's ideal point, where the covariance collapses and the problem is degenerate.
        plan = solve_ocp(sub, ocp_initial_guess(sub), method=f"ocp-replan-{k}")
        if not plan.success:
            raise SurestepError(f"re-plan at step {k}: IPOPT status {plan.status}")
        plans.append(plan)
        total_time += plan.solve_time_s
        total_iter += plan.iterations
        q_exec[k - 1 :] = np.array(plan.q)
    poses0 = np.array([setup.pose_of(q) for q in q_exec])  # first camera frame
    executed = evaluate(setup, "ocp-replanned", poses0, list(q_exec), success=True,
                        status=f"{len(plans)} re-plans", solve_time_s=total_time, iterations=total_iter,
                        objective=np.nan, extras={"replans_at_steps": [int(p.method.rsplit('-', 1)[1]) for p in plans]})
    executed.objective = executed.trace_final
    for sol in (baseline, once, executed, *plans):
        sol.save(out_dir / f"{sol.method}.json")
    rows = [(s.method, s.trace_final, s.terminal_error[0], s.solve_time_s, s.iterations)
            for s in (baseline, once, executed)]
    lines = ["| trajectory | Tr(Σ_T) with the camera moves | terminal error [m] | solve time [s] | iterations |",
             "|---|---|---|---|---|"]
    lines += [f"| {m} | {tr:.3e} | {e:.1e} | {t:.2f} | {it} |" for m, tr, e, t, it in rows]
    table = "\n".join(lines)
    write_text_atomic(out_dir / "replan.md", f"# Re-planning on `{setup.problem.path}`\n\n"
                      "`ocp-once`: planned at the start for a fixed camera, executed while the camera moves. "
                      "`ocp-replanned`: re-optimised after each camera move from the current belief.\n\n"
                      f"{table}\n")
    write_json_atomic(out_dir / "replan.json", {"problem": str(setup.problem.path), "rows": [
        {"method": m, "trace_final": tr, "terminal_error_m": e, "solve_time_s": t, "iterations": it}
        for m, tr, e, t, it in rows]})
    return {"table": table, "executed": executed, "once": once, "plans": plans}
