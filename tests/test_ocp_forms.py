"""The OCP's covariance forms are transcriptions of one problem: they must agree."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.problem.solver_config import resolve_form
from surestep_ocp.solvers.iterate import InitialGuess
from surestep_ocp.solvers.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup

DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"


def ipopt(problem):
    """The forms are IPOPT transcriptions: the condensed reference is solved by IPOPT too."""
    return replace(problem, solver=replace(problem.solver, name="ipopt"))


@pytest.fixture(scope="module")
def small():
    setup = build_setup(ipopt(replace(load_problem(DEFAULT), horizon=5)))
    cond = solve_ocp(setup, ocp_initial_guess(setup), form="condensed")
    # the full form started at the condensed optimum: a KKT point of one is one of the other
    full = solve_ocp(setup, InitialGuess(np.array(cond.q), "condensed optimum"), form="full")
    return setup, {"full": full, "condensed": cond}


def test_auto_picks_condensed_for_the_papers_isotropic_constants(small):
    """The paper's constants are multiples of I, so the scalar recursion is exact and chosen."""
    setup, _ = small
    assert setup.model.diagonal
    assert resolve_form(setup.model, "auto") == "condensed"


def test_full_and_condensed_forms_agree(small):
    """Multiple shooting of vech(Sigma) with free gains keeps the condensed recursion's optimum (same problem).

    (From the straight line the two forms may reach different local optima: the problem is nonconvex.)
    """
    _, sols = small
    full, cond = sols["full"], sols["condensed"]
    assert full.success and cond.success, (full.status, cond.status)
    assert full.trace_final == pytest.approx(cond.trace_final, rel=1e-5)
    np.testing.assert_allclose(np.array(full.poses), np.array(cond.poses), atol=1e-4)
    # each form's own covariance equals the exact EKF's at its optimum
    for sol in (full, cond):
        assert sol.extras["ocp_trace_final"] == pytest.approx(sol.trace_final, rel=1e-6)


def test_diagonal_form_solves_and_matches_the_exact_ekf():
    """The multiple-shooting diagonal form (six scalars and gains per node) builds, solves, and is exact.

    From the straight line at T = 3 it reaches the condensed form's optimum. (The lifted forms are
    fragile where the covariance collapses: started from the condensed optimum at T = 5 it failed
    after a change of 3e-16 rad in the start, see ocp.py; so the start here is the straight line.)
    """
    setup = build_setup(ipopt(replace(load_problem(DEFAULT), horizon=3)))
    init = ocp_initial_guess(setup)
    cond = solve_ocp(setup, init, form="condensed")
    diag = solve_ocp(setup, init, form="diagonal")
    assert diag.success and cond.success, (diag.status, cond.status)
    assert diag.trace_final == pytest.approx(cond.trace_final, rel=1e-6)
    assert diag.extras["ocp_trace_final"] == pytest.approx(diag.trace_final, rel=1e-6)


def test_isotropic_noise_with_a_full_sigma0_runs_scalar_recursions_on_its_eigenvalues():
    """The paper's constants are multiples of I: from a non-diagonal Sigma_0 (after a camera move) the EKF is six
    scalar recursions on Sigma_0's eigenvalues. The condensed OCP uses them; its trace equals a NumPy EKF's."""
    from numpy_ekf import propagate
    from scipy.spatial.transform import Rotation

    prob = load_problem(DEFAULT)
    U = np.eye(6)
    U[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    U[3:, 3:] = Rotation.from_rotvec([-0.4, 0.1, 0.2]).as_matrix()
    sigma0 = U @ np.diag([4e-3, 1e-2, 2e-2, 5e-3, 8e-3, 3e-2]) @ U.T
    setup = build_setup(replace(prob, horizon=6, noise=replace(prob.noise, Sigma0=sigma0)))
    assert not setup.model.diagonal and setup.model.isotropic and setup.model.scalar
    assert resolve_form(setup.model, "auto") == "condensed"
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    assert sol.success, sol.status
    sig, _ = propagate(np.array(sol.poses), setup.problem.noise, setup.problem.camera.intrinsics, guard=COSINE_GUARD)
    assert sol.extras["ocp_trace_final"] == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    assert sol.trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    # a non-isotropic, non-diagonal model is not scalar, but structured (constant maps, mean noise): auto keeps
    # the condensed form, with the 6x6 matrix recursion (tests/test_general_models.py)
    aniso = build_setup(replace(prob, horizon=6, noise=replace(prob.noise, Sigma0=sigma0,
                                                               W_p0=np.diag([1e-3, 2e-3, 1e-3, 1e-3, 1e-3, 1e-3]))))
    assert not aniso.model.scalar and aniso.model.structured and resolve_form(aniso.model, "auto") == "condensed"
    expected = build_setup(replace(prob, horizon=6, noise=replace(aniso.problem.noise, observation_noise="expected")))
    assert not expected.model.structured and resolve_form(expected.model, "auto") == "full"
