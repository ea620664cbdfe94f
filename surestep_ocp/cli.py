"""Command line: `surestep solve|compare|replan|evaluate|sweep|validate|show|export|cache|check`.

User errors (bad problem files, unknown methods, unreachable poses) print one line
and exit 2; a solver that fails prints its status and exits 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .errors import SolverError, SurestepError
from .status import Status


def _load(path: str):
    """The problem file read, and its setup."""
    from .problem.load import load_problem
    from .problem.setup import build_setup

    prob = load_problem(path)
    return prob, build_setup(prob)


def _inputs(prob, problem_path: str) -> list:
    """The files a command reads (an output must not replace any of them)."""
    files = [problem_path, prob.robot.urdf]
    if prob.camera.ecm is not None:
        files.append(prob.camera.ecm.urdf)
    files += [spec.arm.urdf for spec in (prob.start.relative, prob.goal.relative)
              if spec is not None]
    return files


# Above this horizon a solve is announced on stderr with what it may cost (problems/README.md,
# "Limits").
LONG_HORIZON = 60


def _long_work_note(setup) -> None:
    T = setup.ocp.horizon
    if T > LONG_HORIZON:
        from .problem.parse import MAX_HORIZON

        print(f"note: horizon T = {T} (at most {MAX_HORIZON}): the first OCP solve at a new "
              f"horizon compiles its derivatives, up to about {20 + 0.55 * T:.0f} s (measured: "
              "46 s at T = 50, 130 s at T = 200; cached afterwards, problems/README.md "
              "'Limits'); Ctrl-C stops", file=sys.stderr, flush=True)


def _summary(sol, base=None) -> str:
    from .methods.baseline import LENGTHENED, duration_note

    err_m, err_rad = sol.terminal_error
    lines = [
        f"method      {sol.method}",
        f"status      {sol.status} ({'success' if sol.success else 'FAILED'})",
        f"iterations  {sol.iterations}",
        f"solve time  {sol.solve_time_s:.3f} s",
        f"Tr(Sigma_T) {sol.trace_final:.4e}"]
    if duration_note(sol):
        lines.append(f"duration    {duration_note(sol)}")
    if base is not None and base is not sol:
        ratio = (f"{base.trace_final / sol.trace_final:.2f}" if sol.trace_final > 0
                 else "undefined, Tr = 0")
        longer = ""
        if base.status == LENGTHENED:
            longer = (f"; the baseline lengthened to {base.extras['time_law']['duration_s']:.3f} s "
                      "to keep within the limits")
        lines.append(f"baseline    {base.trace_final:.4e}  "
                     f"(ratio baseline / {sol.method} = {ratio}{longer})")
    lines.append(f"terminal    {err_m:.2e} m, {err_rad:.2e} rad from the goal")
    lines += certificate_lines(sol)
    if "grasp" in sol.extras:
        lines.append(f"grasp       {grasp_line(sol.extras['grasp'])}")
    if sol.run.codegen_note:
        lines.append("note        solver.codegen auto: "
                     f"{sol.run.codegen_note.splitlines()[0]}")
    if sol.status == Status.INITIAL_GUESS_KEPT:
        lines.append("warning     every point the solvers converged to was worse than the initial "
                     "guess, which is returned (a poor local optimum; see docs/orientation.md)")
    if sol.run.worse_than_initial_guess:
        lines.append("warning     the optimum found is worse than the initial guess (a poor local "
                     "optimum; see docs/orientation.md)")
    unreachable = sum(q is None for q in sol.q)
    if unreachable:
        lines.append(f"reachable   {len(sol.q) - unreachable}/{len(sol.q)} waypoints (IK)")
    return "\n".join(lines)


def certificate_lines(sol) -> list[str]:
    """The plan's certificate (docs/certificate.md) and, where it differs, the backend's own
    status."""
    c = sol.certificate
    if c is None:
        return []
    lines = [f"certificate {c.level}: stationarity {c.stationarity:.1e}, complementarity "
             f"{c.complementarity:.1e} (tol {c.tolerances.stationarity:g}, acceptable "
             f"{c.tolerances.acceptable:g}), Tr(Sigma_T) by a NumPy EKF {c.trace:.4e}"]
    lines += [f"            not met: {line}" for line in c.failures()]
    if sol.backend_status is not None and sol.backend_status != sol.status:
        lines.append(f"backend     {sol.backend_status}")
    return lines


def grasp_line(rec: dict) -> str:
    """A plan's grasp record (methods/confidence.py) in one line."""
    tol = rec["tolerance"]
    text = (f"confidence {rec['predicted']:.4f} (within {tol['position'] * 1e3:g} mm and "
            f"{tol['angle']:g} rad) at {rec['duration_s']:.2f} s")
    if rec.get("confidence") is None:
        return text
    if rec["reached"]:
        return text + f"; asked {rec['confidence']:g}: reached"
    return text + (f"; asked {rec['confidence']:g}: not reached within timing.max_duration "
                   f"{rec['max_duration_s']:g} s (the best plan found)")


