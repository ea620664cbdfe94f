"""The solve strategy (surestep_ocp.solvers.strategy) picks its fallback by what failed.

First through whole solves (`ocp.solve_ocp`), on problems where a fallback is needed, the plans
checked against IPOPT's own optimum, Pinocchio's FK and the NumPy EKF; then the strategy as data, on
hand-made histories and configurations with a fake backend (no solve)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import numpy_ekf as ref
from surestep_ocp.methods.baseline import solve_baseline
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.methods.registry import ocp_initial_guess
from surestep_ocp.methods.ocp import solve_ocp
from surestep_ocp.problem.load import load_problem
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.problem.solver_config import ResolvedSolver, SolverName
from surestep_ocp.solvers import strategy
from surestep_ocp.solvers.backends import BACKENDS, Context, Outcome
from surestep_ocp.solvers.backends.base import why_not
from surestep_ocp.solvers.backends.ipopt import ipopt_options
from surestep_ocp.ocp.iterate import InitialGuess, Iterate, PrimalDual
from surestep_ocp.solvers.nlp_cache import LIFTED_FROM_CONDENSED
from surestep_ocp.output.solution_records import SolveRecord
from surestep_ocp.solvers.strategy import Attempt, Condition, Stop, default_strategy, run

DEFAULT = Path(__file__).resolve().parents[1] / "problems" / "needle_regrasp_paper_pace.yaml"
EVALUATION = DEFAULT.parent / "evaluations" / "evaluation.yaml"


def _configuration_73(solver: str):
    sampler = ConfigurationSampler(load_evaluation(EVALUATION))
    prob = replace(sampler.problem(sampler.sample(0, 73)), horizon=40)
    return build_setup(replace(prob, solver=replace(prob.solver, codegen=False, name=solver)))


def test_a_false_infeasibility_verdict_is_retried_with_the_monotone_barrier(monkeypatch):
    """IPOPT alone on the default problem (T = 6), its first attempt made to end "infeasible" (as
    the adaptive barrier did on evaluation configuration 73 at T = 40, compiled): the monotone
    barrier with the same Hessian runs next, and no exact-Hessian attempt; its plan is IPOPT's own
    optimum, below the straight line."""
    import surestep_ocp.ocp.transcription as tr

    setup = build_setup(replace(load_problem(DEFAULT), horizon=6))
    setup = setup.with_ocp(solver=replace(setup.ocp.solver, name="ipopt"))
    plain = solve_ocp(setup, ocp_initial_guess(setup))
    real, calls = tr.Transcription.solve, []

    def first_infeasible(self, *args, **kw):
        sol, reached = real(self, *args, **kw)
        calls.append(sol.status)
        if len(calls) == 1:
            sol = replace(sol, status="Infeasible_Problem_Detected", success=False)
        return sol, reached

    monkeypatch.setattr(tr.Transcription, "solve", first_infeasible)
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("surrogate", "Infeasible_Problem_Detected"),
                     ("surrogate, monotone barrier", "Solve_Succeeded")]
    assert sol.trace_final == pytest.approx(plain.trace_final, rel=1e-5)
    assert sol.trace_final < solve_baseline(setup).trace_final


def _ipopt_monotone(setup):
    """IPOPT alone with its monotone barrier update: the central path Newton's barrier run
    follows."""
    spec = setup.ocp.solver
    return setup.with_ocp(solver=replace(spec, name="ipopt",
                                         options={**spec.options, "mu_strategy": "monotone"}))


def test_a_depth_violation_by_newton_goes_to_newton_on_the_barrier_problem():
    """The same configuration with the default solver: Newton's plan goes below the depth bound,
    Newton on IPOPT's barrier problem runs next and is the plan. It is IPOPT's own (monotone
    barrier) optimum, meets the bound by Pinocchio's FK, and its trace is the NumPy EKF's and below
    the straight line's."""
    setup = _configuration_73("auto")
    init = ocp_initial_guess(setup)
    sol = solve_ocp(setup, init)
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("newton", "Depth_Bound_Violated"),
                     ("newton, depth barrier", "Solve_Succeeded")]
    assert sol.run.solver == "newton"
    ipopt = solve_ocp(_ipopt_monotone(setup), init)
    assert ipopt.run.solver == "ipopt" and ipopt.success
    assert sol.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    depths = [setup.pose_of(q)[2] for q in np.asarray(sol.q)]
    assert min(depths) >= setup.ocp.min_depth
    poses = np.asarray(sol.poses)
    n = setup.ocp.noise
    ekf = np.trace(ref.propagate(poses, n, setup.ocp.intrinsics,
                                 guard=n.cosine_guard**2)[0][-1])
    assert ekf == pytest.approx(sol.trace_final, rel=1e-9)
    assert sol.trace_final < solve_baseline(setup).trace_final


