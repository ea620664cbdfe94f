"""The interior-point method's loop: `InteriorNewton` (the rows and the band of one structure,
built once) and a run from a start, iteration by iteration (derivatives, record, convergence test,
the reduced matrix's factor, Mehrotra's probe and barrier update, the direction with its corrector,
the line search, the step)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ...model.limits import MotionLimits
from ...model.robot import CAMERA_PARAMETERS, Robot
from ..newton import TAU_MIN, NewtonRun, NewtonSolver, _SecantCorrection, parameters
from .band import BandPart
from .barrier import barrier_update, end_status, probe, safeguard, stalled
from .kkt import derivatives, directions, reduced_factor
from .line_search import line_search
from .options import ACCEPTABLE_CHANGE, RELAXED_MAX, InteriorOptions
from .record import InteriorRun, IterationRecord
from .rows import RowsPart, RunRows
from ...status import Status


@dataclass
class _State:
    """A run's iterate and what its iterations carry over."""

    x: np.ndarray
    c: np.ndarray  # the rows' values
    rho: np.ndarray  # the rows' relaxation
    s: np.ndarray  # the rows' slacks, c + rho
    w: np.ndarray  # the multipliers
    m: float  # the barrier parameter
    status: Status
    start_ok: bool
    m_last: float = 0.0  # the last iteration's barrier parameter
    it: int = 0
    shift: float = 0.0  # the last factorisation's diagonal shift
    f_hist: list = field(default_factory=list)
    last_step: float = 1.0
    stuck: int = 0
    relaxed_its: int = 0
    # the end-game's secant correction of the surrogate; the last point
    secant: _SecantCorrection | None = None
    previous: tuple | None = None
    last_az: float = 1.0
    last_socs: int = 0
    end_game: bool = False  # the tool rows' exact curvature from then on (else Gauss-Newton's)

    @property
    def nc(self) -> int:
        return len(self.c)


class InteriorNewton(RowsPart, BandPart):
    """The limit rows of one structure (robot, horizon, step time, limits, start at rest or in
    motion) around a projected Newton solver of the same structure, built once; `run` solves from a
    strictly feasible start."""

    def __init__(self, newton: NewtonSolver, robot: Robot, step_s: float, limits: MotionLimits,
                 moving: bool, codegen: bool, codegen_required: bool = False):
        t0 = time.perf_counter()
        self._build_linear_rows(newton, robot, step_s, limits, moving)
        self._build_tool_functions(*self._build_tool_points(robot, limits), codegen,
                                   codegen_required)
        self._build_windows()
        self._build_band_scatter()
        self.build_time_s = time.perf_counter() - t0

    def run(self, setup, init, v0=None, a0=None, tol: float = 1e-6, max_iter: int = 300,
            verbose: bool = False, warm: np.ndarray | None = None, mu0: float | None = None,
            relax: bool = False, reserve: float = 0.0,
            feasible_ok: bool = False, acceptable_change: float = ACCEPTABLE_CHANGE,
            use_secant: bool = True, relaxed_max: int = RELAXED_MAX) -> InteriorRun:
        """From `init`, which must be strictly within every row (else status `Infeasible_Start`: the
        caller starts elsewhere or hands over to IPOPT), with the start's velocity and acceleration
        `v0`, `a0` when the structure starts in motion; `warm`: multipliers of a previous run of the
        same structure (with `mu0`, the barrier parameter to start from). The options as
        `InteriorOptions`' (`solve` takes them as one).

        Steps keep every row within the fraction to the boundary: exactly for the bounds and linear
        rows (linear in the step), and for the curved ones (depths, tool speeds) by up to MAX_SOC
        second-order corrections before the step is shortened (IPOPT's), re-solving with what the
        linearisation missed. The barrier parameter follows Mehrotra's probe (the affine step's
        complementarity, cubed), and re-centres after a step cut short; the direction adds
        Mehrotra's corrector unless it then does not descend the barrier function. Relaxed rows
        (`relax`) lose their relaxation once every row holds with the boundary fraction of its
        slack; with nothing free (one step) the start is the plan or the problem is infeasible."""
        options = InteriorOptions(tol=tol, max_iter=max_iter, verbose=verbose, mu0=mu0,
                                  relax=relax, reserve=reserve, feasible_ok=feasible_ok,
                                  acceptable_change=acceptable_change, use_secant=use_secant,
                                  relaxed_max=relaxed_max)
        return self.solve(setup, init, options, v0=v0, a0=a0, warm=warm)

    def replan(self, setup, warm, options) -> InteriorRun:
        """A Planner's re-plan (`backends.ReplanSolver`): `options` a `backends.ReplanOptions`,
        what it leaves None `InteriorOptions`' defaults."""
        o = options
        given = dict(acceptable_change=o.acceptable_change, relaxed_max=o.relaxed_max)
        return self.solve(setup, warm, InteriorOptions(
            tol=o.tol, max_iter=o.max_iter, mu0=o.mu0, relax=o.relax, reserve=o.reserve,
            feasible_ok=o.feasible_ok, **{k: v for k, v in given.items() if v is not None}),
            v0=o.v0, a0=o.a0)

    def plan_at(self, setup, x, P, trace_ref: float, status, iterations: int,
                relaxed_iterations: int, t0: float) -> InteriorRun:
        """The run that ends at the joints `x` (flat) with `status` after `iterations` (a real-time
        iteration's moved iterate: no iteration of its own), timed from `t0`."""
        end = self.newton._end(setup, x, P, trace_ref, status, iterations, 0, t0)
        return InteriorRun(**{k: getattr(end, k) for k in NewtonRun.__dataclass_fields__},
                           relaxed_iterations=relaxed_iterations)

    def parameters(self, setup) -> np.ndarray:
        """The compiled functions' parameters of `setup` (projected Newton's)."""
        return parameters(setup)

    def solution(self, setup, method: str, start, run: InteriorRun, sigma=None):
        """The Solution of a run (the plan evaluated as projected Newton's are; `sigma`: its
        covariances when the caller has them), its solver named "interior"."""
        sol = self.newton.solution(setup, method, start, run, sigma=sigma)
        return sol.replaced(run=replace(sol.run, solver="interior"))

    def solve(self, setup, init, options: InteriorOptions, v0=None, a0=None,
              warm: np.ndarray | None = None) -> InteriorRun:
        """`run` with its options as one object; each iteration's record in the run's `history`
        (printed as it is made with `options.verbose`)."""
        t0 = time.perf_counter()
        rows, st, trace_ref = _start(self, setup, init, v0, a0, warm, options)
        history = []
        while st.start_ok and _iteration(self, rows, st, options, history):
            pass
        run = self.newton._end(setup, st.x, rows.P, trace_ref, st.status, st.it, 0, t0)
        return InteriorRun(**{k: getattr(run, k) for k in NewtonRun.__dataclass_fields__},
                           multipliers=st.w, relaxed_iterations=st.relaxed_its, history=history)