def _with_solver_flags(setup, args):
    """The setup with the command line's solver settings (--solver, --hessian, --codegen) over the
    file's."""
    from dataclasses import replace

    spec = setup.ocp.solver
    spec = replace(spec, name=args.solver or spec.name, hessian=args.hessian or spec.hessian,
                   codegen=spec.codegen if args.codegen is None else args.codegen)
    return setup.with_ocp(solver=spec)


def cmd_solve(args) -> int:
    from .methods.registry import run_method

    from .output.files import check_finite, check_output_file

    method = _with_init(args.method, args.init)
    _check_ocp_flags([method], args, "--method")
    prob, setup = _load(args.problem)
    setup = _with_solver_flags(setup, args)
    if args.output is not None:  # before the work: a bad path (or '') must not cost a solve
        check_output_file(args.output, _inputs(prob, args.problem), "the solution")
    _long_work_note(setup)
    sol = run_method(setup, method)
    base = run_method(setup, "baseline") if method != "baseline" else sol
    check_finite(sol.to_dict(), f"the {method} solution")
    summary = _summary(sol, base)
    if args.output:
        sol.save(args.output)
    print(summary)
    if args.output:
        print(f"wrote       {args.output}")
    if not sol.success:
        raise SolverError(sol.run.solver or sol.method, sol.status)
    return 0