def test_a_failed_barrier_run_goes_to_ipopts_monotone_barrier(monkeypatch):
    """Where Newton's barrier run does not converge (here: cut to one iteration), IPOPT with the
    monotone barrier follows from the straight line, and its plan meets the bound."""
    from surestep_ocp.solvers.newton import NewtonSolver

    real = NewtonSolver.run_barrier
    monkeypatch.setattr(NewtonSolver, "run_barrier",
                        lambda self, setup, init, tol=1e-6, max_iter=300,
                        verbose=False: real(self, setup, init, tol, 1, verbose))
    setup = _configuration_73("auto")
    sol = solve_ocp(setup, ocp_initial_guess(setup))
    names = [(a.label, a.status) for a in sol.attempts]
    assert names == [("newton", "Depth_Bound_Violated"),
                     ("newton, depth barrier", "Maximum_Iterations_Exceeded"),
                     ("surrogate, monotone barrier", "Solve_Succeeded")]
    assert sol.run.solver == "ipopt"
    assert np.asarray(sol.poses)[:, 2].min() >= setup.ocp.min_depth - 1e-8


def test_newton_stops_early_below_the_depth_bound_and_the_fallback_meets_it(monkeypatch):
    """Configuration 73 at T = 40: Newton's iterates go below the minimum depth in its end phase and
    stay there; it stops there (fewer iterations than without the check, same verdict), and the
    returned plan meets the bound by Pinocchio's FK of its joints."""
    import surestep_ocp.solvers.newton as newton
    from surestep_ocp.solvers.nlp_cache import newton_solver

    setup = _configuration_73("auto")
    init = ocp_initial_guess(setup)
    early = newton_solver(setup).run(setup, init)
    monkeypatch.setattr(newton, "DEPTH_CHECK_BELOW", -1.0)  # never checked before the end
    late = newton_solver(setup).run(setup, init)
    monkeypatch.undo()
    assert early.status == late.status == "Depth_Bound_Violated"
    assert early.iterations < late.iterations
    sol = solve_ocp(setup, init)
    assert sol.success and sol.attempts[0].status == "Depth_Bound_Violated"
    depths = [setup.pose_of(q)[2] for q in np.asarray(sol.q)]
    assert min(depths) >= setup.ocp.min_depth - 1e-7


# ------------------------------------------------------- the strategy as data (solvers/strategy.py)
# Hand-made histories and configurations, no solve: `Condition.holds` on fake attempts,
# `default_strategy`'s attempt lists against the order written out by hand from
# docs/hessian_and_newton.md ("Fallbacks: the order of attempts"), and `run` with a fake backend in
# place of Newton and IPOPT.


def tried(*statuses: str, solved: int | None = None) -> list:
    """A history of attempts that ended with `statuses`; `solved`: the index of the one that
    succeeded."""
    return [SimpleNamespace(outcome=SimpleNamespace(
                solution=SimpleNamespace(status=s, success=k == solved)))
            for k, s in enumerate(statuses)]


