"""The interior-point Newton method within enforced motion limits (`solvers/interior/`,
`solver.name: interior`) against IPOPT on the same NLP, its plan against the limits by the
independent plan report (finite differences of the waypoints) and by the dense check of the played
curve; a curve that starts in motion continues another."""

from __future__ import annotations

import numpy as np
import pytest

import surestep_ocp as ss
from surestep_ocp.errors import ProblemError
from surestep_ocp.model.limits import evaluate_curve, plan_report, problem_limits
from surestep_ocp.problem.setup import build_setup


@pytest.fixture(scope="module")
def plans():
    """The default problem (40 steps of 50 ms, limits enforced) by the interior-point method and by
    IPOPT."""
    problem = ss.load_problem("problems/needle_regrasp.yaml")
    return (build_setup(problem), ss.solve(problem.with_solver(name="interior"), "ocp"),
            ss.solve(problem.with_solver(name="ipopt"), "ocp"))


def test_interior_point_reaches_ipopts_optimum(plans):
    """Same NLP, same optimum: Tr(Sigma_T) within 1e-6 of IPOPT's (or lower), the same joints to
    1e-3 rad, the goal met, and the interior-point attempt is the one kept (no fallback)."""
    _, sol, ref = plans
    assert sol.success and ref.success
    assert ([a.label for a in sol.attempts] == ["interior point"]
            and sol.attempts[0].solver == "interior")
    assert sol.trace_final <= ref.trace_final * (1 + 1e-6)
    np.testing.assert_allclose(sol.joints, ref.joints, atol=1e-3)
    dist, angle = sol.terminal_error
    assert dist < 1e-9 and angle < 1e-9


def test_interior_point_plan_is_within_every_limit(plans):
    """The waypoints' finite differences (`plan_report`, not the solver's rows) and the played curve
    sampled densely (`enforce`'s check, recorded in the solution) are within every limit."""
    setup, sol, _ = plans
    report = plan_report(setup.robot, sol.joints, setup.ocp.timing.step_s,
                         problem_limits(setup), setup.robot.frame)
    assert report.ok, report.violations
    assert sol.motion_limits.ok and sol.motion_limits.enforced


def test_interior_needs_enforced_limits():
    """`solver.name: interior` on a problem without enforced limits is a problem error naming the
    key."""
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml")
    with pytest.raises(ProblemError, match="solver.name: interior needs limits.enforce"):
        problem.with_solver(name="interior")


def test_a_curve_started_in_motion_continues_the_executed_one():
    """A re-plan at knot k from the executed curve's state (position, velocity, acceleration there)
    continues it twice continuously: the stitched curve's values at the switch equal the old
    curve's, and just before and just after it the two curves' accelerations differ by no more than
    their jerk allows (no jump)."""
    rng = np.random.default_rng(0)
    q, dt, k = np.cumsum(rng.normal(size=(12, 3)) * 0.05, axis=0), 0.05, 4
    p, v, a = evaluate_curve(q, dt, np.array([k * dt]))
    # another plan from waypoint k on
    new = q[k:] + np.linspace(0, 1, len(q) - k)[:, None] ** 3 * 0.02
    new[0] = q[k]
    p2, v2, a2 = evaluate_curve(new, dt, np.array([0.0]), start=(v[0], a[0]))
    np.testing.assert_allclose(np.hstack([p2, v2, a2]), np.hstack([p, v, a]), atol=1e-9)
    h = 1e-7
    left = evaluate_curve(q, dt, np.array([k * dt - h]))
    right = evaluate_curve(new, dt, np.array([h]), start=(v[0], a[0]))
    # [rad/s^3] far above either curve's jerk here (|q| steps of 0.05 rad in 0.05 s)
    jerk_bound = 1e4
    for order in range(3):
        assert np.abs(right[order] - left[order]).max() <= 2 * h * jerk_bound * (1 + dt) ** 3


