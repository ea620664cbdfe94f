"""Plans within the motion limits at tracker rate: the interior-point Newton method against IPOPT,
cold and in a 20 Hz re-planning loop.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py [--configs 100] [--seed 0]
        [--episodes 20] [--against main] [--repeats 1] [--no-full-replans] [--output realtime.md]

Cold: the default problem (problems/needle_regrasp.yaml: 40 steps of 50 ms, the limits enforced) and
the first `--configs` configurations of problems/evaluations/evaluation.yaml at the same horizon,
pace and limits, each solved by `solver.name: interior` (the interior-point method, IPOPT as its
fallback) and by IPOPT (`solver.name: ipopt`, the reference and today's default) in the same run;
the solve times (builds cached and not counted; the interior point's start search counted, as
IPOPT's set-up is), the interior attempt's own status, iterations and time, and Tr(Sigma_T) of
both. An infeasibility verdict ends `solver.name: interior`'s solve (no
IPOPT fallback); the separate IPOPT solve says whether it agrees. Where our Tr(Sigma_T) is above
IPOPT's, the row IPOPT's plan breaks most (the interior point's rows, negative: beyond a limit).
`--against REV`: the interior-point attempt alone of this checkout and of REV's
surestep_ocp/solvers/interior.py or interior/ (loaded beside it), alternated per problem
(`--repeats` timed solves each after a warm-up; the iterations and the rows' evaluations of
each), for load-independent ratios.
The 20 Hz loop: `--episodes` episodes of a `Planner` on the default problem (`solver.name:
interior`) against a simulated tracker (seeds 0, 1, ...), a re-plan at every waypoint from the
executed curve's state (after one untimed episode: first uses compile or load), by real-time
iterations (prepared between frames), then (unless
`--no-full-replans`) by full re-plans on the same episodes; per re-plan its time (builds apart;
the call and its preparation), its feedback time and whether it succeeded; per episode
the executed motion (every plan from its start until the next one's, sampled every millisecond)
checked against the limits by finite differences and Pinocchio's kinematics (violations: samples
beyond a limit by more than the differencing error). Writes benchmarks/results/realtime.md (or
`--output`); the last
line is `realtime: cold_median_ms=... cold_worst_ms=... replan_median_ms=... replan_worst_ms=...
infeasible=... violations=... ipopt_ratio=<IPOPT's cold median / ours> replan_feedback_ms=<median>
replan_certificate_ms=<median> replan_verdict_ms=<median>` (the feedback: from the estimate until
the plan's joints, then the re-plan's certificate, since an infeasible plan is not run; the
verdict: from the same start until the certificate's verdict by the clock, the plan's Solution
evaluated between the two included)
(the re-plan figures: real-time iterations).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import argparse  # noqa: E402
import os  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402


def cold_problems(args) -> list:
    """(name, problem): the default problem and the evaluation configurations at its horizon, pace
    and limits."""
    problems = [("default", h.load_problem(h.DEFAULT_PROBLEM))]
    base = problems[0][1]
    for c, p in h.configurations(h.sampler(), args.configs, args.seed, horizon=base.horizon):
        problems.append((str(c), replace(p, timing=base.timing, limits=base.limits)))
    return problems


def worst_row(setup, q) -> float:
    """The smallest of the interior point's rows at the plan q (scaled; negative: beyond)."""
    from surestep_ocp.ocp.iterate import InitialGuess
    from surestep_ocp.solvers.nlp_cache import interior_solver

    return interior_solver(setup).start_margin(setup, InitialGuess(np.asarray(q, float), "plan"))