def test_condition_holds_on_hand_made_histories():
    depth, infeasible = strategy.DEPTH, strategy.INFEASIBLE
    unsolved = Condition()
    assert unsolved.holds([]) and unsolved.holds(tried("Maximum_Iterations_Exceeded"))
    assert not unsolved.holds(tried("Maximum_Iterations_Exceeded", "Solve_Succeeded", solved=1))
    assert strategy.ALWAYS.holds(tried("Solve_Succeeded", solved=0)) and strategy.ALWAYS.holds([])
    after_depth = Condition(first_status_in=(depth,))
    assert not after_depth.holds([])  # no first attempt yet
    assert after_depth.holds(tried(depth, "Maximum_Iterations_Exceeded"))  # the first, not the last
    assert not after_depth.holds(tried("Maximum_Iterations_Exceeded", depth))
    not_after_depth = Condition(first_status_not_in=(depth,))
    assert not_after_depth.holds([]) and not_after_depth.holds(tried("Stalled"))
    assert not not_after_depth.holds(tried(depth))
    last = Condition(last_status_in=strategy.FALSE_VERDICTS)
    assert not last.holds([])
    assert last.holds(tried("Stalled", "Restoration_Failed"))
    assert not last.holds(tried("Restoration_Failed", "Stalled"))
    both = Condition(first_status_not_in=(depth,), last_status_in=(infeasible,))
    assert both.holds(tried(infeasible)) and not both.holds(tried(depth, infeasible))
    # a succeeded attempt ends every unsolved condition, whatever the statuses
    assert not both.holds(tried(infeasible, infeasible, solved=0))
    assert Condition(unsolved=False, first_status_in=(depth,)).holds(tried(depth, "x", solved=1))


def resolved(name="auto", form="condensed", hessian="surrogate", forced=False,
             fits=True) -> ResolvedSolver:
    return ResolvedSolver(SolverName(name), form, hessian, forced, fits)


def context(r: ResolvedSolver, limits=False, scalar=True, structured=True, max_iter=3000,
            surrogate_max_iter=300):
    """A Context with only what the strategy reads: the resolved choices, the solver spec's caps,
    whether the limits are enforced and the model's structure."""
    spec = SimpleNamespace(max_iter=max_iter, surrogate_max_iter=surrogate_max_iter)
    setup = SimpleNamespace(ocp=SimpleNamespace(solver=spec,
                                                limits=SimpleNamespace(enforce=limits)),
                            model=SimpleNamespace(scalar=scalar, structured=structured))
    return Context(setup, r, "ocp", {})


def described(steps) -> list:
    """Each step as (label, backend, Hessian, start) or "STOP"."""
    return ["STOP" if isinstance(s, Stop) else (s.label, s.backend, s.hessian, s.start.value)
            for s in steps]


DUALS = Iterate(np.zeros((2, 7)), PrimalDual(np.zeros(1), np.zeros(1), np.zeros(1), np.ones(1),
                                             1.0))
NEWTON_END = Iterate(np.zeros((2, 7)))  # a Newton plan's joints: no multipliers

