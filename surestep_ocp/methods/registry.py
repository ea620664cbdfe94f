"""Method names and dispatch: every method takes a Setup and returns a Solution.

Names (`method_grammar`): `baseline`, `gradient`, `gradient-no-pose-loss`, `ocp`,
`ocp-from-gradient` (the OCP started from the gradient solution), `ocp-mpc` (closed loop: as a plan,
its first one within the enforced limits), each optionally with an ablation
suffix `-no-depth`, `-no-fov` or `-no-orientation` (that observation component is left out during
optimisation; evaluation always uses all components), then `-expected`, then `-predicted`.
"""

from __future__ import annotations

from dataclasses import replace

from .baseline import solve_baseline
from ..ocp.certificate import judge
from .confidence import plan_to_confidence
from .gradient import solve_gradient
from ..model.belief import COMPONENTS
from ..errors import SurestepError
from ..model.limits import VIOLATED, enforce as enforce_limits
from ..method_grammar import BASE_METHODS, CLOSED_LOOP_METHODS, split_name
from .ocp import ocp_initial_guess, resolved_solver, solve_ocp
from .planner import Planner
from ..problem.setup import Setup
from ..problem.solver_config import SolverName
from ..output.solution import Solution
from ..solvers.backends import BACKENDS, Context
from ..solvers.strategy import replan_backend

COMPARE_METHODS = BASE_METHODS  # the open-loop plans


def parse_method(name: str) -> tuple[str, tuple[str, ...] | None, str | None, str | None]:
    """Split a method name into (base, components or None, observation-noise form or None, objective
    or None).

    A trailing `-predicted` minimises Tr(Sigma_T|T-1); before it, `-expected` plans with the
    belief-aware observation noise (section 8). The grammar is `method_grammar.split_name`'s.
    """
    try:
        base, ablated, expected, predicted = split_name(name)
    except ValueError as exc:
        raise SurestepError(str(exc)) from None
    comps = None if ablated is None else tuple(c for c in COMPONENTS if c != ablated)
    return base, comps, "expected" if expected else None, "predicted" if predicted else None


def _variant(setup: Setup, components: tuple[str, ...] | None, form: str | None,
             objective: str | None = None) -> Setup:
    """The same setup planning with other observation components, noise form or objective."""
    if components is None and form is None and objective is None:
        return setup
    noise = setup.ocp.noise
    noise = replace(noise, components=components or noise.components, observation_noise=form or
                    noise.observation_noise, objective=objective or noise.objective)
    return setup.with_ocp(noise=noise)


def method_setup(setup: Setup, name: str) -> Setup:
    """The setup the named method plans with (its observation components, noise form,
    objective)."""
    _, comps, form, objective = parse_method(name)
    return _variant(setup, comps, form, objective)


def closed_loop_plan(setup: Setup, solver_options: dict | None = None) -> Solution:
    """A closed-loop method's first plan: the `Planner`'s within the enforced limits (its rollouts
    re-plan from there, evaluation/closed_loop.py); an error naming what is missing otherwise."""
    if solver_options:
        raise SurestepError("ocp-mpc: IPOPT options do not apply (it re-plans with the "
                            "interior-point solver)")
    why = closed_loop_unavailable(setup)
    if why:
        raise SurestepError(why)
    return Planner(setup, prebuild=False).plan


CLOSED_LOOP_NEEDS = ("ocp-mpc re-plans within enforced motion limits with the interior-point "
                     "solver: it needs `limits: {enforce: true}` (and a horizon the limits allow, "
                     "e.g. 40 steps of 0.05 s) and `solver.name` auto or interior")


def closed_loop_unavailable(setup: Setup) -> str | None:
    """Why a closed-loop method cannot re-plan this setup (None: it can): the `Planner`'s
    conditions for re-planning within the limits, said."""
    resolved = resolved_solver(setup)
    movers = [b.name for b in BACKENDS.values() if b.handles.moving_start]
    if not setup.ocp.limits.enforce or resolved.name not in (SolverName.AUTO, *movers):
        return CLOSED_LOOP_NEEDS
    if replan_backend(Context(setup, resolved, "ocp-mpc", {})) is None:
        return ("ocp-mpc re-plans with the interior-point solver, which needs what newton "
                "needs: the condensed form of a model with constant motion and observation maps, "
                "noise.observation_noise: mean (not -expected), solver.hessian: auto and six "
                "joints moving the tracked frame")
    return None


def honours_limits(name: str) -> bool:
    """Whether the method plans within enforced motion limits: the OCP methods (their constraints)
    and the baseline (its time law, `baseline.py`). The gradient variants cannot; with
    `limits.enforce: true` they report their violations."""
    base = parse_method(name)[0]
    return base.startswith("ocp") or base == "baseline"


def counted_failures(sols: list[Solution]) -> tuple[list[str], list[str]]:
    """(failed, over the limits only): methods whose failure counts (any failure of a method that
    honours the limits, any other failure of one that cannot), and methods that cannot honour them
    reported over them (`Motion_Limits_Violated`), which `surestep compare` prints and does not
    count."""
    failed = [s.method for s in sols if not s.success
              and (honours_limits(s.method) or s.status != VIOLATED)]
    reported = [s.method for s in sols if not s.success and s.method not in failed]
    return failed, reported


def run_method(setup: Setup, name: str, cache: dict[str, Solution] | None = None,
               solver_options: dict | None = None) -> Solution:
    """Solve `setup` with the named method (see module docstring).

    `cache` (method name -> Solution) lets `ocp-from-gradient` reuse a gradient solution.
    """
    base, comps, _, _ = parse_method(name)
    s = method_setup(setup, name)
    grasp = s.ocp.grasp
    if grasp.confidence is not None and base not in ("baseline", "gradient",
                                                     "gradient-no-pose-loss"):
        # the horizon is the OCP's decision (methods/confidence.py): each one solved without it
        plain = replace(grasp, confidence=None)
        sol = plan_to_confidence(s, lambda sub: run_method(sub.with_ocp(grasp=plain), name, cache,
                                                           solver_options))
        return sol.replaced(method=name)
    if base == "baseline":
        sol = solve_baseline(s)
    elif base in ("gradient", "gradient-no-pose-loss"):
        sol = solve_gradient(s, pose_loss=(base == "gradient"), components=comps)
    elif base == "ocp":
        sol = solve_ocp(s, ocp_initial_guess(s), solver_options)
    elif base in CLOSED_LOOP_METHODS:
        sol = closed_loop_plan(s, solver_options)
    else:  # ocp-from-gradient
        suffix = name[len(base):]
        grad = ((cache or {}).get("gradient" + suffix)
                or run_method(setup, "gradient" + suffix, cache))
        sol = solve_ocp(s, ocp_initial_guess(s, "gradient", grad), solver_options)
    sol = sol.replaced(method=name)
    # one meaning of success: the certificate (docs/certificate.md); the Planner's own plan
    # (ocp-mpc) is certified, its success left to the Planner
    sol = judge(s, sol, gate=base not in CLOSED_LOOP_METHODS)
    # limits.enforce: true: a plan over a limit is not a success, whichever method made it
    return enforce_limits(s, sol)
