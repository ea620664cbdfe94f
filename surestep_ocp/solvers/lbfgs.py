"""L-BFGS with PyTorch's semantics (`torch.optim.LBFGS`), in NumPy, without torch.

The paper ran "L-BFGS, 50 iterations" in PyTorch. What that means depends on
torch's optimiser, which differs from scipy's L-BFGS-B in ways that change the
result (see docs/evaluation.md, "Table I"):

- `step(closure)` is an *outer* call: it evaluates the loss and gradient once, then
  runs up to `max_iter` inner L-BFGS iterations (default 20), stopping early when
  the function-evaluation budget `max_eval` (default `max_iter * 5 // 4`, counting
  the first evaluation) is spent, when `max|g| <= tolerance_grad` (1e-7), when the
  directional derivative `g.d > -tolerance_change` (1e-9), when the step
  `max|t d| <= tolerance_change`, or when the loss changed by less than
  `tolerance_change` (absolute, not relative). The memory (`history_size`, default
  100 pairs) and the last direction persist across `step()` calls, so 50 `step()`
  calls are one L-BFGS run of up to 50 x 20 inner iterations with restarts of the
  evaluation budget.
- The first iteration's step is `min(1, 1 / ||g||_1) * lr`, later ones `lr`.
- A pair (s, y) is stored only when `y.s > 1e-10` (absolute); the initial inverse
  Hessian is `H0 = (y.s) / (y.y)` of the newest stored pair.
- Without a line search the step is the fixed `lr * d` (torch's default, which
  diverges easily); `line_search="strong_wolfe"` runs the bracketing / zoom search
  with cubic interpolation (c1 = 1e-4, c2 = 0.9, at most 25 evaluations) of
  minFunc / torch7's `lswolfe`.

This module is written from the published algorithm (Nocedal and Wright,
algorithms 7.4 and 3.5/3.6, and torch's documented behaviour); tests check it
against properties of L-BFGS (exact minimisation of a quadratic in n iterations
with exact line searches, the strong Wolfe conditions, monotone decrease) and
against scipy's L-BFGS-B on the same problems. Computations are in float64
(torch's default dtype is float32).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

Closure = Callable[[np.ndarray], tuple[float, np.ndarray]]
LINE_SEARCHES = ("strong_wolfe", "none")


def cubic_minimiser(x1: float, f1: float, g1: float, x2: float, f2: float, g2: float,
                    bounds: tuple[float, float] | None = None) -> float:
    """Minimiser of the cubic through (x1, f1, g1) and (x2, f2, g2), clamped to `bounds`.

    Default bounds are [min(x1, x2), max(x1, x2)]; when the cubic has no real minimiser the
    midpoint of the bounds is returned.
    """
    lo, hi = bounds if bounds is not None else (min(x1, x2), max(x1, x2))
    if x1 == x2:  # a collapsed bracket (only with tolerance_change = 0): nothing to interpolate
        return float(min(max(x1, lo), hi))
    d1 = g1 + g2 - 3.0 * (f1 - f2) / (x1 - x2)
    disc = d1 * d1 - g1 * g2
    if disc < 0 or not np.isfinite(disc):
        return 0.5 * (lo + hi)
    d2 = np.sqrt(disc)
    if x1 <= x2:
        x = x2 - (x2 - x1) * ((g2 + d2 - d1) / (g2 - g1 + 2.0 * d2))
    else:
        x = x1 - (x1 - x2) * ((g1 + d2 - d1) / (g1 - g2 + 2.0 * d2))
    if not np.isfinite(x):
        return 0.5 * (lo + hi)
    return float(min(max(x, lo), hi))


@dataclass
class _Point:
    t: float
    f: float
    g: np.ndarray
    gtd: float


def strong_wolfe(fun: Callable[[float], tuple[float, np.ndarray]], d: np.ndarray, t: float,
                 f0: float, g0: np.ndarray, gtd0: float, c1: float = 1e-4, c2: float = 0.9,
                 tolerance_change: float = 1e-9,
                 max_ls: int = 25) -> tuple[float, np.ndarray, float, int]:
    """Strong-Wolfe line search along d from the point with loss f0, gradient g0, slope gtd0 < 0.

    `fun(t)` returns the loss and gradient at x + t d. Returns (f, g, t, evaluations) of the
    accepted point: the first trial satisfying both conditions, else the lowest point of the
    final bracket (which may be t = 0 with f0, g0 when nothing lower was found).
    """
    d_max = float(np.max(np.abs(d)))
    f, g = fun(t)
    evals, it = 1, 0
    gtd = float(g @ d)
    prev = _Point(0.0, f0, g0, gtd0)
    bracket: list[_Point] | None = None
    found: _Point | None = None
    # phase 1: expand until a bracket is found or the conditions hold
    while it < max_ls:
        cur = _Point(t, f, g, gtd)
        if f > f0 + c1 * t * gtd0 or (it > 1 and f >= prev.f):
            bracket = [prev, cur]
            break
        if abs(gtd) <= -c2 * gtd0:
            found = cur
            break
        if gtd >= 0:
            bracket = [prev, cur]
            break
        t_new = cubic_minimiser(prev.t, prev.f, prev.gtd, t, f, gtd,
                                bounds=(t + 0.01 * (t - prev.t), 10.0 * t))
        prev = cur
        t = t_new
        f, g = fun(t)
        evals += 1
        gtd = float(g @ d)
        it += 1
    if found is not None:
        return found.f, found.g, found.t, evals
    if bracket is None:  # budget spent while expanding
        bracket = [_Point(0.0, f0, g0, gtd0), _Point(t, f, g, gtd)]
    # phase 2: zoom (the bracket's ends are [low, high] by loss)
    low, high = (0, 1) if bracket[0].f <= bracket[1].f else (1, 0)
    insufficient = False
    done = False
    while not done and it < max_ls:
        a, b = bracket[0].t, bracket[1].t
        if abs(b - a) * d_max < tolerance_change:
            break
        t = cubic_minimiser(a, bracket[0].f, bracket[0].gtd, b, bracket[1].f, bracket[1].gtd)
        lo, hi = min(a, b), max(a, b)
        eps = 0.1 * (hi - lo)
        # too close to an end: move inside unless the last step was fine
        if min(hi - t, t - lo) < eps:
            if insufficient or t >= hi or t <= lo:
                t = hi - eps if abs(t - hi) < abs(t - lo) else lo + eps
                insufficient = False
            else:
                insufficient = True
        else:
            insufficient = False
        f, g = fun(t)
        evals += 1
        it += 1
        gtd = float(g @ d)
        cur = _Point(t, f, g, gtd)
        if f > f0 + c1 * t * gtd0 or f >= bracket[low].f:
            bracket[high] = cur
        else:
            if abs(gtd) <= -c2 * gtd0:
                done = True
            elif gtd * (bracket[high].t - bracket[low].t) >= 0:
                bracket[high] = bracket[low]
            bracket[low] = cur
        low, high = (0, 1) if bracket[0].f <= bracket[1].f else (1, 0)
    best = bracket[low]
    return best.f, best.g, best.t, evals


@dataclass
class StepInfo:
    """What one `step()` call did."""

    loss_before: float
    loss_after: float
    iterations: int
    evaluations: int
    stop: str  # max_iter, max_eval, tolerance_grad, tolerance_change (step / loss / slope)


@dataclass
class LBFGS:
    """torch.optim.LBFGS's algorithm on a flat float64 vector; state persists across `step()`
    calls."""

    x: np.ndarray
    lr: float = 1.0
    max_iter: int = 20
    max_eval: int | None = None
    tolerance_grad: float = 1e-7
    tolerance_change: float = 1e-9
    history_size: int = 100
    line_search: str = "strong_wolfe"
    # torch fixes these two; exposed for tests (e.g. near-exact line searches)
    wolfe_c1: float = 1e-4
    wolfe_c2: float = 0.9
    # state
    n_iter: int = 0
    func_evals: int = 0
    steps: list[StepInfo] = field(default_factory=list)
    _s: list = field(default_factory=list)
    _y: list = field(default_factory=list)
    _rho: list = field(default_factory=list)
    _h0: float = 1.0
    _d: np.ndarray | None = None
    _t: float | None = None
    _g_prev: np.ndarray | None = None
    _f_prev: float | None = None

    def __post_init__(self):
        self.x = np.array(self.x, dtype=float).ravel()
        if self.max_eval is None:
            self.max_eval = self.max_iter * 5 // 4
        if self.line_search not in LINE_SEARCHES:
            raise ValueError(f"unknown line search '{self.line_search}'; allowed: "
                             f"{', '.join(LINE_SEARCHES)}")
        if self.max_iter < 1 or self.history_size < 1 or self.lr <= 0:
            raise ValueError("need max_iter >= 1, history_size >= 1, lr > 0")

    def _direction(self, g: np.ndarray) -> np.ndarray:
        """-H g by the two-loop recursion over the stored pairs (newest last)."""
        q = -g
        alpha = []
        for s, y, rho in zip(reversed(self._s), reversed(self._y), reversed(self._rho)):
            a = rho * float(s @ q)
            alpha.append(a)
            q = q - a * y
        r = self._h0 * q
        for s, y, rho, a in zip(self._s, self._y, self._rho, reversed(alpha)):
            b = rho * float(y @ r)
            r = r + (a - b) * s
        return r

    def step(self, closure: Closure) -> float:
        """One outer step (up to `max_iter` inner iterations); returns the loss at its start."""
        f, g = closure(self.x)
        f, g = float(f), np.asarray(g, dtype=float).ravel()
        f_start, evals, n = f, 1, 0
        self.func_evals += 1
        if np.max(np.abs(g)) <= self.tolerance_grad:
            self.steps.append(StepInfo(f_start, f, 0, evals, "tolerance_grad"))
            return f_start
        stop = "max_iter"
        while n < self.max_iter:
            n += 1
            self.n_iter += 1
            if self.n_iter == 1:
                d = -g
                self._s, self._y, self._rho, self._h0 = [], [], [], 1.0
            else:
                y = g - self._g_prev
                s = self._t * self._d
                ys = float(y @ s)
                if ys > 1e-10:
                    if len(self._s) == self.history_size:
                        del self._s[0], self._y[0], self._rho[0]
                    self._s.append(s)
                    self._y.append(y)
                    self._rho.append(1.0 / ys)
                    self._h0 = ys / float(y @ y)
                d = self._direction(g)
            self._g_prev, self._f_prev = g.copy(), f
            t = min(1.0, 1.0 / float(np.sum(np.abs(g)))) * self.lr if self.n_iter == 1 else self.lr
            gtd = float(g @ d)
            self._d, self._t = d, t
            if gtd > -self.tolerance_change:
                stop = "tolerance_change (slope)"
                break
            if self.line_search == "strong_wolfe":
                x0 = self.x

                def along(tt, x0=x0, d=d):
                    ff, gg = closure(x0 + tt * d)
                    return float(ff), np.asarray(gg, dtype=float).ravel()

                f, g, t, ls = strong_wolfe(along, d, t, f, g, gtd, c1=self.wolfe_c1,
                                           c2=self.wolfe_c2, tolerance_change=self.tolerance_change)
                self._t = t
                self.x = x0 + t * d
                grad_ok = np.max(np.abs(g)) <= self.tolerance_grad
            else:
                self.x = self.x + t * d
                ls = 0
                grad_ok = False
                if n != self.max_iter:  # torch skips the evaluation after the last inner iteration
                    f, g = closure(self.x)
                    f, g = float(f), np.asarray(g, dtype=float).ravel()
                    ls = 1
                    grad_ok = np.max(np.abs(g)) <= self.tolerance_grad
            evals += ls
            self.func_evals += ls
            if n == self.max_iter:
                stop = "max_iter"
                break
            if evals >= self.max_eval:
                stop = "max_eval"
                break
            if grad_ok:
                stop = "tolerance_grad"
                break
            if np.max(np.abs(t * d)) <= self.tolerance_change:
                stop = "tolerance_change (step)"
                break
            if abs(f - self._f_prev) < self.tolerance_change:
                stop = "tolerance_change (loss)"
                break
        self.steps.append(StepInfo(f_start, f, n, evals, stop))
        return f_start


def minimize(closure: Closure, x0: np.ndarray, steps: int = 50,
             **options) -> tuple[np.ndarray, LBFGS]:
    """`steps` outer `step()` calls from x0 (torch's training-loop usage); returns (x,
    optimiser)."""
    opt = LBFGS(x0, **options)
    for _ in range(steps):
        opt.step(closure)
    return opt.x, opt