# The order of docs/hessian_and_newton.md, written out: Newton where it applies (its barrier run
# after a violated depth bound, the scalar recursion); IPOPT with the surrogate Hessian from init
# (the monotone barrier instead after Newton's depth violation; the monotone barrier after a false
# infeasibility verdict); the exact Hessian from where it stopped; the exact Hessian from init,
# adaptive then monotone barrier.
SURROGATE_THEN_EXACT = [
    ("surrogate, monotone barrier", "ipopt", "surrogate", "init"),
    ("surrogate", "ipopt", "surrogate", "init"),
    ("surrogate, monotone barrier", "ipopt", "surrogate", "init"),
    ("exact", "ipopt", "exact", "reached"),
    ("exact", "ipopt", "exact", "init"),
    ("exact, monotone barrier", "ipopt", "exact", "init"),
]
NEWTON = [("newton", "newton", None, "given"), ("newton, depth barrier", "newton", None, "init")]
# within enforced limits, under auto or interior
INTERIOR = [("interior point", "interior", None, "given")]
EXPECTED = {
    "auto": NEWTON + SURROGATE_THEN_EXACT,
    # no barrier run, no unrolled exact Hessian
    "auto, 6x6 recursion": NEWTON[:1] + SURROGATE_THEN_EXACT[:3],
    "ipopt": SURROGATE_THEN_EXACT,
    "newton": NEWTON + SURROGATE_THEN_EXACT,
    # enforced limits: no Newton under auto, no barrier retry; an infeasibility verdict is the
    # limits' (stop)
    # (the interior point's own verdict stops too)
    "auto, limits": INTERIOR + ["STOP"] + SURROGATE_THEN_EXACT[:2] + ["STOP"]
    + SURROGATE_THEN_EXACT[3:],
    "newton, limits": NEWTON + SURROGATE_THEN_EXACT[:2] + ["STOP"] + SURROGATE_THEN_EXACT[3:],
    # a forced Hessian: its own runs only, no exact-Hessian attempt
    "gauss-newton": [("gauss-newton, monotone barrier", "ipopt", "gauss-newton", "init"),
                     ("gauss-newton", "ipopt", "gauss-newton", "init"),
                     ("gauss-newton, monotone barrier", "ipopt", "gauss-newton", "init")],
    # `solver.hessian: exact`: the exact Hessian from init, adaptive then monotone
    "exact": SURROGATE_THEN_EXACT[4:],
    # the barrier update pinned by the problem or the caller: no monotone fallbacks
    "pinned": NEWTON + [("surrogate", "ipopt", "surrogate", "init"),
                        ("exact", "ipopt", "exact", "reached"),
                        ("exact", "ipopt", "exact", "init")],
    # the lifted form from the condensed solution: the small monotone barrier, then the adaptive one
    "lifted start": [("lifted", "ipopt", "surrogate", "init"),
                     ("lifted, adaptive barrier", "ipopt", "surrogate",
                      "init")] + SURROGATE_THEN_EXACT[4:],
    "lifted start, 6x6 recursion": [("lifted", "ipopt", "surrogate", "init"),
                                    ("lifted, adaptive barrier", "ipopt", "surrogate", "init")],
    "lifted, pinned": [("lifted", "ipopt", "surrogate", "init"),
                       ("exact", "ipopt", "exact", "init")],
    # a warm start with IPOPT's multipliers: the exact Hessian from there first, then the cold order
    # without Newton
    "warm with duals": [("exact", "ipopt", "exact", "given")] + SURROGATE_THEN_EXACT,
    # (the lifted NLP's own structured Hessian from there; its false infeasibility verdicts retried
    # as above)
    "warm with duals, lifted": [("surrogate", "ipopt", "surrogate", "given"),
                                ("lifted", "ipopt", "surrogate", "init"),
                                ("surrogate, monotone barrier", "ipopt", "surrogate", "init")]
    + SURROGATE_THEN_EXACT[4:],
    # a Newton iterate (no multipliers): Newton from it, as cold
    "warm without duals": NEWTON + SURROGATE_THEN_EXACT,
}
CONFIGURATIONS = {  # name: (resolved, context keywords, warm, pinned, lifted_start)
    "auto": (resolved(), {}, None, False, False),
    "auto, 6x6 recursion": (resolved(), dict(scalar=False), None, False, False),
    "ipopt": (resolved("ipopt"), {}, None, False, False),
    "newton": (resolved("newton"), {}, None, False, False),
    "auto, limits": (resolved(), dict(limits=True), None, False, False),
    "newton, limits": (resolved("newton"), dict(limits=True), None, False, False),
    "gauss-newton": (resolved(hessian="gauss-newton", forced=True, fits=False), {}, None, False,
                     False),
    "exact": (resolved(hessian="exact", fits=False), {}, None, False, False),
    "pinned": (resolved(), {}, None, True, False),
    "lifted start": (resolved(form="full", fits=False), {}, None, False, True),
    "lifted start, 6x6 recursion": (resolved(form="full", fits=False), dict(scalar=False), None,
                                    False, True),
    "lifted, pinned": (resolved(form="full", fits=False), {}, None, True, True),
    "warm with duals": (resolved(), {}, DUALS, False, False),
    "warm with duals, lifted": (resolved(form="full", fits=False), {}, DUALS, False, False),
    "warm without duals": (resolved(), {}, NEWTON_END, False, False),
}