def _start(ip, setup, init, v0, a0, warm, o: InteriorOptions) -> tuple[RunRows, _State, float]:
    """(the run's rows, its start state, the objective's scale): the start point, its rows'
    relaxation (`relax`), the multipliers (`warm` or mu / s) and the status it starts with."""
    nw, nq = ip.newton, ip.nq
    P = parameters(setup)
    x = np.array(init.q, float).ravel()
    idx = ip.free_idx
    min_depth = setup.ocp.min_depth
    lin_c = ip._lin_const(v0, a0)
    offsets = ip._tool_offsets(v0, a0)
    # the fraction of the velocity, acceleration and tool-speed limits the plan may use
    keep = 1.0 - o.reserve
    tool_scale = ip.tool_scale / keep**2
    # the objective's scale: the start's trace (by the rows' function: no derivatives)
    P[CAMERA_PARAMETERS] = trace_ref = float(nw.fz(x, P)[2][0])
    m = o.mu_init if o.mu0 is None else o.mu0
    nb, nl = len(idx), ip.n_lin
    rows = RunRows(P, lin_c, offsets, min_depth, keep, tool_scale, idx, nb, nl, 2 * nb + 2 * nl)
    x, f_val, c = ip._start_point(x, P, lin_c, offsets, min_depth, keep, o.relax)
    # rows outside (or within RELAX_TO of) their boundary at the start are relaxed by rho, which
    # every step of length a shrinks by (1 - a): the Newton step aims at rho = 0 (an
    # infeasible-start interior point)
    rho = (np.maximum(o.relax_to - c, 0.0) if o.relax and not np.all(c > 0)
           else np.zeros(len(c)))
    start_ok = bool(np.all(np.isfinite(c)) and np.all(c + rho > 0)
                    and np.allclose(x[:nq], setup.q_start, atol=1e-12))
    nc = len(c)
    s = c + rho  # the rows' slacks
    # the multipliers
    w = (np.asarray(warm, float).copy() if warm is not None and len(warm) == nc else m / s)
    if warm is not None and len(warm) == nc:
        w = safeguard(w, m, s)
    status = Status.MAXIMUM_ITERATIONS_EXCEEDED if start_ok else Status.INFEASIBLE_START
    if start_ok and nb == 0:
        # nothing free (a one-step plan): the start is the plan, within every row or not (else
        # the relaxation shrinks towards a slack of 0, and w / s overflows)
        status = Status.SOLVE_SUCCEEDED if np.all(c > 0) else Status.INFEASIBLE_PROBLEM_DETECTED
        start_ok = False
    return rows, _State(x, c, rho, s, w, m, status, start_ok, m_last=m), trace_ref


