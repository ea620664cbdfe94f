"""The solve strategy picks its fallback by what failed (ocp.solve_ocp_warm)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import numpy_ekf as ref
from surestep_ocp.baseline import solve_baseline
from surestep_ocp.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.methods import ocp_initial_guess
from surestep_ocp.ocp import FALSE_VERDICTS, solve_ocp
from surestep_ocp.setup import build_setup

EVALUATION = Path(__file__).resolve().parents[1] / "problems" / "evaluations" / "evaluation.yaml"


def test_a_false_infeasibility_verdict_is_retried_with_the_monotone_barrier():
    """Evaluation configuration 73 at T = 40: Newton's plan goes below the depth bound, IPOPT with the surrogate
    Hessian and the adaptive barrier then reports the problem infeasible although its start (the straight line's IK)
    meets every bound; the monotone barrier with the same Hessian converges, and no exact-Hessian attempt runs. The
    plan meets the bound and is below the straight line, by the NumPy EKF."""
    sampler = ConfigurationSampler(load_evaluation(EVALUATION))
    prob = replace(sampler.problem(sampler.sample(0, 73)), horizon=40)
    setup = build_setup(replace(prob, solver=replace(prob.solver, codegen=False)))
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    names = [(a["hessian"], a["status"]) for a in sol.extras["attempts"]]
    assert names[0] == ("newton", "Depth_Bound_Violated")
    assert names[1][0] == "surrogate" and names[1][1] in FALSE_VERDICTS
    assert names[2] == ("surrogate, monotone barrier", "Solve_Succeeded") and len(names) == 3
    poses = np.asarray(sol.poses)
    assert poses[:, 2].min() >= setup.problem.min_depth - 1e-8
    n = setup.problem.noise
    ekf = np.trace(ref.propagate(poses, n, setup.problem.camera.intrinsics, guard=n.cosine_guard**2)[0][-1])
    assert ekf == pytest.approx(sol.trace_final, rel=1e-9)
    assert sol.trace_final < solve_baseline(setup).trace_final