@pytest.mark.parametrize("name", list(CONFIGURATIONS))
def test_default_strategy_is_the_documented_order(name):
    r, kw, warm, pinned, lifted_start = CONFIGURATIONS[name]
    assert (described(default_strategy(context(r, **kw), warm, pinned, lifted_start))
            == EXPECTED[name])


def test_default_strategy_caps_and_barrier_options():
    """The surrogate's cap (`surrogate_max_iter`, `max_iter` when the Hessian is forced), the
    monotone barrier where the label says so, the exact Hessian's cap with the limits enforced, the
    lifted start's small barrier."""
    steps = default_strategy(context(resolved(), surrogate_max_iter=40), None, False, False)
    by_label = {s.label: s for s in reversed(steps)}  # the first of two same labels
    assert by_label["surrogate"].options == {"max_iter": 40}
    assert by_label["surrogate, monotone barrier"].options == {"max_iter": 40,
                                                               "barrier_update": "monotone"}
    assert (by_label["exact"].options == {}
            and by_label["exact, monotone barrier"].options == {"barrier_update": "monotone"})
    assert by_label["newton, depth barrier"].options == {"depth_barrier": True}
    forced = default_strategy(context(resolved(hessian="surrogate", forced=True, fits=False),
                                      max_iter=900, surrogate_max_iter=40), None, False, False)
    assert {s.options["max_iter"] for s in forced} == {900}
    limited = default_strategy(context(resolved(), limits=True, surrogate_max_iter=40), None, False,
                               False)
    assert all(s.options.get("max_iter") == 40 for s in limited
               if isinstance(s, Attempt) and s.backend == "ipopt")
    lifted = default_strategy(context(resolved(form="full", fits=False)), None, False, True)
    assert lifted[0].options == {"max_iter": 300, "near_start": True}
    assert lifted[1].options == {"max_iter": 300}
    # in IPOPT's words
    assert ipopt_options(lifted[0].options) == {**LIFTED_FROM_CONDENSED, "ipopt.max_iter": 300}
    assert (ipopt_options({"max_iter": 40, "barrier_update": "monotone"})
            == {"ipopt.max_iter": 40, "ipopt.mu_strategy": "monotone"})
    with pytest.raises(ValueError, match="ipopt.tol"):
        ipopt_options({"ipopt.tol": 1e-9})


class FakeBackend:
    """Ends its attempts with the scripted statuses, in order; records what each attempt was
    given."""

    def __init__(self, name: str, script: list[str], calls: list):
        self.name, self.script, self.calls = name, script, calls
        # the real backend's declaration: the strategy is derived from it
        self.label, self.handles = BACKENDS[name].label, BACKENDS[name].handles

    def applies(self, ctx):
        return why_not(self.handles, ctx)

    def solve(self, ctx, start, warm, hessian, options):
        status = self.script[len(self.calls)]
        self.calls.append(SimpleNamespace(backend=self.name, start=start, warm=warm,
                                          hessian=hessian, options=options))
        ok = status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        sol = SimpleNamespace(status=status, success=ok, run=SolveRecord(solver=self.name))
        # IPOPT ends with a primal-dual point, Newton with joints only
        return Outcome(sol, Iterate(np.full((2, 7), len(self.calls)),
                                    DUALS.dual if self.name == "ipopt" else None))


@pytest.fixture()
def fake(monkeypatch):
    """Both backends replaced by one script of statuses (the registry and the strategy's imported
    name)."""
    from surestep_ocp.solvers import backends

    def install(*script: str):
        calls: list = []
        fakes = {n: FakeBackend(n, list(script), calls) for n in ("newton", "ipopt")}
        monkeypatch.setattr(backends, "BACKENDS", fakes)
        monkeypatch.setattr(strategy, "BACKENDS", fakes)
        return calls

    return install