def cmd_compare(args) -> int:
    from .comparison import run_comparison, write_comparison
    from .model.limits import LimitsReport, worst_violations
    from .methods.registry import COMPARE_METHODS, counted_failures

    from .output.files import check_finite, check_output_dir, check_output_file

    methods = tuple(args.methods) if args.methods else COMPARE_METHODS
    _check_ocp_flags(methods, args, "--methods")
    prob, setup = _load(args.problem)
    setup = _with_solver_flags(setup, args)
    inputs = _inputs(prob, args.problem)
    out = check_output_dir(args.output_dir, inputs, "the comparison")
    for name in [f"{m}.json" for m in methods] + ["comparison.json", "comparison.md", "trace.png",
                                                  "path.png", "motion.png"]:
        check_output_file(out / name, inputs, "the comparison")
    _long_work_note(setup)
    sols = run_comparison(setup, methods,
                          progress=lambda m: print(f"solving: {m}", file=sys.stderr, flush=True))
    for s in sols:
        check_finite(s.to_dict(), f"the {s.method} solution")
    table = write_comparison(sols, Path(args.output_dir), args.problem)
    print(table)
    print(f"\nwrote {args.output_dir}/{{<method>.json, comparison.md, comparison.json, trace.png, "
          f"path.png, motion.png}}")
    failed, reported = counted_failures(sols)  # the gradient plans cannot honour enforced limits
    for s in sols:
        if s.method in reported:
            rep = s.motion_limits  # a report: `enforce` made the status
            count = len(rep.violations) if isinstance(rep, LimitsReport) else 0
            print(f"over the limits: {s.method} ({count} violations: "
                  f"{worst_violations(rep)}; it does not plan within limits, reported only)",
                  file=sys.stderr)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def cmd_replan(args) -> int:
    from .methods.camera_move_replan import replan_after_camera_moves

    from .output.files import check_output_dir

    prob, setup = _load(args.problem)
    setup = _with_solver_flags(setup, args)
    check_output_dir(args.output_dir, _inputs(prob, args.problem), "the re-planning")
    _long_work_note(setup)
    # a fixed camera: the tracker loop
    if not any(c is not None for c in setup.camera_changes() or ()):
        from .evaluation.tracker_loop import tracker_loop, write_tracker_loop

        res = tracker_loop(setup, seed=args.seed, progress=lambda k, p: print(
            f"step {k}: {p.status}, {p.replan.time_s * 1e3:.1f} ms", file=sys.stderr,
            flush=True))
        print(write_tracker_loop(res, Path(args.output_dir)))
        print(f"wrote {args.output_dir}/loop.md, loop.json")
        return 0
    res = replan_after_camera_moves(setup, Path(args.output_dir), progress=lambda k: print(
        f"re-planning after the camera move at step {k}", file=sys.stderr, flush=True))
    print(res["table"])
    built = ", ".join(f"T={n}" for n in sorted(res["builds"]))
    print(f"\nbuild time  {res['build_time_s']:.2f} s ({len(res['builds'])} solvers: "
          f"{built or 'none timed apart'})")
    print(f"solve time  {res['solve_time_s']:.3f} s (the first plan and {len(res['plans'])} "
          "re-plans, without builds)")
    print(f"\nwrote {args.output_dir}/{{baseline, ocp-once, ocp-replanned, "
          f"ocp-replan-<step>}}.json, replan.md, replan.json")
    return 0


def cmd_validate(args) -> int:
    bad = 0
    for path in args.problems:
        try:
            _, setup = _load(path)
            print(f"ok    {path}  (T={setup.ocp.horizon}, goal depth {setup.x_goal[2]:.3f} m)")
        except SurestepError as exc:  # every error of the file, one line each
            from .errors import error_lines

            for line in error_lines(exc):
                print(f"error {line}", file=sys.stderr)
            bad += 1
    return 2 if bad else 0


def cmd_show(args) -> int:
    try:
        from .viz import show
    except ImportError as exc:
        raise SurestepError(f"the visualisation needs meshcat: {exc}") from None
    target = Path(args.target)
    for flag, value in (("--html", args.html), ("--screenshot", args.screenshot)):
        if value is not None and not str(value).strip():
            raise SurestepError(f"{flag}: an empty file name; give the file to write")
    if not target.exists():
        raise SurestepError(f"{target}: no such file or directory")
    solutions = None
    if target.suffix in (".yaml", ".yml"):
        from .methods.registry import run_method

        _, setup = _load(str(target))
        solutions = [run_method(setup, "baseline").to_dict()]
    return show(target, open_browser=args.open, html=Path(args.html) if args.html else None,
                endoscope_view=args.endoscope_view, solutions=solutions,
                screenshot=Path(args.screenshot) if args.screenshot else None) or 0


OCP_FLAGS = ("solver", "hessian", "codegen")  # act on the OCP only (method_grammar.OCP_METHODS)


def _solver_flags(parser: argparse.ArgumentParser) -> None:
    """--solver, --hessian, --codegen: the OCP's settings over the problem file's `solver:`
    section."""
    from .problem.solver_config import SolverName
    from .problem.spec import SolverSpec

    d = SolverSpec()
    parser.add_argument("--solver", choices=[name.value for name in SolverName],
                        help=f"OCP solver (default: the problem file's solver.name, else {d.name}: "
                             "projected Newton in the joints where it applies, IPOPT as its "
                             "fallback; docs/solve_speed.md); OCP methods only")
    parser.add_argument("--hessian", choices=("auto", "exact", "surrogate", "gauss-newton"),
                        help="OCP Hessian (default: the problem file's solver.hessian, else "
                             f"{d.hessian}); OCP methods only")
    parser.add_argument("--codegen", action=argparse.BooleanOptionalAction, default=None,
                        help="compile the OCP's stage-wise derivatives to C, or not (default: the "
                             f"problem file's solver.codegen, else {d.codegen}: when a C compiler "
                             "is found; cached, see docs/hessian_and_newton.md); OCP methods only")