def _played_peaks(setup, q):
    """The played curve's largest joint velocity and acceleration over their limits, sampled every
    millisecond and differenced with NumPy (not the solver's rows)."""
    dt, lim = setup.ocp.timing.step_s, problem_limits(setup)
    h = 1e-3
    p = evaluate_curve(np.asarray(q, float), dt, np.arange(0.0, (len(q) - 1) * dt + h / 2, h))[0]
    mov = setup.robot.supporting_joints()
    v = np.abs(np.diff(p, axis=0)[:, mov]) / h / lim.velocity[mov]
    a = np.abs(np.diff(p, n=2, axis=0)[:, mov]) / h**2 / lim.acceleration[mov]
    return v.max(), a.max()


@pytest.fixture(scope="module")
def relaxed_runs():
    """The default problem from the straight line at a constant pace (which breaks the acceleration
    rows in its first and last step), relaxed; and from its plan again within a 5 % reserve."""
    from surestep_ocp.ocp.straight_line import timed_line
    from surestep_ocp.ocp.iterate import InitialGuess
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    solver = interior_solver(setup)
    line = timed_line(setup, lambda T: np.linspace(0.0, 1.0, T + 1), "constant")
    start_margin = solver.start_margin(setup, line)
    plain = solver.run(setup, line, tol=1e-6, max_iter=300)
    relaxed = solver.run(setup, line, tol=1e-6, max_iter=300, relax=True)
    tight = solver.run(setup, InitialGuess(relaxed.q, "relaxed run"), tol=1e-6, max_iter=300,
                       relax=True, reserve=0.05)
    return setup, start_margin, plain, relaxed, tight


def test_a_start_outside_the_rows_is_relaxed_to_a_plan_within_them(relaxed_runs):
    """The constant-pace line is outside the rows (margin < 0): without `relax` the run refuses it,
    with it the run ends within every limit (the played curve differenced, not the rows)."""
    setup, margin, plain, relaxed, _ = relaxed_runs
    assert margin < 0 and plain.status == "Infeasible_Start"
    assert relaxed.success and relaxed.relaxed_iterations > 0
    v, a = _played_peaks(setup, relaxed.q)
    assert v <= 1.0 + 1e-3 and a <= 1.0 + 1e-2


def test_a_reserve_keeps_the_plan_inside_the_tightened_limits(relaxed_runs):
    """`reserve=0.05`: the plan keeps to 95 % of the velocity and acceleration limits (within the
    differencing error), where the plan without it uses them to the full."""
    setup, _, _, relaxed, tight = relaxed_runs
    assert tight.success
    v_full, a_full = _played_peaks(setup, relaxed.q)
    v, a = _played_peaks(setup, tight.q)
    assert a_full > 0.98  # the plan without a reserve is on the acceleration limit somewhere
    assert v <= 0.95 + 1e-3 and a <= 0.95 + 5e-3
    assert tight.trace >= relaxed.trace * (1 - 1e-9)  # less room: no better plan


def test_an_infeasibility_verdict_is_the_interior_points_own_and_ends_the_solve():
    """A tool speed limit under the straight distance over the duration (no plan exists): the
    interior point's relaxed rows stop shrinking, its `Infeasible_Problem_Detected` is the solve's
    status and no IPOPT attempt follows (it took 36 s to agree on evaluation configuration 33;
    benchmarks/realtime.py checks each such verdict with IPOPT)."""
    import dataclasses

    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior")
    slow = dataclasses.replace(problem, limits=dataclasses.replace(problem.limits,
                                                                   tool_speed=0.01))
    setup = build_setup(slow)
    start, goal = (setup.robot.frame_pose(q)[:3, 3] for q in (setup.q_start, setup.q_goal))
    assert np.linalg.norm(goal - start) > 0.01 * slow.horizon * slow.timing.step_s
    sol = ss.solve(slow, "ocp")
    assert not sol.success and sol.status == "Infeasible_Problem_Detected"
    assert [(a.label, a.solver, a.status) for a in sol.attempts] == [
        ("interior point", "interior", "Infeasible_Problem_Detected")]