INIT = InitialGuess(np.zeros((2, 7)), "straight line")


def labels(ran) -> list:
    return [(t.label, t.outcome.solution.status) for t in ran]


def test_run_stops_at_the_first_success_and_skips_conditions_that_do_not_hold(fake):
    calls = fake("Maximum_Iterations_Exceeded", "Maximum_Iterations_Exceeded", "Solve_Succeeded")
    ran = run(default_strategy(context(resolved()), None, False, False), context(resolved()), INIT,
              None)
    # Newton stopped short (no depth violation: no barrier run, the adaptive barrier); the surrogate
    # stopped short; the exact Hessian from where it stopped succeeded: nothing after it
    assert labels(ran) == [("newton", "Maximum_Iterations_Exceeded"),
                           ("surrogate", "Maximum_Iterations_Exceeded"),
                           ("exact, warm start", "Solve_Succeeded")]
    assert [c.backend for c in calls] == ["newton", "ipopt", "ipopt"]
    # GIVEN without a warm start: the initial guess
    assert calls[0].start is INIT and calls[0].warm is None
    assert calls[1].start is INIT and calls[1].warm is None and calls[1].hessian == "surrogate"
    # REACHED: where it ended
    assert calls[2].warm is ran[1].outcome.iterate and calls[2].hessian == "exact"


def test_run_after_a_depth_violation_takes_the_barrier_runs(fake):
    depth = strategy.DEPTH
    fake(depth, "Maximum_Iterations_Exceeded", "Solve_Succeeded")
    ran = run(default_strategy(context(resolved()), None, False, False), context(resolved()), INIT,
              None)
    assert labels(ran) == [("newton", depth),
                           ("newton, depth barrier", "Maximum_Iterations_Exceeded"),
                           ("surrogate, monotone barrier", "Solve_Succeeded")]
    fake(depth, "Solve_Succeeded")  # the barrier run converged: it is the plan
    ran = run(default_strategy(context(resolved()), None, False, False), context(resolved()), INIT,
              None)
    assert labels(ran) == [("newton", depth), ("newton, depth barrier", "Solve_Succeeded")]


def test_run_retries_a_false_infeasibility_verdict_with_the_monotone_barrier(fake):
    r = resolved("ipopt", fits=False)
    calls = fake(strategy.INFEASIBLE, "Solve_Succeeded")
    ran = run(default_strategy(context(r), None, False, False), context(r), INIT, None)
    assert labels(ran) == [("surrogate", strategy.INFEASIBLE),
                           ("surrogate, monotone barrier", "Solve_Succeeded")]
    assert calls[1].options["barrier_update"] == "monotone" and calls[1].warm is None


def test_run_stops_at_an_infeasibility_verdict_with_the_limits_enforced(fake):
    ctx = context(resolved("ipopt"), limits=True)
    fake(strategy.INFEASIBLE, "Solve_Succeeded")
    ran = run(default_strategy(ctx, None, False, False), ctx, INIT, None)
    assert labels(ran) == [("surrogate", strategy.INFEASIBLE)]  # the Stop: no exact-Hessian attempt
    # stopped short: the exact Hessian goes on
    fake("Maximum_Iterations_Exceeded", "Solve_Succeeded")
    ran = run(default_strategy(ctx, None, False, False), ctx, INIT, None)
    assert labels(ran) == [("surrogate", "Maximum_Iterations_Exceeded"),
                           ("exact, warm start", "Solve_Succeeded")]


