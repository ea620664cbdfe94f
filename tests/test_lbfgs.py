"""surestep_ocp.solvers.lbfgs (torch.optim.LBFGS's algorithm in NumPy) against L-BFGS's known
behaviour and scipy."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from surestep_ocp.solvers.lbfgs import LBFGS, cubic_minimiser, minimize, strong_wolfe


def quadratic(n: int = 6, seed: int = 0):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n))
    A = M @ M.T + n * np.eye(n)
    b = rng.standard_normal(n)
    return A, b, (lambda x: (0.5 * x @ A @ x - b @ x, A @ x - b))


def rosenbrock(x):
    f = 100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2
    g = np.array([-400.0 * x[0] * (x[1] - x[0] ** 2) - 2.0 * (1.0 - x[0]),
                  200.0 * (x[1] - x[0] ** 2)])
    return f, g


class Recorder:
    """A closure that records every evaluation."""

    def __init__(self, fun):
        self.fun, self.xs, self.fs = fun, [], []

    def __call__(self, x):
        f, g = self.fun(x)
        self.xs.append(np.array(x))
        self.fs.append(f)
        return f, g


def test_cubic_minimiser_is_exact_on_a_cubic_and_a_quadratic():
    """Through two points with slopes, the interpolant of a cubic (or quadratic) is the function
    itself."""
    c = lambda x: (x**3 - 3 * x**2 + 1, 3 * x**2 - 6 * x)  # local minimum at x = 2
    (f1, g1), (f2, g2) = c(0.5), c(3.0)
    assert cubic_minimiser(0.5, f1, g1, 3.0, f2, g2) == pytest.approx(2.0, abs=1e-12)
    q = lambda x: ((x - 0.3) ** 2, 2 * (x - 0.3))
    assert cubic_minimiser(-1.0, *q(-1.0), 2.0, *q(2.0)) == pytest.approx(0.3, abs=1e-12)
    assert cubic_minimiser(-1.0, *q(-1.0), 2.0, *q(2.0), bounds=(1.0, 2.0)) == 1.0  # clamped


def test_line_search_meets_the_strong_wolfe_conditions():
    """The accepted step has sufficient decrease and |g(t).d| <= c2 |g(0).d| (Rosenbrock, steepest
    descent)."""
    x0 = np.array([-1.2, 1.0])
    f0, g0 = rosenbrock(x0)
    d = -g0
    gtd0 = float(g0 @ d)
    for t0 in (1e-4, 1e-3, 1.0):  # too short (expansion), about right, far too long (zoom)
        f, g, t, evals = strong_wolfe(lambda t: rosenbrock(x0 + t * d), d, t0, f0, g0, gtd0)
        assert f <= f0 + 1e-4 * t * gtd0
        assert abs(float(g @ d)) <= 0.9 * abs(gtd0)
        assert f == pytest.approx(rosenbrock(x0 + t * d)[0], rel=1e-14) and 1 <= evals <= 25


def test_quadratic_in_n_iterations_with_exact_line_searches():
    """L-BFGS with memory >= n and exact line searches minimises an n-dimensional quadratic in n
    iterations."""
    A, b, fq = quadratic(6)
    x_star = np.linalg.solve(A, b)
    opt = LBFGS(np.zeros(6), max_iter=6, max_eval=10_000, tolerance_grad=0.0, tolerance_change=0.0,
                wolfe_c2=1e-10)  # c2 -> 0: the strong Wolfe search becomes an exact one
    opt.step(fq)
    assert opt.steps[-1].iterations == 6
    np.testing.assert_allclose(opt.x, x_star, atol=1e-9)
    # after 5 iterations it is not there yet (the property is tight, not loose)
    opt5 = LBFGS(np.zeros(6), max_iter=5, max_eval=10_000, tolerance_grad=0.0, tolerance_change=0.0,
                 wolfe_c2=1e-10)
    opt5.step(fq)
    assert np.max(np.abs(opt5.x - x_star)) > 1e-6


def test_monotone_decrease_with_the_line_search_and_not_without():
    """With the strong Wolfe search every accepted iterate lowers the loss (Armijo). Torch's
    default, the fixed step lr = 1 without a line search, has no such guarantee: on Rosenbrock it
    goes uphill."""
    losses = {}
    for ls in ("strong_wolfe", "none"):
        opt = LBFGS(np.array([-1.2, 1.0]), max_iter=1, line_search=ls, tolerance_grad=0.0,
                    tolerance_change=0.0)
        losses[ls] = [rosenbrock(opt.x)[0]]
        for _ in range(40):
            opt.step(rosenbrock)
            losses[ls].append(rosenbrock(opt.x)[0])
    assert np.all(np.diff(losses["strong_wolfe"]) <= 0.0)
    assert losses["strong_wolfe"][-1] < 1e-3
    assert np.any(np.diff(losses["none"]) > 0.0)


def test_first_step_length_is_torchs():
    """Iteration 1 moves -t g with t = min(1, 1/||g||_1) * lr (no line search)."""
    A, b, fq = quadratic(4)
    x0 = np.full(4, 3.0)
    g0 = fq(x0)[1]
    opt = LBFGS(x0, lr=0.5, max_iter=1, line_search="none")
    opt.step(fq)
    np.testing.assert_allclose(opt.x, x0 - min(1.0, 1.0 / np.sum(np.abs(g0))) * 0.5 * g0,
                               rtol=1e-14)
    # torch does not re-evaluate after the last inner iteration
    assert opt.steps[-1].evaluations == 1


def test_state_persists_across_steps():
    """Two step() calls of 5 inner iterations are one call of 10 (memory, direction and step carried
    over), at the cost of one extra evaluation at the start of the second call."""
    one = LBFGS(np.array([-1.2, 1.0]), max_iter=10, max_eval=1000, tolerance_grad=0.0,
                tolerance_change=0.0)
    one.step(rosenbrock)
    two = LBFGS(np.array([-1.2, 1.0]), max_iter=5, max_eval=1000, tolerance_grad=0.0,
                tolerance_change=0.0)
    two.step(rosenbrock)
    two.step(rosenbrock)
    np.testing.assert_allclose(two.x, one.x, rtol=1e-13, atol=1e-13)
    assert two.n_iter == one.n_iter == 10
    assert two.func_evals == one.func_evals + 1


def test_budgets_and_tolerances_stop_a_step():
    """max_eval (default max_iter * 5 // 4) ends a step; tolerance_change (absolute) ends later
    steps at once."""
    opt = LBFGS(np.array([-1.2, 1.0]))
    assert opt.max_eval == 25
    for _ in range(50):
        opt.step(rosenbrock)
    first = opt.steps[0]
    assert first.stop == "max_eval" and first.evaluations >= 25 and first.iterations <= 20
    assert all(s.iterations <= 20 for s in opt.steps)
    assert opt.steps[-1].stop.startswith("tolerance") and opt.steps[-1].iterations <= 1
    np.testing.assert_allclose(opt.x, [1.0, 1.0], atol=1e-4)
    # history_size bounds the memory
    small = LBFGS(np.array([-1.2, 1.0]), history_size=3, max_iter=30, max_eval=1000)
    small.step(rosenbrock)
    assert len(small._s) <= 3


@pytest.mark.parametrize("problem", ["rosenbrock", "quadratic"])
def test_against_scipy(problem):
    """Same minimiser as scipy's L-BFGS-B, in a comparable number of iterations."""
    if problem == "rosenbrock":
        fun, x0, x_star = rosenbrock, np.array([-1.2, 1.0]), np.array([1.0, 1.0])
    else:
        A, b, fun = quadratic(8, seed=2)
        x0, x_star = np.zeros(8), np.linalg.solve(A, b)
    ref = scipy.optimize.minimize(fun, x0, jac=True, method="L-BFGS-B",
                                  options={"gtol": 1e-10, "ftol": 0.0, "maxiter": 500})
    x, opt = minimize(fun, x0, steps=1, max_iter=500, max_eval=5000, tolerance_grad=1e-10,
                      tolerance_change=0.0, history_size=10)
    np.testing.assert_allclose(ref.x, x_star, atol=1e-6)
    np.testing.assert_allclose(x, x_star, atol=1e-6)
    assert opt.n_iter <= 2 * ref.nit + 5 and ref.nit <= 2 * opt.n_iter + 5


def test_bad_options_are_errors():
    with pytest.raises(ValueError, match="line search"):
        LBFGS(np.zeros(2), line_search="backtracking")
    with pytest.raises(ValueError):
        LBFGS(np.zeros(2), max_iter=0)
