"""The OCP's surrogate and Gauss-Newton Hessians: checked against finite differences of a plain
NumPy recursion, structured as claimed, and the solves they drive reach the exact Hessian's optima;
and the covariance forms (condensed, full, diagonal) are transcriptions of one problem: they
agree."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy_ekf import image_offset
from scipy.spatial.transform import Rotation

from surestep_ocp.methods.baseline import solve_baseline
from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.errors import SurestepError
from surestep_ocp.methods.registry import ocp_initial_guess
from surestep_ocp.solvers.nlp_cache import transcription
from surestep_ocp.methods.ocp import solve_ocp, solve_ocp_warm
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.problem.solver_config import resolve_form
from surestep_ocp.ocp.iterate import InitialGuess


DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"


def with_solver(problem, **kw):
    return replace(problem, solver=replace(problem.solver, **kw))


def setup_with_solver(setup, **kw):
    return setup.with_ocp(solver=replace(setup.ocp.solver, **kw))


@pytest.fixture(scope="module")
def short():
    # IPOPT's Hessians
    return build_setup(with_solver(replace(load_problem(DEFAULT), horizon=6), name="ipopt"))


# ------------------------------------------------------------------ independent structured Hessians
def rotation(m) -> Rotation:
    """scipy's rotation of a mean's quaternion `(w, x, y, z)` (normalised by scipy)."""
    return Rotation.from_quat(np.r_[m[4:7], m[3]])


def residuals(setup, x0, x1) -> list[np.ndarray]:
    """Motion (step, relative rotation) then observation (depth, image offset, 1 - cos) residuals,
    NumPy, of two means `(p, Q)` (the NLP's variables); the cosine of scipy's principal rotation
    vector."""
    n, cam = setup.ocp.noise, setup.ocp.intrinsics
    rel = (rotation(x0).inv() * rotation(x1)).as_rotvec()
    o = np.asarray(n.o_star, float)
    r = rotation(x1).as_rotvec()
    cos = float(r @ o) / (np.sqrt(r @ r + COSINE_GUARD) * np.linalg.norm(o))
    return [x1[:3] - x0[:3], rel, np.array([x1[2] - n.depth_star]),
            np.array(image_offset(x1[:3], cam)), np.array([1 - cos])]


def trace_of_coefficients(setup, c: np.ndarray, T: int) -> float:
    """Tr(Sigma_T) of the scalar recursions given the (T, 5) noise coefficients."""
    n = setup.ocp.noise
    W = [np.diag(n.W_p0), np.diag(n.W_o0)]
    V = [np.diag(n.V_d0), np.diag(n.V_f0), np.diag(n.V_o0)]
    s = np.diag(np.asarray(n.Sigma0, float)).copy()
    for t in range(T):
        p = s + c[t, 0] * W[0] + c[t, 1] * W[1]
        v = c[t, 2] * V[0] + c[t, 3] * V[1] + c[t, 4] * V[2]
        s = p * v / (p + v)
    return float(s.sum())


def numpy_structured_hessian(setup, mus: np.ndarray, trace_ref: float, kind: str) -> np.ndarray:
    """Over the means (7(T+1) square), by central differences: `gauss-newton` sum_k dS/dc_k 2 J_k^T
    J_k, `surrogate` sum_k dS/dc_k Hess c_k."""
    T = len(mus) - 1
    c = np.array([[float(e @ e) for e in residuals(setup, mus[t], mus[t + 1])] for t in range(T)])
    w = np.zeros_like(c)
    for idx in np.ndindex(*c.shape):
        h = 1e-6 * max(abs(c[idx]), 1e-12)
        cp, cm = c.copy(), c.copy()
        cp[idx] += h
        cm[idx] -= h
        w[idx] = ((trace_of_coefficients(setup, cp, T) - trace_of_coefficients(setup, cm, T))
                  / (2 * h) / trace_ref)
    H = np.zeros((7 * (T + 1), 7 * (T + 1)))
    for t in range(T):
        ab = np.concatenate([mus[t], mus[t + 1]])
        base = residuals(setup, ab[:7], ab[7:])
        J = [np.zeros((len(e), 14)) for e in base]
        for j in range(14):
            d = np.zeros(14)
            d[j] = 1e-7
            up, dn = residuals(setup, *np.split(ab + d, 2)), residuals(setup, *np.split(ab - d, 2))
            for k in range(len(base)):
                J[k][:, j] = (up[k] - dn[k]) / 2e-7
        if kind == "gauss-newton":
            block = sum(2 * w[t, k] * J[k].T @ J[k] for k in range(len(base)))
        else:
            def weighted(y, t=t):
                return sum(w[t, k] * float(e @ e)
                           for k, e in enumerate(residuals(setup, *np.split(y, 2))))
            block, h = np.zeros((14, 14)), 1e-4
            for i in range(14):
                for j in range(14):
                    di, dj = np.eye(14)[i] * h, np.eye(14)[j] * h
                    block[i, j] = (weighted(ab + di + dj) - weighted(ab + di - dj)
                                   - weighted(ab - di + dj)
                                   + weighted(ab - di - dj)) / (4 * h * h)
        H[7 * t:7 * t + 14, 7 * t:7 * t + 14] += block
    return H


@pytest.mark.parametrize("kind", ["gauss-newton", "surrogate"])
def test_structured_hessians_match_numpy_finite_differences(short, kind):
    """The CasADi surrogate and Gauss-Newton Hessians (objective part) equal independent NumPy
    constructions."""
    setup = short
    tr = transcription(setup, hessian=kind)
    init = ocp_initial_guess(setup)
    x0, scale = tr.guess(setup, np.asarray(init.q))
    mus = np.array([x0[f"mu{t}"] for t in range(tr.T + 1)])
    trace_ref = trace_of_coefficients(  # the solver's own reference: the initial guess's trace
        setup, np.array([[float(e @ e) for e in residuals(setup, mus[t], mus[t + 1])]
                         for t in range(tr.T)]), tr.T)
    x = tr.layout.join(x0)
    p = np.concatenate([setup.camera_parameter(), scale, [trace_ref],
                        np.asarray(setup.model.sigma0_vech())])
    H = np.asarray(tr.hess_lag(x, p, 1.0, np.zeros(tr.ng)))
    H = np.triu(H) + np.triu(H, 1).T
    offsets = np.cumsum([0] + [size for _, size, _ in tr.layout.blocks])
    names = [name for name, _, _ in tr.layout.blocks]
    mu_idx = np.concatenate([np.arange(offsets[names.index(f"mu{t}")],
                                       offsets[names.index(f"mu{t}")] + 7)
                             for t in range(tr.T + 1)])
    expected = numpy_structured_hessian(setup, mus, trace_ref, kind)
    got = H[np.ix_(mu_idx, mu_idx)]
    assert (np.max(np.abs(got - expected))
            <= (1e-5 if kind == "gauss-newton" else 1e-4) * np.max(np.abs(expected)))
    # no other entries: with zero multipliers and no smoothness only the means carry curvature
    rest = H.copy()
    rest[np.ix_(mu_idx, mu_idx)] = 0
    assert np.max(np.abs(rest)) == 0
    if kind == "gauss-newton":  # positive semidefinite
        eig = np.linalg.eigvalsh(got)
        assert eig.min() >= -1e-10 * eig.max()
    # block tridiagonal in the means: nothing between nodes two or more steps apart
    for t in range(tr.T + 1):
        far = [i for i in range(tr.T + 1) if abs(i - t) >= 2]
        for i in far:
            assert np.all(got[7 * t:7 * t + 7, 7 * i:7 * i + 7] == 0)


@pytest.mark.parametrize("kind", ["gauss-newton", "surrogate"])
def test_staged_derivatives_equal_casadis_own(short, kind):
    """The stage-wise gradient, constraint Jacobian and kinematic/smoothness curvature (scattered
    stage blocks) equal what CasADi's AD derives from the whole NLP, at a perturbed point with
    random multipliers."""
    setup = short.with_ocp(smoothness=0.3)
    staged, exact = transcription(setup, hessian=kind), transcription(setup, hessian="exact")
    x0, scale = staged.guess(setup, np.asarray(ocp_initial_guess(setup).q))
    rng = np.random.default_rng(3)
    x = staged.layout.join(x0) + 1e-2 * rng.normal(size=staged.layout.vector().shape[0])
    p = np.concatenate([setup.camera_parameter(), scale, [2e-5],
                        np.asarray(setup.model.sigma0_vech())])
    lam_g = rng.normal(size=staged.ng)
    fns = {name: exact.solver.get_function(name)
           for name in ("nlp_grad_f", "nlp_jac_g", "nlp_hess_l")}
    f_e, g_e = (np.asarray(v) for v in fns["nlp_grad_f"](x, p))
    f_s, g_s = (np.asarray(v) for v in staged.solver.get_function("nlp_grad_f")(x, p))
    assert abs(f_s - f_e).max() <= 1e-12 * abs(f_e).max()
    assert np.abs(g_s - g_e).max() <= 1e-10 * np.abs(g_e).max()
    c_e, J_e = fns["nlp_jac_g"](x, p)
    c_s, J_s = staged.solver.get_function("nlp_jac_g")(x, p)
    assert np.abs(np.asarray(c_s) - np.asarray(c_e)).max() <= 1e-13
    assert np.abs(np.asarray(J_s.full()) - np.asarray(J_e.full())).max() <= 1e-12
    # constraint curvature (no objective): the same matrix
    H_s = np.asarray(staged.hess_lag(x, p, 0.0, lam_g).full())
    H_e = np.asarray(fns["nlp_hess_l"](x, p, 0.0, lam_g).full())
    assert np.abs(H_s - np.triu(H_e)).max() <= 1e-10 * np.abs(H_e).max()
    # the smoothness term's curvature (joints only; the trace does not depend on them)
    q_idx = np.concatenate([np.arange(o, o + size) for (name, size, _), o in
                            zip(staged.layout.blocks,
                                np.cumsum([0] + [b[1] for b in staged.layout.blocks]))
                            if name.startswith("q")])
    H_s = np.asarray(staged.hess_lag(x, p, 1.0, np.zeros(staged.ng)).full())[np.ix_(q_idx, q_idx)]
    H_e = np.asarray(fns["nlp_hess_l"](x, p, 1.0, np.zeros(staged.ng)).full())[np.ix_(q_idx, q_idx)]
    assert np.abs(H_s - np.triu(H_e)).max() <= 1e-12 and np.abs(H_e).max() > 0


def test_structured_hessians_reach_the_exact_hessians_optimum():
    """Surrogate or Gauss-Newton alone, the default (surrogate, then exact if needed), the exact
    Hessian:
    one optimum on the default problem."""
    prob = load_problem(DEFAULT)
    sols = {}
    for h in ("auto", "exact", "surrogate", "gauss-newton"):
        setup = build_setup(with_solver(prob, hessian=h, name="ipopt"))
        sols[h] = solve_ocp(setup, ocp_initial_guess(setup))
        assert sols[h].success, (h, sols[h].status)
        assert sols[h].run.constraint_violation <= 1e-6
        assert np.max(np.abs(np.array(sols[h].poses[-1]) - setup.x_goal)) <= 1e-6
    # the planner's objective at its initial point (the straight line) is the baseline's exact-EKF
    # trace
    from surestep_ocp.methods.baseline import solve_baseline

    base = solve_baseline(build_setup(prob)).trace_final
    for h in sols:
        assert sols[h].run.initial_trace == pytest.approx(base, rel=1e-9)
    for h in ("auto", "surrogate", "gauss-newton"):
        assert sols[h].trace_final == pytest.approx(sols["exact"].trace_final, rel=1e-6)
        assert sols[h].iterations < sols["exact"].iterations
    for h in ("surrogate", "gauss-newton", "exact"):
        assert sols[h].run.hessian == h
    assert sols["auto"].run.hessian.startswith("surrogate")
    attempts = sols["auto"].attempts
    assert sum(a.iterations for a in attempts) == sols["auto"].iterations
    assert attempts[0].iterations <= prob.solver.surrogate_max_iter


def test_warm_resolve_after_a_camera_move_reaches_the_cold_optimum(short):
    """A warm start (previous primal-dual point) after a small camera move converges to the same KKT
    point."""
    setup = short
    init = ocp_initial_guess(setup)
    _, warm = solve_ocp_warm(setup, init)
    D = np.eye(4)
    D[:3, 3] = [0.002, -0.001, 0.001]
    moved = setup.seen_from(setup.camera_pose @ D)
    again, _ = solve_ocp_warm(moved, init, warm=warm)
    cold = solve_ocp(moved, ocp_initial_guess(moved))
    assert again.success, again.status
    assert again.run.init.startswith("warm start")
    assert again.trace_final == pytest.approx(cold.trace_final, rel=1e-4)


def test_structured_hessians_need_the_mean_noise_form():
    """The structured Hessians are not defined for the expected-noise recursion: a clear error, not
    a fallback."""
    prob = load_problem(DEFAULT)
    prob = with_solver(replace(prob, noise=replace(prob.noise, observation_noise="expected")),
                       hessian="gauss-newton")
    with pytest.raises(SurestepError, match="solver.hessian"):  # checked when the problem is set up
        build_setup(prob)
    # auto picks the exact Hessian there
    auto = build_setup(with_solver(prob, hessian="auto"))
    from surestep_ocp.problem.solver_config import resolve_hessian

    assert resolve_hessian(auto.model, "condensed", "auto") == "exact"


def test_an_optimum_worse_than_the_start_keeps_the_start():
    """Evaluation configuration 36 with the paper's cosine exactly (`cut_band: 0`: a jump where its
    straight line passes through a rotation of pi): the surrogate converges above its own feasible
    start, so the start (the straight line's IK, feasible) is the plan returned, and said so."""
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

    sampler = ConfigurationSampler(load_evaluation(DEFAULT.parent / "evaluations"
                                                   / "evaluation.yaml"))
    prob = sampler.problem(sampler.sample(0, 36))
    prob = replace(prob, noise=replace(prob.noise, cut_band=0.0))
    setup = build_setup(with_solver(prob, name="ipopt"))
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    attempts = sol.attempts
    assert attempts[0].label == "surrogate"
    converged = [a.objective for a in attempts
                 if a.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")]
    assert converged and min(converged) > sol.run.initial_trace
    assert attempts[-1].label.startswith("none: the feasible initial guess") and attempts[-1].kept
    assert sum(a.kept for a in attempts) == 1
    assert (sol.status == "Initial_Guess_Kept" and sol.success
            and not sol.run.worse_than_initial_guess)
    assert sol.objective == sol.run.initial_trace
    baseline = solve_baseline(setup)
    # the straight line, by its IK
    assert sol.trace_final == pytest.approx(baseline.trace_final, rel=1e-6)
    # the planner's trace is the EKF's
    assert sol.objective == pytest.approx(sol.trace_final, rel=1e-6)
    assert sol.iterations == sum(a.iterations for a in attempts)
    assert max(sol.terminal_error) <= 1e-9  # the kept point meets the terminal pose (Pinocchio FK)


def test_codegen_auto_follows_the_compiler(short, monkeypatch):
    """solver.codegen auto: compiled when a C compiler is found, not when none is; true without a
    compiler, or true with the exact Hessian, is an error (not a silent fallback)."""
    from surestep_ocp.solvers.nlp_cache import resolve_codegen

    auto = setup_with_solver(short, codegen="auto")
    forced = setup_with_solver(short, codegen=True, hessian="exact")
    assert resolve_codegen(auto, "exact") is False
    monkeypatch.setenv("CC", "no-such-compiler-here")
    assert resolve_codegen(auto, "surrogate") is False
    with pytest.raises(SurestepError, match="compiler"):
        transcription(setup_with_solver(short, codegen=True),
                      hessian="surrogate", horizon=2)
    with pytest.raises(SurestepError, match="exact"):
        solve_ocp(forced, ocp_initial_guess(forced))
    # any program on PATH counts as found; compiling is not attempted here
    monkeypatch.setenv("CC", "sh")
    assert resolve_codegen(auto, "surrogate") is True


def test_start_solution_only_for_a_feasible_start(short):
    """The start is offered as a plan only when it meets every bound (here: the terminal pose)."""
    tr = transcription(short, hessian="exact")
    init = ocp_initial_guess(short)
    start = tr.start_solution(short, init)
    assert start is not None and start.status == "Initial_Guess_Kept" and start.iterations == 0
    assert start.objective == pytest.approx(start.trace_final, rel=1e-9)
    moved = np.array(init.q)
    moved[-1, 0] += 1e-6  # the last node no longer reaches the goal pose
    assert tr.start_solution(short, type(init)(moved, "moved")) is None


def test_codegen_auto_falls_back_when_the_compile_fails(short, monkeypatch, tmp_path):
    """A compiler that fails (here `false`): with codegen auto the solve runs interpreted and says
    why; with codegen true it is an error."""
    monkeypatch.setenv("CC", "false")
    monkeypatch.setenv("SURESTEP_CACHE", str(tmp_path))
    # a new structure
    odd = short.with_ocp(smoothness=0.0123)
    auto = setup_with_solver(odd, codegen="auto", hessian="surrogate")
    sol = solve_ocp(auto, ocp_initial_guess(auto))
    assert (sol.success and sol.run.compiled is False
            and "failed" in sol.run.codegen_note)
    forced = setup_with_solver(odd, codegen=True, hessian="surrogate")
    with pytest.raises(SurestepError, match="failed on the generated code"):
        solve_ocp(forced, ocp_initial_guess(forced))


# The OCP's covariance forms are transcriptions of one problem: they must agree.


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
    """Multiple shooting of vech(Sigma) with free gains keeps the condensed recursion's optimum
    (same problem).

    (From the straight line the two forms may reach different local optima: the problem is
    nonconvex.)
    """
    _, sols = small
    full, cond = sols["full"], sols["condensed"]
    assert full.success and cond.success, (full.status, cond.status)
    assert full.trace_final == pytest.approx(cond.trace_final, rel=1e-5)
    np.testing.assert_allclose(np.array(full.poses), np.array(cond.poses), atol=1e-4)
    # each form's own covariance equals the exact EKF's at its optimum
    for sol in (full, cond):
        assert sol.run.ocp_trace_final == pytest.approx(sol.trace_final, rel=1e-6)


def test_diagonal_form_solves_and_matches_the_exact_ekf():
    """The multiple-shooting diagonal form (six scalars and gains per node) builds, solves, and is
    exact.

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
    assert diag.run.ocp_trace_final == pytest.approx(diag.trace_final, rel=1e-6)


def test_isotropic_noise_with_a_full_sigma0_runs_scalar_recursions_on_its_eigenvalues():
    """The paper's constants are multiples of I: from a non-diagonal Sigma_0 (after a camera move)
    the EKF is six scalar recursions on Sigma_0's eigenvalues. The condensed OCP uses them; its
    trace equals a NumPy EKF's."""
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
    sig, _ = propagate(np.array(sol.poses), setup.ocp.noise, setup.ocp.intrinsics,
                       guard=COSINE_GUARD)
    assert sol.run.ocp_trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    assert sol.trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)
    # a non-isotropic, non-diagonal model is not scalar, but structured (constant maps, mean noise):
    # auto keeps the condensed form, with the 6x6 matrix recursion (tests/test_lifted.py,
    # tests/test_surrogate.py)
    aniso = build_setup(replace(prob, horizon=6, noise=replace(
        prob.noise, Sigma0=sigma0, W_p0=np.diag([1e-3, 2e-3, 1e-3, 1e-3, 1e-3, 1e-3]))))
    assert (not aniso.model.scalar and aniso.model.structured
            and resolve_form(aniso.model, "auto") == "condensed")
    expected = build_setup(replace(prob, horizon=6,
                                   noise=replace(aniso.ocp.noise,
                                                 observation_noise="expected")))
    assert not expected.model.structured and resolve_form(expected.model, "auto") == "full"