def cold(args) -> tuple[list[str], dict]:
    """Every cold problem by both solvers: table lines and the figures."""
    problems = cold_problems(args)
    rows, ours, ref, worse, failed, disagree, alone, own_ok = [], [], [], [], [], [], [], 0
    for name, prob in problems:
        setup = h.setup(h.with_solver(prob, name="interior"))
        h.ocp(setup)  # builds (and compiles) outside the timed solves
        sol = h.ocp(setup)
        ipopt = h.ocp(h.with_solver(setup, name="ipopt"))
        own = sol.attempts[0]
        alone.append(own.solve_time_s * 1e3)
        own_ok += own.status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        ours.append(sol.solve_time_s * 1e3)
        ref.append(ipopt.solve_time_s * 1e3)
        rel = (sol.trace_final / ipopt.trace_final - 1 if ipopt.success and sol.success
               else float("nan"))
        if sol.success and ipopt.success and rel > 1e-6:
            worse.append((name, rel, worst_row(setup, ipopt.joints)))
        if not sol.success:
            failed.append((name, sol.status, ipopt.status))
            if ipopt.success:
                disagree.append(name)
        rows.append((name, sol.status, f"{ours[-1]:.1f}", own.status, own.iterations,
                     f"{alone[-1]:.1f}", ipopt.status, f"{ref[-1]:.1f}", f"{rel:.1e}"))
        print(name, sol.status, f"{ours[-1]:.1f} ms", ipopt.status, f"{ref[-1]:.1f} ms",
              f"rel {rel:.1e}", flush=True)
    so, sr, sa = h.stats(ours), h.stats(ref), h.stats(alone)
    worse_text = ", ".join(f"{n}: {r:.1e} (IPOPT's plan's lowest row {c:.1e})"
                           for n, r, c in worse)
    lines = ["## Cold, within the limits (T = 40, 50 ms steps)", "",
             (f"{len(problems)} problems: the default and {args.configs} evaluation "
              f"configurations (seed {args.seed})."),
             (f"solver.name: interior (IPOPT its fallback, not after an infeasibility verdict): "
              f"median {so.median:.1f} ms, "
              f"p90 {so.p90:.1f} ms, worst {so.worst:.1f} ms; IPOPT in the "
              f"same run: median {sr.median:.1f} ms, worst {sr.worst:.1f} ms "
              f"(IPOPT / ours, medians: {sr.median / so.median:.1f}x). "
              f"Not solved: {len(failed)} "
              f"({', '.join(f'{n}: {s} (IPOPT {i})' for n, s, i in failed) or 'none'}); "
              f"of those, solved by IPOPT: {len(disagree)}. "
              f"Tr(Sigma_T) more than 1e-6 above IPOPT's: {len(worse)} "
              f"({worse_text or 'none'}). "
              f"The interior-point attempt alone: "
              f"converged on {own_ok} of {len(problems)}, median {sa.median:.1f} ms, "
              f"worst {sa.worst:.1f} ms."), "",
             *h.table(["problem", "status", "ms (with fallback)", "interior attempt",
                       "its iterations", "its ms", "IPOPT status", "IPOPT ms",
                       "Tr / IPOPT's - 1"], rows), ""]
    return lines, {"cold_median_ms": so.median, "cold_worst_ms": so.worst,
                   "ipopt_ratio": sr.median / so.median,
                   "cold_failed": len(failed), "cold_disagree": len(disagree),
                   "cold_worse": len(worse)}


WARM_UP_SEED = 10_000  # the untimed episode before the loop's


