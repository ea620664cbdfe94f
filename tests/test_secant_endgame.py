"""Newton's secant end-game (`newton._SecantCorrection`): its Woodbury step against a dense solve, its positive-
definiteness test against eigenvalues, and a 6x6-recursion solve that uses it against IPOPT with the exact Hessian."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg.lapack import dpbtrf

from surestep_ocp.problem.setup import build_setup
from surestep_ocp.solvers.methods import ocp_initial_guess
from surestep_ocp.solvers.newton import _SecantCorrection
from surestep_ocp.solvers.nlp_cache import newton_solver
from surestep_ocp.solvers.ocp import solve_ocp


def banded_spd(n: int, band: int, rng) -> np.ndarray:
    """A random SPD matrix of half-bandwidth band - 1."""
    B = rng.standard_normal((n, n)) * (np.abs(np.subtract.outer(np.arange(n), np.arange(n))) < band)
    return np.tril(B) @ np.tril(B).T + n * np.eye(n) * 0.1  # banded lower factor: the same half-bandwidth


@pytest.mark.parametrize("seed", range(6))
def test_woodbury_step_equals_a_dense_solve_and_refuses_an_indefinite_correction(seed):
    rng = np.random.default_rng(seed)
    n, band = 40, 6
    H = banded_spd(n, band, rng)
    fixed = np.zeros(n, bool)
    fixed[rng.choice(n, 5, replace=False)] = True
    sec = _SecantCorrection(n)
    for _ in range(4):  # SR1 terms from random secant pairs (y - H s of a "true" Hessian H + N, N indefinite)
        s = rng.standard_normal(n)
        N = rng.standard_normal((n, 3))
        sec.update(s, (N @ (rng.choice([-1.0, 1.0], 3) * (N.T @ s))) * 0.3)
    assert sec.w.size == 4
    A = sec.U @ np.diag(sec.w) @ sec.U.T
    g = rng.standard_normal(n)
    # the reduced system: free rows and columns of H + A, identity for the held variables (their step is 0)
    M = np.where(np.outer(~fixed, ~fixed), H + A, 0.0) + np.diag(fixed.astype(float))
    rhs = np.where(fixed, 0.0, -g)
    Hred = np.where(np.outer(~fixed, ~fixed), H, 0.0) + np.diag(fixed.astype(float))
    abr = np.zeros((band, n))
    for k in range(band):
        abr[k, : n - k] = np.diag(Hred, -k)
    factor, info = dpbtrf(abr, lower=1)
    assert info == 0
    d = sec.step(factor, fixed, np.linalg.solve(Hred, rhs))
    positive = np.linalg.eigvalsh(M[np.ix_(~fixed, ~fixed)]).min() > 0
    if positive:
        assert d is not None
        np.testing.assert_allclose(d, np.linalg.solve(M, rhs), rtol=1e-9, atol=1e-12)
        assert np.all(d[fixed] == 0)
    else:
        assert d is None
    # a correction that makes H + A indefinite on the free set is refused
    big = _SecantCorrection(n)
    v = np.where(fixed, 0.0, rng.standard_normal(n))
    big.U, big.w = v[:, None], np.array([-10.0 * np.linalg.norm(H, 2) / (v @ v)])
    assert big.step(factor, fixed, np.linalg.solve(Hred, rhs)) is None


def test_sr1_update_meets_the_secant_condition():
    """After an update with step s, (H + A) s equals y: A s = y - H s."""
    rng = np.random.default_rng(3)
    n = 12
    sec = _SecantCorrection(n)
    for _ in range(3):
        s, r = rng.standard_normal(n), rng.standard_normal(n)
        sec.update(s, r)
        np.testing.assert_allclose(sec.U @ (sec.w * (sec.U.T @ s)), r, rtol=1e-10, atol=1e-12)


def test_a_correlated_model_solve_uses_the_end_game_and_matches_ipopt_exact(default_problem):
    """The 6x6 recursion (a correlated depth noise): Newton's plan, with secant steps at its end, against IPOPT with
    the exact Hessian of the unrolled EKF from Newton's plan (a different solver and Hessian)."""
    V = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
    V[0, 2] = V[2, 0] = 2e-2
    prob = replace(default_problem, horizon=10, noise=replace(default_problem.noise, V_d0=V))
    setup = build_setup(prob)
    assert not setup.model.scalar
    init = ocp_initial_guess(setup)
    run = newton_solver(setup).run(setup, init, tol=1e-6, max_iter=300)  # the default tol
    assert run.success and run.secant_steps > 0 and run.exact_steps == 0
    exact = replace(prob, solver=replace(prob.solver, name="ipopt", hessian="exact", tol=1e-10))
    ref = solve_ocp(build_setup(exact), init)  # from the same straight line
    assert ref.success, ref.status
    assert abs(run.trace - ref.trace_final) <= 1e-6 * ref.trace_final
    np.testing.assert_allclose(run.q, np.asarray(ref.q), atol=1e-4)
