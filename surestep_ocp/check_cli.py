"""`surestep check SOLUTION.json`: is a solution file's plan a certified optimum of its problem?

The certificate is recomputed from the problem file the solution names when that file still
describes the plan (same horizon and start; not a re-plan), else the recorded certificate's
measures are judged again. Either way the file's own trace and terminal pose are checked too.
Exit 0 certified, 1 not (one line per failing criterion), 2 a file that is not a solution.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import SurestepError, shown
from .methods.registry import method_setup
from .ocp.certificate import certify, claims_optimum
from .output.certificate import FEASIBLE
from .output.export_load import load_solution
from .output.solution import Solution
from .problem.load import load_problem
from .problem.setup import build_setup


def _solution(path: str):
    d = load_solution(path)  # a missing, huge or malformed file: one line, exit 2
    try:
        return Solution.from_dict(d)
    except KeyError as exc:
        raise SurestepError(f"{path}: not a solution file (missing key {shown(exc.args[0], 60)}; "
                            "written by `surestep solve --output` or `surestep compare`)") from None
    except (TypeError, ValueError, AttributeError) as exc:
        raise SurestepError(f"{path}: not a solution file ({shown(str(exc), 200)})") from None


def _recomputed(sol):
    """(certificate, where from) recomputed from the problem file, or (None, why not)."""
    if sol.replan is not None:
        return None, "a re-plan (its start and Sigma_0 are not the problem file's)"
    path = Path(str(sol.problem))
    if not path.is_file():
        return None, f"its problem file {shown(str(path), 120)} is not found"
    try:
        setup = method_setup(build_setup(load_problem(path)), sol.method)
    except SurestepError as exc:
        return None, f"its problem file does not load ({shown(str(exc), 120)})"
    if setup.ocp.horizon != sol.horizon or not np.allclose(sol.q[0], setup.q_start, atol=1e-9):
        return None, f"{shown(str(path), 120)} now describes another start or horizon"
    return certify(setup, sol), f"recomputed from {shown(str(path), 120)}"


def check_lines(path: str) -> tuple[bool, list[str]]:
    """(certified, the lines to print) for the solution file `path`."""
    sol = _solution(path)
    cert, source = _recomputed(sol)
    if cert is None and sol.certificate is None:
        return False, [f"{path}: no certificate: none recorded (a file written before "
                       f"certificates) and none recomputed: {source}"]
    if cert is None:
        cert, source = sol.certificate.judged(), f"the recorded certificate ({source})"
    fails = cert.failures()
    tol = cert.tolerances.feasibility
    err_m, err_rad = sol.terminal_error
    if max(err_m, err_rad) > tol:
        fails.append(f"terminal pose (the file's poses): {err_m:.3g} m, {err_rad:.3g} rad from "
                     f"the goal, allowed {tol:.3g}")
    recorded = float(np.trace(np.asarray(sol.sigma_final, float)))
    if abs(recorded - sol.trace_final) > cert.tolerances.trace * max(abs(recorded), 1e-300):
        fails.append(f"trace (the file's): Tr(sigma_final) {recorded:.6g} but trace[-1] "
                     f"{sol.trace_final:.6g}")
    if sol.success and fails and claims_optimum(sol.method):
        fails.append("success: the file says true; the certificate does not confirm it")
    if cert.level == FEASIBLE and not fails:
        fails.append("optimality: a feasible plan, not a certified optimum")
    if fails:
        return False, [f"{path}: not certified ({cert.level}; {source}):"] + [
            f"  {line}" for line in fails]
    return True, [f"{path}: certified {cert.level} ({source}): stationarity "
                  f"{cert.stationarity:.2g}, complementarity {cert.complementarity:.2g}, terminal "
                  f"{cert.terminal_position_m:.2g} m, Tr(Sigma_T) {cert.trace:.6g}"]


def cmd_check(args) -> int:
    ok, lines = check_lines(args.solution)
    print("\n".join(lines))
    return 0 if ok else 1


def register(sub) -> None:
    c = sub.add_parser("check", help="check a solution file's optimality certificate (exit 0 "
                                     "certified, 1 not, 2 not a solution file)")
    c.add_argument("solution", help="a solution JSON file (surestep solve --output)")
    c.set_defaults(func=cmd_check)