def _iteration(ip, rows: RunRows, st: _State, o: InteriorOptions, history: list) -> bool:
    """One iteration from `st` (updated in place): False once the run ends (`st.status`)."""
    d = derivatives(ip, rows, st.x, st.w, st.s, st.nc, st.end_game, st.secant, st.previous)
    st.f_hist.append(d.f_val)
    is_stalled = stalled(st.f_hist, d.f_val, o)
    record = IterationRecord(st.it, d.f_val, st.m, d.err_d, d.gap, st.rho.max(initial=0),
                             st.last_step, st.last_az, st.last_socs)
    history.append(record)
    if o.verbose:
        print(record.line(), flush=True)
    status = end_status(st.status, d.gap, d.err_d, is_stalled, st.rho, st.c, st.it,
                        st.relaxed_its, o)
    if status is not None:
        st.status = status
        return False
    sig, factor = reduced_factor(ip, rows, d, st.w, st.s, st.end_game, st.shift)
    if factor is None:
        st.status = Status.SINGULAR_HESSIAN
        return False
    solve, st.shift, band_factor, fixed = factor
    # the tool rows' exact curvature from the end-game on (Gauss-Newton's can stall there)
    st.end_game = st.end_game or (not st.rho.any() and d.gap <= o.secant_gap)
    if st.secant is None and o.use_secant and d.gap <= o.secant_gap and not st.rho.any():
        st.secant = _SecantCorrection(ip.n)  # the end-game: pairs from the next step on
    st.previous = (st.x, d.g)
    s, w, rho = st.s, st.w, st.rho
    direction = directions(d.jac, solve, st.secant, band_factor, fixed, d.g, s, w, sig, rho)
    dca, dwa, gap_aff = probe(direction, s, w, st.nc)
    m = st.m = barrier_update(st.m, st.m_last, d.gap, gap_aff, d.err_d, is_stalled, rho,
                              st.last_step, o)
    st.m_last = m
    # Mehrotra's corrector: the affine step's second-order complementarity term, unless the
    # direction then does not descend the barrier function (slope g.dx - (mu / s).(J dx))
    dx, dc, dw = direction(m - dca * dwa)
    if float(d.g @ dx) - m * float((dc + rho) @ (1.0 / s)) >= 0.0:
        dx, dc, dw = direction(m)
    found, az, socs = line_search(ip, rows, st.x, st.c, s, w, rho, d.f_val, d.g, (dx, dc, dw), m,
                                  d.jac, solve, sig, o)
    return _step(st, found, dx, dw, az, socs, o)


def _step(st: _State, found, dx, dw, az, socs, o: InteriorOptions) -> bool:
    """The line search's point taken (`found`: point, rows, step length), the relaxation shrunk
    and the multipliers stepped: False if the run ends (a failed line search, a relaxation that no
    longer shrinks)."""
    rho, x, nc = st.rho, st.x, st.nc
    if found is None:
        st.status = Status.INFEASIBLE_PROBLEM_DETECTED if rho.any() else Status.LINE_SEARCH_FAILED
        return False
    st.last_step = float(np.max(np.abs(found[0] - x)) / max(float(np.max(np.abs(dx))), 1e-300))
    st.stuck = st.stuck + 1 if rho.any() and found[2] < o.stuck_step else 0
    if st.stuck == o.stuck_iter:
        # the relaxation no longer shrinks: no point within every row near here
        st.status = Status.INFEASIBLE_PROBLEM_DETECTED
        return False
    x, c = found[0], found[1]
    rho = (1.0 - found[2]) * rho if found[2] < 1.0 else np.zeros(nc)
    if rho.any() and np.all(c >= (1.0 - TAU_MIN) * (c + rho)):
        # every row holds, each with at least the boundary fraction of its slack: the
        # relaxation is done (else it would end only with a full step, after many short ones
        # that shrink it geometrically); a row barely inside would leave a slack near 0
        rho = np.zeros(nc)
    s = c + rho
    w = st.w + min(1.0, az) * dw
    st.last_az, st.last_socs = az, socs
    # IPOPT's safeguard keeps w s within a band around mu
    w = safeguard(w, st.m, s)
    st.x, st.c, st.rho, st.s, st.w = x, c, rho, s, w
    st.it += 1
    st.relaxed_its += bool(rho.any())
    return True
