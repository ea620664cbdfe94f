"""The Python API's entry points beside `Problem`, `Solution` and `Planner`: load or build, solve.

    import surestep_ocp as ss
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_goal(pose=[0.04, 0.0, 0.11, 0.6, 0.1, 1.4])
    sol = ss.solve(problem, method="ocp")
    sol.joints, sol.positions, sol.covariances   # (T+1, nq) [rad, m], (T+1, 3) [m], (T+1, 6, 6) [m^2, rad^2]
"""

from __future__ import annotations

from .problem.spec import Problem
from .output.solution import Solution


def solve(problem: Problem, method: str = "ocp") -> Solution:
    """Plan `problem` with a method: `baseline`, `gradient`, `gradient-no-pose-loss`, `ocp`, `ocp-from-gradient`
    (optionally `-no-depth`, `-no-fov`, `-no-orientation`, then `-expected`, then `-predicted`; README, "Quick start").

    The OCP's solver settings are the problem's (`problem.with_solver(name="ipopt")`). Check `sol.success`:
    a solver failure returns a Solution with its `status`. Raises ProblemError (naming the key) when the
    problem cannot be set up (an unreachable goal, joints outside their limits).
    """
    from .solvers.methods import run_method
    from .problem.setup import build_setup

    return run_method(build_setup(problem), method)