def test_the_rows_jacobian_and_the_window_sums_match_their_definitions():
    """At the default problem's start: the rows' Jacobian (one CSR matrix, the tool points mapped
    inside the compiled functions) times a direction equals the rows' central differences, its
    transpose is its adjoint; each window's curvature block equals the sum of K_p^T H_p K_p over
    its points (the Kronecker form)."""
    from surestep_ocp.solvers.backends.interior_point import feasible_line
    from surestep_ocp.solvers.interior import WINDOW, _RowJacobian
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    ip = interior_solver(setup)
    x = np.asarray(feasible_line(setup, ip).q, float).ravel()
    P = np.concatenate([setup.camera_parameter(), [1.0],
                        setup.model.recursion_sigma0(setup.ocp.sigma0)])
    free = ip.bounds(setup.q_start)[2]
    idx = np.flatnonzero(free)
    offsets, lin_c = ip._tool_offsets(None, None), ip._lin_const(None, None)

    def rows(z):
        return ip.constraints(z, P, lin_c, offsets, setup.ocp.min_depth)[1]

    DZ = np.array(ip.newton.depth(x, P)[1]).reshape(ip.T + 1, ip.nq)
    _, gy = ip._tool_gradients(*ip.tool_jacs(x, offsets), ip.tool_scale)
    jac = _RowJacobian(ip, idx, DZ, ip._to_window(gy))
    rng = np.random.default_rng(1)
    d = np.zeros(ip.n)
    d[idx] = rng.normal(size=len(idx))
    h = 1e-6
    fd = (rows(x + h * d) - rows(x - h * d)) / (2 * h)
    lin = jac.dot(d)
    assert np.abs(lin - fd).max() <= 1e-6 * max(1.0, np.abs(fd).max())
    v = rng.normal(size=len(lin))
    assert abs(jac.T(v) @ d - v @ lin) <= 1e-10 * np.abs(v).sum() * np.abs(lin).max()
    H = rng.normal(size=(ip.n_pts, 2 * ip.nq, 2 * ip.nq))
    H = H + H.transpose(0, 2, 1)
    expect = np.zeros((ip.n_windows, ip.bw, ip.bw))
    for p in range(ip.n_pts):
        expect[ip.point_window[p]] += ip.tool_map[p].T @ H[p] @ ip.tool_map[p]
    # the terms are flat in (window, node m, node n, joint i, joint j) order
    nq, nw = ip.nq, ip.n_windows
    blocks = (ip._window_terms(H).reshape(nw, WINDOW, WINDOW, nq, nq).transpose(0, 1, 3, 2, 4)
              .reshape(nw, ip.bw, ip.bw))
    np.testing.assert_allclose(blocks, expect, rtol=0, atol=1e-10 * np.abs(expect).max())