def loop(args, rti: bool = True) -> tuple[list[str], dict]:
    """The 20 Hz loop's episodes (`rti`: real-time iterations, each prepared between frames;
    else full re-plans): table lines and the figures (nan with `--episodes 0`: the cold solves
    alone). A re-plan's time is the frame's work: the call, and its preparation when made before
    it; the feedback time is the real-time iteration's, from the call until the plan's joints and
    then its certificate (the gate before the command)."""
    kind = "real-time iterations" if rti else "full re-plans"
    if args.episodes <= 0:
        return ([f"## The 20 Hz loop within the limits: {kind}", "", "Not run (`--episodes 0`).",
                 ""],
                {"replan_median_ms": float("nan"), "replan_worst_ms": float("nan"),
                 "feedback_median_ms": float("nan"), "certificate_median_ms": float("nan"),
                 "verdict_median_ms": float("nan"), "infeasible": 0, "violations": 0})
    setup = h.setup(h.load_problem(h.DEFAULT_PROBLEM).with_solver(name="interior"))
    rows, times, feedback, certs, failed, bad, late, held, full = [], [], [], [], 0, 0, [], 0, 0
    verdicts = []
    # one episode untimed first: the certificate's and the re-plans' first uses compile or load
    # their functions (a node warms up likewise before its first frame)
    h.tracker_loop(setup, seed=WARM_UP_SEED, rti=rti)
    for seed in range(args.episodes):
        episode = h.tracker_loop(setup, seed=seed, rti=rti)  # what `surestep replan` runs
        planner, pieces = episode["planner"], episode["pieces"]
        dt = planner.setup.ocp.timing.step_s
        records = [p.replan for p in episode["plans"]]
        ep_times = [(r.time_s + (r.prepare_s if r.prepared_ahead else 0.0)) * 1e3
                    for r in records]
        ep_feedback = [(r.feedback_s + (r.certificate_s or 0.0)) * 1e3 for r in records
                       if r.feedback_s is not None]
        certs += [r.certificate_s * 1e3 for r in records if r.certificate_s is not None]
        verdicts += [r.verdict_s * 1e3 for r in records if r.verdict_s is not None]
        ep_full = sum(bool(r.rti and r.rti.startswith("full")) for r in records)
        ep_failed, ep_held = episode["summary"]["failed"], episode["summary"]["registration_held"]
        n_bad = h.violations(planner.setup, h.stitched(pieces, dt))
        s = h.stats(ep_times)
        late.append(planner.horizon - planner.setup.ocp.horizon)
        rows.append((seed, len(ep_times), ep_failed, ep_held, ep_full, f"{s.median:.1f}",
                     f"{s.worst:.1f}",
                     f"{np.median(ep_feedback):.2f}" if ep_feedback else "-", late[-1], n_bad))
        print(*rows[-1], flush=True)
        times += ep_times
        feedback += ep_feedback
        failed += ep_failed
        held += ep_held
        full += ep_full
        bad += n_bad
    s = h.stats(times)
    fb = h.stats(feedback) if feedback else None
    lines = [f"## The 20 Hz loop within the limits: {kind}", "",
             (f"{args.episodes} episodes of the default problem (`solver.name: interior`), "
              f"a re-plan at every waypoint from the executed curve's state: "
              f"{len(times)} re-plans, "
              f"median {s.median:.1f} ms, p90 {s.p90:.1f} ms, worst {s.worst:.1f} ms "
              f"(the call, and its preparation between frames)"
              + (f"; of the call, the re-plan's certificate median {np.median(certs):.2f} ms, "
                 f"worst {max(certs):.2f} ms" if certs else "")
              + (f"; the feedback (the call until the plan's joints, then its certificate) "
                 f"median {fb.median:.2f} ms, "
                 f"p90 {fb.p90:.2f} ms, worst {fb.worst:.2f} ms over the {len(feedback)} "
                 f"re-plans that were real-time iterations; {full} re-planned in full instead "
                 f"(a row broken by the moved goal, or the preparation failed)" if fb else "")
              + (f"; by the clock from the same start until the certificate's verdict (the plan's "
                 f"Solution evaluated between the two included) median {np.median(verdicts):.2f} "
                 f"ms, worst {max(verdicts):.2f} ms" if verdicts else "")
              + f"; not succeeded (the previous plan kept): {failed}; "
              f"the registration before held (the tracker's estimate put the goal out of reach): "
              f"{held}; "
              f"steps the goal moved later (median, worst): {int(np.median(late))}, {max(late)}; "
              f"executed samples beyond a limit: {bad}."), "",
             *h.table(["seed", "re-plans", "failed", "registration held", "in full",
                       "median ms", "worst ms", "feedback median ms", "steps later",
                       "violations"], rows),
             ""]
    return lines, {"replan_median_ms": s.median, "replan_worst_ms": s.worst,
                   "feedback_median_ms": fb.median if fb else float("nan"),
                   "certificate_median_ms": float(np.median(certs)) if certs else float("nan"),
                   "verdict_median_ms": (float(np.median(verdicts)) if verdicts
                                         else float("nan")),
                   "infeasible": failed, "violations": bad}


