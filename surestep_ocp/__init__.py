"""SURESTEP belief-space trajectory optimisation: the Python API.

    import surestep_ocp as ss
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml")  # or ss.problem_from_dict({...})
    problem = problem.with_goal(pose=[0.045, 0.005, 0.115, 0.6, 0.1, 1.4])   # [m], axis-angle [rad]
    sol = ss.solve(problem, method="ocp")                          # any method name of the CLI
    sol.joints, sol.positions, sol.covariances, sol.trace_final    # arrays with units (Solution)
    planner = ss.Planner(problem)                                  # re-planning at tracker rate
    plan = planner.replan(mean, covariance)                        # from a tracker's estimate

Names are imported on first use, so `import surestep_ocp` stays light (the CLI starts fast).
"""

__version__ = "0.1.0"

_EXPORTS = {
    "load_problem": "problem.load", "problem_from_dict": "problem.load", "Problem": "problem.spec",
    "solve": "api", "Solution": "output.solution", "Planner": "solvers.planner", "SimulatedTracker": "evaluation.tracker",
    "SurestepError": "errors", "ProblemError": "errors", "METHODS": "solvers.methods",
}
__all__ = ["METHODS", "Planner", "Problem", "ProblemError", "SimulatedTracker", "Solution", "SurestepError",
           "load_problem", "problem_from_dict", "solve"]


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'surestep_ocp' has no attribute '{name}'")
    from importlib import import_module

    module = import_module(f".{_EXPORTS[name]}", __name__)
    return getattr(module, "BASE_METHODS" if name == "METHODS" else name)
