"""SURESTEP belief-space trajectory optimisation: the Python API.

    import surestep_ocp as ss
    # or ss.problem_from_dict({...})
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml")
    # camera frame: [m], axis-angle [rad]
    problem = problem.with_goal(pose=[0.035, -0.010, 0.110, 0.6, 0.1, 1.4])
    sol = ss.solve(problem, method="ocp")                          # any method name of the CLI
    sol.joints, sol.positions, sol.covariances, sol.trace_final    # arrays with units (Solution)
    # a joint trajectory, as `surestep export`
    ss.export(sol, "ros2", "out/plan.yaml")
    planner = ss.Planner(problem)                                  # re-planning at tracker rate
    plan = planner.replan(mean, covariance)                        # from a tracker's estimate

Names are imported on first use, so `import surestep_ocp` stays light (the CLI starts fast); editors
and type checkers see them through the imports under `TYPE_CHECKING` (the package ships `py.typed`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

__version__ = "0.1.0"

_EXPORTS = {
    "load_problem": "problem.load", "problem_from_dict": "problem.load", "Problem": "problem.spec",
    "solve": "api", "export": "api", "Solution": "output.solution", "Planner": "methods.planner",
    "SimulatedTracker": "evaluation.tracker", "SurestepError": "errors", "ProblemError": "errors",
    "ProblemErrors": "errors", "METHODS": "methods.registry",
}
__all__ = ["METHODS", "Planner", "Problem", "ProblemError", "ProblemErrors", "SimulatedTracker",
           "Solution", "SurestepError", "export", "load_problem", "problem_from_dict", "solve"]

if TYPE_CHECKING:
    # what __getattr__ imports on first use, for editors and type checkers (never run)
    from .api import export, solve
    from .errors import ProblemError, ProblemErrors, SurestepError
    from .evaluation.tracker import SimulatedTracker
    from .output.solution import Solution
    from .problem.load import load_problem, problem_from_dict
    from .problem.spec import Problem
    from .methods.registry import BASE_METHODS as METHODS
    from .methods.planner import Planner


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'surestep_ocp' has no attribute '{name}'")
    from importlib import import_module

    module = import_module(f".{_EXPORTS[name]}", __name__)
    # imported once
    value = globals()[name] = getattr(module, "BASE_METHODS" if name == "METHODS" else name)
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