def test_the_tool_blocks_are_gauss_newtons_and_the_barriers_by_pinocchio():
    """Each tool point's block of the reduced matrix (`_tool_blocks`, from the compiled Jacobians)
    equals Gauss-Newton's curvature of wk . g plus sum_k st_k grad g_k
    grad g_k^T, with the velocities (p', vec(R')) from Pinocchio's frame Jacobian and every
    derivative by central differences; the gradients too."""
    from surestep_ocp.solvers.backends.interior_point import feasible_line
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    ip, robot = interior_solver(setup), setup.robot
    x = np.asarray(feasible_line(setup, ip).q, float).ravel()
    rng = np.random.default_rng(2)
    wk, st = rng.uniform(0.1, 2.0, (ip.tool_k, ip.n_pts)), rng.uniform(0.1, 2.0, (ip.n_pts, 2))
    A, gy = ip._tool_gradients(*ip.tool_jacs(x, ip._tool_offsets(None, None)), ip.tool_scale)
    Hp = ip._tool_blocks(A, gy, wk, st)
    nq = ip.nq

    def velocities(y):
        q, qd = y[:nq], y[nq:]
        J = robot.frame_jacobian(q, robot.frame)
        w = J[3:] @ qd
        R = robot.frame_pose(q, robot.frame)[:3, :3]
        Rd = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) @ R
        return np.concatenate([J[:3] @ qd, Rd.ravel(order="F")])

    def central(f, y, h=1e-6):
        return np.stack([(f(y + h * e) - f(y - h * e)) / (2 * h) for e in np.eye(len(y))], axis=-1)

    def rows(y):
        v = velocities(y)
        return ip.tool_scale * np.array([v[:3] @ v[:3], 0.5 * v[3:] @ v[3:]])

    for p in (0, ip.n_pts // 3, ip.n_pts - 1):
        y = ip.tool_map[p] @ x[ip.tool_var[p]]  # the point's (q(s), q'(s)), at rest
        A, G = central(velocities, y), central(rows, y)
        wv = np.concatenate([np.full(3, 2 * wk[0, p]), np.full(9, wk[1, p])])
        expect = A.T @ (wv[:, None] * A) + G.T @ (st[p][:, None] * G)
        np.testing.assert_allclose(gy[p], G, rtol=0, atol=1e-6 * np.abs(G).max())
        np.testing.assert_allclose(Hp[p], expect, rtol=0, atol=1e-6 * np.abs(expect).max())


def test_a_start_is_inside_when_its_rows_are():
    """`starts_inside` (the linear rows looked at first) agrees with every row evaluated at the
    start and at its pushed point: the line at a constant pace (its accelerations broken at the
    ends), the line at a feasible time law, and that line with one waypoint moved past a joint
    bound, by 0.05 rad (an acceleration row broken) and by 1e-9 rad (still inside)."""
    from surestep_ocp.solvers.backends.interior_point import feasible_line
    from surestep_ocp.ocp.straight_line import timed_line
    from surestep_ocp.ocp.iterate import InitialGuess
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    ip = interior_solver(setup)
    line = feasible_line(setup, ip)
    q = np.asarray(line.q, float)
    j = setup.robot.supporting_joints()[0]
    moved = [q.copy() for _ in range(3)]
    moved[0][5, j] = ip.joint_upper[j] + 0.1
    moved[1][5, j] += 0.05
    moved[2][5, j] += 1e-9
    starts = [timed_line(setup, lambda T: np.linspace(0.0, 1.0, T + 1), "constant"), line,
              *(InitialGuess(m, "moved") for m in moved)]
    verdicts = []
    for start in starts:
        x = np.asarray(start.q, float).ravel()
        expect = (ip.start_margin(setup, start) > 0
                  or ip.start_margin(setup, InitialGuess(ip._pushed(x).reshape(q.shape), "")) > 0)
        verdicts.append(ip.starts_inside(setup, start))
        assert verdicts[-1] == expect
    assert verdicts == [False, True, False, False, True]


def test_the_band_is_the_reduced_matrix_assembled_densely():
    """The band that the parts' sparse products fill (`_band`: the surrogate's interval blocks, the
    linear rows' weights, the depths' node blocks, the tool windows' blocks) equals the same matrix
    assembled densely from its definition, `sum_t H_t + L^T diag(w) L + sum_t E_t^T B_t E_t +
    sum_p K_p^T H_p K_p`, in LAPACK's lower band storage; `tool_scatter` alone gives the last
    term; on the free joints (the held ones' rows and columns are zero)."""
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    ip = interior_solver(setup)
    nw, n, nq, T, bw = ip.newton, ip.n, ip.nq, ip.T, ip.bw
    rng = np.random.default_rng(5)

    def sym(*shape):
        A = rng.normal(size=shape)
        return A + np.swapaxes(A, -1, -2)

    HB = sym(T, 2 * nq, 2 * nq).ravel()
    wl = rng.random(ip.n_lin)
    blocks = sym(T + 1, nq, nq)
    H = sym(ip.n_pts, 2 * nq, 2 * nq)
    dense = np.zeros((n, n))
    np.add.at(dense, (nw.h_rows, nw.h_cols), HB)
    L = ip.lin_map.toarray()
    dense += L.T @ (wl[:, None] * L)
    for t in range(T + 1):
        dense[t * nq:(t + 1) * nq, t * nq:(t + 1) * nq] += blocks[t]
    tool = np.zeros((n, n))
    for p in range(ip.n_pts):
        K = np.zeros((2 * nq, n))
        np.add.at(K.T, ip.tool_var[p], ip.tool_map[p].T)
        tool += K.T @ H[p] @ K
    dense += tool

    def band(M):
        out = np.zeros((bw, n))
        for k in range(bw):
            out[k, :n - k] = np.diagonal(M, -k)
        return out

    # the held joints' rows and columns are not part of it (the factorisation puts identity rows
    # there): zeros in the band
    held = ~ip.bounds(setup.q_start)[2]
    for M in (dense, tool):
        M[held, :] = 0.0
        M[:, held] = 0.0
    ab = ip._band(HB, wl, blocks.ravel(), ip._window_terms(H))
    scale = np.abs(dense).max()
    np.testing.assert_allclose(ab, band(dense), rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose((ip.tool_scatter @ ip._window_terms(H)).reshape(bw, n),
                               band(tool), rtol=0, atol=1e-12 * scale)


def test_a_one_step_plan_is_decided_at_once():
    """With one step nothing is free: the start is the plan. Moving the default problem's distance
    in 50 ms breaks the limit rows (infeasible, relaxed or not); staying put keeps them; either
    verdict without iterations and without floating-point trouble (the relaxation once shrank
    towards a slack of 0 and w / s overflowed)."""
    from dataclasses import replace

    from surestep_ocp.ocp.iterate import InitialGuess
    from surestep_ocp.solvers.nlp_cache import interior_solver

    base = build_setup(ss.load_problem("problems/needle_regrasp.yaml"))
    one = base.with_ocp(horizon=1)
    solver = interior_solver(one)
    jump = InitialGuess(np.array([base.q_start, base.q_goal], float), "one step")
    with np.errstate(all="raise"):
        far = solver.run(one, jump, relax=True, feasible_ok=True)
        stay_setup = replace(one, q_goal=np.array(base.q_start, float))
        stay_setup.x_goal = stay_setup.pose_of(stay_setup.q_goal)
        still = solver.run(stay_setup, InitialGuess(np.array([base.q_start] * 2, float), "still"))
    assert far.status == "Infeasible_Problem_Detected" and far.iterations == 0
    assert still.status == "Solve_Succeeded" and still.iterations == 0
    np.testing.assert_allclose(still.q, [base.q_start] * 2)


def test_the_step_to_the_boundary_is_the_largest_that_keeps_the_fraction():
    """`_to_boundary` (one division a vector) against its definition row by row: the largest a <= 1
    with v + a dv >= (1 - tau) v for every positive v, checked at that step and just beyond it."""
    from surestep_ocp.solvers.interior import _to_boundary

    rng = np.random.default_rng(3)
    for _ in range(200):
        n = int(rng.integers(1, 50))
        v = rng.uniform(1e-6, 2.0, n)
        dv = rng.normal(size=n) * 10 ** rng.uniform(-3, 3, n)
        tau = float(rng.choice([1.0, 0.99, 0.995]))
        a = _to_boundary(v, dv, tau)
        falling = dv < 0
        expect = min([1.0] + [-tau * vi / di for vi, di in zip(v[falling], dv[falling])])
        assert a == pytest.approx(expect, rel=1e-12)
        assert np.all(v + a * dv >= (1 - tau) * v - 1e-12 * v)
        if a < 1.0:  # a little further breaks a row
            assert np.any(v + 1.001 * a * dv < (1 - tau) * v)
    assert _to_boundary(np.ones(3), np.array([0.0, 1.0, 2.0]), 0.99) == 1.0  # nothing falls


def test_a_runs_options_as_one_object_and_its_iterations_records(relaxed_runs, capsys):
    """`solve` with `InteriorOptions` is `run` with the same keyword arguments, to the bit; the
    run's `history` holds one record per iteration (and the last test's), the lines `verbose`
    prints."""
    from surestep_ocp.solvers.interior import InteriorOptions
    from surestep_ocp.ocp.iterate import InitialGuess
    from surestep_ocp.solvers.nlp_cache import interior_solver

    setup, _, _, relaxed, tight = relaxed_runs
    solver = interior_solver(setup)
    start = InitialGuess(relaxed.q, "relaxed run")
    again = solver.solve(setup, start, InteriorOptions(max_iter=300, relax=True, reserve=0.05,
                                                       verbose=True))
    printed = [line for line in capsys.readouterr().out.splitlines()
               if line.startswith("interior ")]
    assert again.status == tight.status and again.iterations == tight.iterations
    assert np.array_equal(again.q, tight.q) and np.array_equal(again.multipliers,
                                                                tight.multipliers)
    assert len(tight.history) == tight.iterations + 1
    assert [r.iteration for r in tight.history] == list(range(tight.iterations + 1))
    assert printed == [r.line() for r in again.history] == tight.log().splitlines()