def test_run_starts_from_the_given_iterate(fake):
    """GIVEN: Newton starts at a Newton iterate's joints (a new initial guess naming its source),
    IPOPT at a primal-dual point; both labelled ", warm start". An ALWAYS attempt runs even after a
    success."""
    calls = fake("Solve_Succeeded")
    ran = run(default_strategy(context(resolved()), NEWTON_END, False, False), context(resolved()),
              INIT, NEWTON_END)
    assert labels(ran) == [("newton, warm start", "Solve_Succeeded")]
    assert calls[0].warm is NEWTON_END and calls[0].start.source == "warm start (straight line)"
    np.testing.assert_array_equal(calls[0].start.q, NEWTON_END.q)
    calls = fake("Solve_Succeeded")
    ran = run(default_strategy(context(resolved()), DUALS, False, False), context(resolved()), INIT,
              DUALS)
    assert labels(ran) == [("exact, warm start", "Solve_Succeeded")]
    assert calls[0].warm is DUALS and calls[0].start is INIT and calls[0].hessian == "exact"
    always = (Attempt("a", "ipopt", "exact"), Attempt("b", "ipopt", "exact", when=strategy.ALWAYS),
              Attempt("c", "ipopt", "exact"))
    fake("Solve_Succeeded", "Solve_Succeeded")
    assert [t.label for t in run(always, context(resolved()), INIT, None)] == ["a", "b"]


# Which backend goes first, written out from docs/hessian_and_newton.md: `solver.name`'s own where
# it applies, under auto projected Newton without enforced limits and the interior point within
# them, none where neither fits or IPOPT is named. (name, limits enforced, Newton fits) -> first
FIRST = {("auto", False, True): "newton", ("auto", True, True): "interior",
         ("auto", False, False): None, ("auto", True, False): None,
         ("newton", False, True): "newton", ("newton", True, True): "newton",
         ("newton", False, False): None, ("interior", True, True): "interior",
         ("interior", False, True): None, ("interior", True, False): None,
         ("ipopt", False, True): None, ("ipopt", True, True): None}


@pytest.mark.parametrize("case", list(FIRST))
def test_the_first_backend_follows_the_declarations(case):
    name, limits, fits = case
    ctx = context(resolved(name, fits=fits), limits=limits)
    first = strategy.first_backend(ctx)
    assert (None if first is None else first.name) == FIRST[case]
    # the Planner re-plans from the moving robot only within the limits, with the interior point
    mover = strategy.replan_backend(ctx)
    assert (None if mover is None else mover.name) == ("interior" if FIRST[case] == "interior"
                                                       else None)


def test_a_new_backend_is_tried_by_what_it_declares(monkeypatch):
    """A backend registered before the others with its declaration only (enforced limits, any
    model it fits) goes first under auto within the limits, with the verdict stop a backend that
    carries the limits gets; nothing in the strategy names it. Without `moving_start` the Planner
    does not re-plan with it."""
    from surestep_ocp.solvers import backends
    from surestep_ocp.solvers.backends.base import Handles

    class Fresh(FakeBackend):
        def __init__(self):
            self.name, self.label = "fresh", "fresh method"
            self.handles = Handles(limits=True, only_limits=True)

    fresh = {"fresh": Fresh(), **BACKENDS}
    monkeypatch.setattr(backends, "BACKENDS", fresh)
    monkeypatch.setattr(strategy, "BACKENDS", fresh)
    steps = described(default_strategy(context(resolved(), limits=True), None, False, False))
    assert steps[:2] == [("fresh method", "fresh", None, "given"), "STOP"]
    assert steps[2:] == SURROGATE_THEN_EXACT[:2] + ["STOP"] + SURROGATE_THEN_EXACT[3:]
    # without the limits it does not apply: projected Newton first, as before
    assert described(default_strategy(context(resolved()), None, False, False)) == EXPECTED["auto"]
    assert strategy.replan_backend(context(resolved(), limits=True)) is None


def test_an_attempt_option_its_backend_does_not_take_is_refused(fake):
    fake("Solve_Succeeded")
    bad = (Attempt("newton", "newton", options={"max_iter": 3}),)
    with pytest.raises(ValueError, match="takes no options"):
        run(bad, context(resolved()), INIT, None)