def load_interior(rev: str):
    """`rev`'s interior-point method as a module beside this checkout's
    (surestep_ocp.solvers.interior_against): its single file surestep_ocp/solvers/interior.py or
    its package surestep_ocp/solvers/interior/, whichever `rev` has."""
    import importlib.util
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    def git(*a):
        return subprocess.run(["git", *a], cwd=h.ROOT, check=True, capture_output=True,
                              text=True).stdout

    name, root = "surestep_ocp.solvers.interior_against", Path(tempfile.mkdtemp())
    files = git("ls-tree", "-r", "--name-only", rev, "--", "surestep_ocp/solvers/interior/").split()
    if files:  # a package: its modules in a directory of the module's name
        package = root / "interior_against"
        package.mkdir()
        for file in files:
            target = package / Path(file).relative_to("surestep_ocp/solvers/interior")
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(git("show", f"{rev}:{file}"))
        spec = importlib.util.spec_from_file_location(
            name, package / "__init__.py", submodule_search_locations=[str(package)])
    else:
        path = root / "interior_against.py"
        path.write_text(git("show", f"{rev}:surestep_ocp/solvers/interior.py"))
        spec = importlib.util.spec_from_file_location(name, path)
    # the modules an older revision imports from solvers/ that now live in ocp/ (issue 45's rooms)
    for moved in ("codegen", "iterate", "stages", "surrogate", "transcription", "lifted"):
        sys.modules.setdefault(f"surestep_ocp.solvers.{moved}",
                               importlib.import_module(f"surestep_ocp.ocp.{moved}"))
    other = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = other
    spec.loader.exec_module(other)
    # what this revision's backend calls and an older class lacks (issue 45's solver boundary)
    from surestep_ocp.solvers.interior import InteriorNewton
    if not hasattr(other.InteriorNewton, "solution"):
        other.InteriorNewton.solution = InteriorNewton.solution
    return other


def against(args) -> list[str]:
    """The interior-point attempt alone, this checkout's interior-point method against
    `args.against`'s (`load_interior`), alternated per problem: table lines."""
    import surestep_ocp.methods.ocp as ocp_module
    import surestep_ocp.solvers.backends.interior_point as backend
    from surestep_ocp.solvers import nlp_cache
    from surestep_ocp.solvers.strategy import Attempt, Start

    other = load_interior(args.against)
    built = {}

    def other_solver(setup, moving=False):
        ours = nlp_cache.interior_solver(setup, moving)
        if id(ours) not in built:
            built[id(ours)] = other.InteriorNewton(ours.newton, ours.robot, ours.dt, ours.limits,
                                                   ours.moving, codegen=True)
        return built[id(ours)]

    # each solve's evaluations of the rows (the start's and the line search's points)
    from surestep_ocp.solvers.interior import InteriorNewton

    evaluations = [0]
    # (each class's own attribute, None where it inherits `constraints` from a base class)
    originals = {cls: (cls.constraints, cls.__dict__.get("constraints"))
                 for cls in (InteriorNewton, other.InteriorNewton)}

    def counted(fn):
        def constraints(self, *a, **k):
            evaluations[0] += 1
            return fn(self, *a, **k)
        return constraints

    for cls, (fn, _) in originals.items():
        cls.constraints = counted(fn)
    strategy, solver = ocp_module.default_strategy, backend.interior_solver
    ocp_module.default_strategy = lambda *a, **k: (Attempt("interior point", "interior",
                                                           start=Start.GIVEN),)
    rows, mine, theirs, its_mine, its_theirs, ev_mine, ev_theirs = [], [], [], [], [], [], []
    same = 0  # problems whose plans are bit for bit the same
    try:
        for name, prob in cold_problems(args):
            setup = h.setup(h.with_solver(prob, name="interior"))
            res = {"this": [], "other": []}
            for k in range(2 * (args.repeats + 1)):
                variant = ("this", "other")[k % 2]
                backend.interior_solver = solver if variant == "this" else other_solver
                before = evaluations[0]
                sol = h.ocp(setup)
                a = sol.attempts[0]
                if k >= 2:  # after a warm-up of each
                    res[variant].append((a.solve_time_s * 1e3, a.iterations, a.status,
                                         evaluations[0] - before,
                                         np.asarray(sol.joints, float).tobytes()))
            t1, t0 = (float(np.median([r[0] for r in res[v]])) for v in ("this", "other"))
            mine.append(t1)
            theirs.append(t0)
            its_mine.append(res["this"][0][1])
            its_theirs.append(res["other"][0][1])
            ev_mine.append(res["this"][0][3])
            ev_theirs.append(res["other"][0][3])
            same += res["this"][0][4] == res["other"][0][4]
            rows.append((name, f"{t0:.1f}", res["other"][0][1], res["other"][0][3],
                         res["other"][0][2], f"{t1:.1f}", res["this"][0][1], res["this"][0][3],
                         res["this"][0][2], f"{t1 / t0:.2f}"))
            print("against", *rows[-1], flush=True)
    finally:
        ocp_module.default_strategy, backend.interior_solver = strategy, solver
        for cls, (_, own) in originals.items():
            if own is None:
                del cls.constraints
            else:
                cls.constraints = own
    a, b = h.stats(theirs), h.stats(mine)
    return [f"## The interior point against {args.against}'s", "",
            (f"`--against {args.against} --repeats {args.repeats}`: the interior-point attempt "
             f"alone (no fallback) of {args.against}'s surestep_ocp/solvers/interior and of "
             f"this checkout's, alternated per problem, the median of {args.repeats} timed "
             f"solve(s) each after a warm-up: median {a.median:.1f} ms against this "
             f"checkout's {b.median:.1f} ms (ratio of medians {b.median / a.median:.2f}; "
             f"median of the per-problem ratios "
             f"{float(np.median(np.array(mine) / np.array(theirs))):.2f}), worst {a.worst:.1f} "
             f"against {b.worst:.1f} ms, iterations median {np.median(its_theirs):.0f} against "
             f"{np.median(its_mine):.0f}, worst {max(its_theirs)} against {max(its_mine)}, "
             f"in all {sum(its_theirs)} against {sum(its_mine)}; the rows evaluated (the start's "
             f"and the line searches' points) {sum(ev_theirs)} against {sum(ev_mine)}; the plans "
             f"bit for bit the same in {same} of {len(rows)} problems."), "",
            *h.table(["problem", f"{args.against} ms", "its iterations", "its evaluations",
                      "its status", "this ms", "iterations", "evaluations", "status",
                      "this / theirs"], rows), ""]