def _method_name(name: str) -> str:
    """argparse type of a method name: unknown names are a usage error listing the grammar."""
    from .method_grammar import split_name

    try:
        split_name(name)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return name


def _with_init(method: str, init: str | None) -> str:
    """The method `--init` asks for: `--init gradient` turns ocp (or a variant) into
    ocp-from-gradient."""
    from .method_grammar import split_name

    if init is None:
        return method
    if split_name(method)[0] != "ocp":
        raise SurestepError("--init applies to --method ocp and its variants only, not to "
                            f"'{method}' (ocp-from-gradient already starts from the "
                            "gradient solution)")
    return "ocp-from-gradient" + method[len("ocp"):] if init == "gradient" else method


def _check_ocp_flags(methods, args, flag: str) -> None:
    """An OCP flag (--solver, --hessian, --codegen) with no OCP method to act on is an error."""
    from .method_grammar import OCP_METHODS, split_name

    given = [f"--{n}" for n in OCP_FLAGS if getattr(args, n, None) is not None]
    if given and not any(split_name(m)[0] in OCP_METHODS for m in methods):
        raise SurestepError(f"{', '.join(given)} applies to the OCP methods only "
                            f"({', '.join(OCP_METHODS)} and their variants); {flag} "
                            f"{' '.join(methods)} has none")


