"""The OCP solver backends (surestep_ocp.solvers.backends): every registered one keeps the `Backend`
protocol, and every solver name but `auto` has exactly one; on one small problem Newton and IPOPT
(another algorithm, with the exact Hessian) reach the same plan, and both plans' covariances are a
plain NumPy EKF's (tests/numpy_ekf.py) along the plan's poses; `applies` says why Newton does not
apply; and the solution file's attempt records read from the format before they were typed.
"""

from __future__ import annotations

import inspect
import json
from dataclasses import replace

import numpy as np
import numpy_ekf as ref
import pytest

from surestep_ocp.model.belief import COSINE_GUARD
from surestep_ocp.output.attempt_record import AttemptRecord
from surestep_ocp.output.solution import Solution
from surestep_ocp.problem.setup import build_setup
from surestep_ocp.problem.solver_config import SolverName, resolve
from surestep_ocp.solvers.backends import BACKENDS, Backend, Context
from surestep_ocp.ocp.iterate import Iterate
from surestep_ocp.methods.registry import ocp_initial_guess, run_method
from surestep_ocp.methods.ocp import resolved_solver


@pytest.fixture(scope="module")
def small(default_problem):
    """The default problem at 6 steps, interpreted derivatives (no compile in the test)."""
    prob = replace(default_problem, horizon=6,
                   solver=replace(default_problem.solver, codegen=False))
    setup = build_setup(prob)
    return setup, Context(setup, resolved_solver(setup), "ocp", {})


@pytest.fixture(scope="module")
def plans(small):
    """One attempt of each backend from the same straight line: Newton, and IPOPT with the exact
    Hessian."""
    setup, ctx = small
    init = ocp_initial_guess(setup)
    return {"newton": BACKENDS["newton"].solve(ctx, init, None, None, {}),
            "ipopt": BACKENDS["ipopt"].solve(replace(ctx, options={"ipopt.tol": 1e-10}), init,
                                             None, "exact", {})}


@pytest.mark.parametrize("key", list(BACKENDS))
def test_every_registered_backend_keeps_the_protocol(key):
    backend = BACKENDS[key]
    assert backend.name == key and isinstance(backend.name, str)
    for method in ("applies", "solve"):
        assert callable(getattr(backend, method))
        assert (list(inspect.signature(getattr(backend, method)).parameters)
                == list(inspect.signature(getattr(Backend, method)).parameters)[1:])  # without self


def test_every_solver_name_has_one_backend():
    """`SolverName` is the one list of the solvers: every name but `auto` (a choice among them) has
    exactly one backend, registered under it, and every backend's name is one of them."""
    assert all(isinstance(b.name, SolverName) and key is b.name for key, b in BACKENDS.items())
    names = [b.name for b in BACKENDS.values()]
    assert sorted(names) == sorted(n for n in SolverName if n is not SolverName.AUTO)
    assert BACKENDS["newton"] is BACKENDS[SolverName.NEWTON]  # the strategy's strings find them


def test_newton_and_ipopt_reach_the_same_plan(plans):
    newton, ipopt = plans["newton"].solution, plans["ipopt"].solution
    assert newton.success and ipopt.success, (newton.status, ipopt.status)
    assert newton.run.solver == "newton" and ipopt.run.solver == "ipopt"
    assert newton.trace_final == pytest.approx(ipopt.trace_final, rel=1e-6)
    np.testing.assert_allclose(np.asarray(newton.q), np.asarray(ipopt.q), atol=1e-5)


# the interior-point method: tests/test_interior.py
@pytest.mark.parametrize("key", ["newton", "ipopt"])
def test_each_plans_covariances_are_the_numpy_ekfs(small, plans, key):
    setup, _ = small
    sol = plans[key].solution
    sig, _ = ref.propagate(np.asarray(sol.poses), setup.ocp.noise,
                           setup.ocp.intrinsics, guard=COSINE_GUARD)
    assert np.abs(sol.covariances - sig).max() <= 1e-9 * np.abs(sig).max()
    assert sol.trace_final == pytest.approx(np.trace(sig[-1]), rel=1e-9)


def test_each_backend_offers_where_it_ended(plans):
    """IPOPT's end is a primal-dual point a warm solve starts from; Newton's its joints only."""
    newton, ipopt = plans["newton"].iterate, plans["ipopt"].iterate
    assert isinstance(newton, Iterate) and not newton.has_duals
    assert isinstance(ipopt, Iterate) and ipopt.has_duals
    np.testing.assert_array_equal(newton.q, np.asarray(plans["newton"].solution.joints))


def test_applies_says_why_newton_does_not_apply(small):
    setup, ctx = small
    assert BACKENDS["newton"].applies(ctx) is None and BACKENDS["ipopt"].applies(ctx) is None
    spec = setup.ocp.solver
    cases = {"a redundant arm (7 joints)": resolve(spec, setup.model, 7),
             "the exact Hessian": resolve(replace(spec, hessian="exact"), setup.model, 6)}
    for case, r in cases.items():
        why = BACKENDS["newton"].applies(replace(ctx, resolved=r))
        assert isinstance(why, str) and "six joints" in why, case
        assert BACKENDS["ipopt"].applies(replace(ctx, resolved=r)) is None, case


def test_a_solution_file_before_typed_attempt_records_loads(small, tmp_path):
    """A solution file whose attempts are dicts with the label under "hessian" (no "label", no
    "solver"): read into AttemptRecords with the backend and Hessian taken from the label."""
    setup, _ = small
    path = run_method(setup, "baseline").save(tmp_path / "new.json")
    tree = json.loads(path.read_text())
    tree["attempts"] = [
        {"hessian": "newton", "status": "Depth_Bound_Violated", "iterations": 12,
         "solve_time_s": 0.01, "objective": 0.5, "kept": False},
        {"hessian": "surrogate, monotone barrier", "status": "Maximum_Iterations_Exceeded",
         "iterations": 300, "solve_time_s": 0.2, "objective": 0.4, "kept": False, "compiled": True},
        {"hessian": "exact, warm start", "status": "Solve_Succeeded", "iterations": 7,
         "solve_time_s": 0.05, "objective": 0.3, "kept": True},
        {"hessian": "none (initial guess kept)", "status": "Initial_Guess_Kept", "iterations": 0,
         "solve_time_s": 0.0, "objective": 0.6, "kept": False},
    ]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(tree))
    sol = Solution.load(old)
    assert sol.attempts == [
        AttemptRecord("newton", "newton", None, "Depth_Bound_Violated", 12, 0.01, 0.5, False,
                      False),
        AttemptRecord("surrogate, monotone barrier", "ipopt", "surrogate",
                      "Maximum_Iterations_Exceeded", 300, 0.2, 0.4, False, True),
        AttemptRecord("exact, warm start", "ipopt", "exact", "Solve_Succeeded", 7, 0.05, 0.3, True,
                      False),
        AttemptRecord("none (initial guess kept)", "none", None, "Initial_Guess_Kept", 0, 0.0, 0.6,
                      False, False),
    ]
    assert "attempts" not in sol.extras
    # written again, it is the typed format, and reads back the same
    again = Solution.load(sol.save(tmp_path / "again.json"))
    assert again.attempts == sol.attempts
    assert all("label" in a and "solver" in a
               for a in json.loads((tmp_path / "again.json").read_text())["attempts"])