def main() -> None:
    ap = h.parser(__doc__, configs=100, seed=0)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--against", default=None,
                    help="a git revision whose interior point to alternate with this checkout's")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--full-replans", action=argparse.BooleanOptionalAction, default=True,
                    help="also run the loop with full re-plans (Planner(rti=False)), for ratios")
    ap.add_argument("--output", default="realtime.md",
                    help="a file name under benchmarks/results/, or a path")
    args = ap.parse_args()
    load = [os.getloadavg()[0]]  # the machine's load: absolute times depend on it
    lines = ["# Plans within the motion limits at tracker rate", "",
             (f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/realtime.py "
              f"--configs {args.configs} --seed {args.seed} --episodes {args.episodes}"
              f"{f' --against {args.against} --repeats {args.repeats}' if args.against else ''}"
              f"{f' --output {args.output}' if args.output != 'realtime.md' else ''}` "
              f"(one BLAS thread; builds cached, not counted)."), ""]
    block, figs = cold(args)
    if args.against:
        block += against(args)
    load.append(os.getloadavg()[0])
    block2, lp = loop(args)
    block3, lf = loop(args, rti=False) if args.full_replans else ([], None)
    load.append(os.getloadavg()[0])
    lines += [(f"Load average (1 min) at the start, after the cold solves, at the end: "
               f"{', '.join(f'{x:.2f}' for x in load)} on {os.cpu_count()} cores (above about 1: "
               f"other work ran beside the benchmark, absolute times are inflated; "
               f"`--against` gives ratios measured alternately)."), "",
              (f"Ratios in this run: IPOPT's cold median / ours {figs['ipopt_ratio']:.1f}x"
               + (f"; full re-plans' median / real-time iterations' "
                  f"{lf['replan_median_ms'] / lp['replan_median_ms']:.2f}x, worst "
                  f"{lf['replan_worst_ms'] / lp['replan_worst_ms']:.2f}x" if lf else "") + "."),
              "", *block, *block2, *block3]
    last = h.last_line("realtime", h.key_values(
        cold_median_ms=f"{figs['cold_median_ms']:.1f}",
        cold_worst_ms=f"{figs['cold_worst_ms']:.1f}",
        replan_median_ms=f"{lp['replan_median_ms']:.1f}",
        replan_worst_ms=f"{lp['replan_worst_ms']:.1f}",
        infeasible=lp["infeasible"], violations=lp["violations"],
        ipopt_ratio=f"{figs['ipopt_ratio']:.1f}",
        replan_feedback_ms=f"{lp['feedback_median_ms']:.2f}",
        replan_certificate_ms=f"{lp['certificate_median_ms']:.2f}",
        replan_verdict_ms=f"{lp['verdict_median_ms']:.2f}"))
    text = "\n".join(lines + [last]) + "\n"
    h.write_result(args.output, text)
    print(text)


if __name__ == "__main__":
    main()