def _version() -> str:
    """The installed distribution's version (the package's own when run from a bare checkout)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("surestep_ocp")
    except PackageNotFoundError:
        from . import __version__

        return __version__


class _OneLineParser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (exit 2), like every other user error."""

    def error(self, message: str):
        from .errors import one_line

        self.exit(2, f"{self.prog}: error: {one_line(message, 500)} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The `surestep` command line: this module's commands, then those registered by theirs."""
    p = _OneLineParser(prog="surestep",
                       description="Uncertainty-aware trajectory optimisation (SURESTEP).")
    p.add_argument("--version", action="version", version=f"surestep {_version()}")
    sub = p.add_subparsers(dest="command", required=True)
    _add_solve_and_compare(sub)
    _add_replan(sub)
    _add_validate_and_show(sub)
    _register_commands(sub)
    return p


def _add_solve_and_compare(sub) -> None:
    """`surestep solve` and `surestep compare`."""
    from .method_grammar import BASE_METHODS, grammar

    s = sub.add_parser("solve", help="solve one problem with one method, write the solution JSON")
    s.add_argument("problem", help="problem YAML (problems/README.md)")
    s.add_argument("--method", default="ocp", type=_method_name, help=f"{grammar()} (default ocp)")
    s.add_argument("--init", choices=("baseline", "gradient"),
                   help="initial guess of --method ocp (or a variant): the straight line (the "
                        "default) or the gradient solution (= --method ocp-from-gradient); an "
                        "error with any other method")
    _solver_flags(s)
    s.add_argument("--output", "-o",
                   help="solution JSON to write (default: none, the summary only)")
    s.set_defaults(func=cmd_solve)

    c = sub.add_parser("compare", help="run every method on one problem and compare them")
    c.add_argument("problem", help="problem YAML (problems/README.md)")
    c.add_argument("--output-dir", required=True,
                   help="folder for <method>.json, the tables and the plots")
    c.add_argument("--methods", nargs="+", type=_method_name, metavar="METHOD",
                   help=f"methods to run (default: {' '.join(BASE_METHODS)}); each {grammar()}")
    _solver_flags(c)
    c.set_defaults(func=cmd_compare)


def _add_replan(sub) -> None:
    """`surestep replan`."""
    r = sub.add_parser("replan", help="plan, then re-plan after every camera move (problems with "
                                      "camera.moves), else at every frame of a simulated "
                                      "20 Hz tracker")
    r.add_argument("problem", help="problem YAML (problems/README.md): with camera.moves (e.g. "
                                   "problems/type4_camera_moves.yaml) a re-plan after each move; "
                                   "without, a re-plan at every waypoint against a simulated "
                                   "tracker, within the limits from the moving robot's state when "
                                   "they are enforced")
    r.add_argument("--seed", type=int, default=0,
                   help="the simulated tracker's noise seed (problems whose camera does not move)")
    r.add_argument("--output-dir", required=True,
                   help="folder for baseline.json, ocp-once.json (planned once), "
                        "ocp-replanned.json (the motion as re-planned), ocp-replan-<step>.json "
                        "(each re-plan), replan.md and replan.json (the table)")
    _solver_flags(r)
    r.set_defaults(func=cmd_replan)


def _add_validate_and_show(sub) -> None:
    """`surestep validate` and `surestep show`."""
    v = sub.add_parser("validate", help="check problem files")
    v.add_argument("problems", nargs="+", metavar="PROBLEM", help="problem YAML files to check")
    v.set_defaults(func=cmd_validate)

    w = sub.add_parser("show",
                       help="Meshcat view of a problem, a solution or a comparison directory")
    w.add_argument("target",
                   help="a solution JSON, a folder of them (surestep compare's output) or a "
                        "problem YAML (its baseline is solved and shown)")
    w.add_argument("--open", action="store_true", help="open a browser")
    w.add_argument("--html",
                   help="write a self-contained static HTML file (with a legend) instead of "
                        "serving (default: serve live Meshcat on loopback until Ctrl-C)")
    w.add_argument("--screenshot", metavar="PNG",
                   help="render the static HTML with headless Chromium and write it as a PNG")
    w.add_argument("--endoscope-view", action="store_true", help="look through the endoscope")
    w.set_defaults(func=cmd_show)


def _register_commands(sub) -> None:
    """The commands registered by their own modules (evaluate, export, sweep, cache, ros, check)."""
    from .evaluation.evaluation import register as register_evaluate
    from .output.export import register as register_export

    register_evaluate(sub)
    register_export(sub)
    from .evaluation.sweep import register as register_sweep

    register_sweep(sub)
    from .cache_cli import register as register_cache
    from .check_cli import register as register_check

    register_cache(sub)
    from .ros.commands import register as register_ros  # serve, sim-robot (DDS loaded on use)

    register_ros(sub)
    register_check(sub)


def main(argv: list[str] | None = None) -> int:
    """Run a command; user errors are one line and exit 2, solver failures exit 1, Ctrl-C exits 130,
    a closed output pipe (`| head -1`) ends quietly (141, as killed by SIGPIPE)."""
    import os

    from .errors import one_line

    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except SolverError as exc:
        print(f"surestep: {exc}", file=sys.stderr)
        return 1
    except SurestepError as exc:
        from .errors import error_lines

        for line in error_lines(exc):  # a problem file's every error, one line each
            print(f"surestep: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _say("surestep: interrupted")
        return 130
    except BrokenPipeError:
        try:  # nothing more reaches the reader; keep the interpreter's final flush quiet as well
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return 141
    except MemoryError:
        _say("surestep: out of memory (a smaller horizon, fewer configurations or rollouts "
             "need less)")
        return 2
    except OSError as exc:  # the file system refused a read or write the checks could not foresee
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        _say(f"surestep: {one_line(where)}{one_line(exc.strerror or exc)}")
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug: one line unless asked for the traceback
        if os.environ.get("SURESTEP_TRACEBACK"):
            raise
        import traceback

        last = traceback.extract_tb(exc.__traceback__)[-1]
        _say(f"surestep: internal error: {type(exc).__name__}: {one_line(exc, 300)} (at "
             f"{Path(last.filename).name}:{last.lineno}; SURESTEP_TRACEBACK=1 shows the traceback)")
        return 1


def _say(text: str) -> None:
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


if __name__ == "__main__":
    sys.exit(main())
