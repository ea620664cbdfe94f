"""The enforced-limits OCP solve of one revision against an older one, interleaved in one run.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/enforced_speed.py [--baseline-rev 21afa93]
        [--rev HEAD] [--configs 24] [--horizon 40] [--step-s 0.05] [--repeats 3]

Two worker processes, each importing `surestep_ocp` from `git archive` of its revision unpacked in a
temporary folder (`--rev`, default HEAD: uncommitted changes are not measured; `--baseline-rev`,
default 21afa93, the code before the enforced-solve changes), solve the same plans in turn (old,
new, old, new, ... for `--repeats` rounds per plan, so the load of a shared machine falls on both
alike): the default problem (problems/needle_regrasp.yaml) and the first `--configs` evaluation
configurations (problems/evaluations/evaluation.yaml, seed 0), each at `--horizon` steps of
`--step-s` with `limits.enforce: true`, by the `ocp` method (`run_method`, as
`surestep solve --method ocp`). Per plan and tree: status, Tr(Sigma_T), the solver's own time
(`solve_time_s`: every attempt, Newton's included; builds excluded; the median over the repeats),
IPOPT's iterations, the limit check of the plan (`Solution.motion_limits`) and the export's
(`time_parametrise`, timing auto: "planned" when the played curve at the planned times is within
every limit by the export's own dense check, else toppra). Writes
benchmarks/results/enforced_speed.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


# The worker imports `surestep_ocp` itself, not through benchmarks/harness.py: it runs the revision
# it measures, whose modules may be laid out otherwise than the harness expects. The parent process
# uses the harness (report).


def cases(horizon: int, step_s: float, configs: int):
    """(name, problem) of every plan, as both trees read them (the problem files of this tree)."""
    from dataclasses import replace

    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
    from surestep_ocp.problem.load import load_problem

    def enforced(p):
        return replace(p, horizon=horizon, limits=replace(p.limits, enforce=True),
                       timing=replace(p.timing, step_s=step_s))

    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations"
                                                   / "evaluation.yaml"))
    yield "default", enforced(load_problem(ROOT / "problems" / "needle_regrasp.yaml"))
    for i in range(configs):
        yield f"config {i}", enforced(sampler.problem(sampler.sample(0, i)))


def worker(horizon: int, step_s: float, configs: int) -> None:
    """Read a plan's index per line, solve it, write one JSON line (the tree is whichever
    `surestep_ocp` imports)."""
    import numpy as np

    import surestep_ocp
    from surestep_ocp.model import limits as lm
    from surestep_ocp.output.export import time_parametrise, within_position_limits
    from surestep_ocp.problem.setup import build_setup
    from surestep_ocp.solvers.methods import run_method

    plans = list(cases(horizon, step_s, configs))
    setups = {}
    print(json.dumps({"ready": str(Path(surestep_ocp.__file__).parent)}), flush=True)
    for line in sys.stdin:
        k = int(line)
        name, prob = plans[k]
        setup = setups.setdefault(k, build_setup(prob))
        sol = run_method(setup, "ocp")
        # before the typed report: a dict in the extras
        rep = getattr(sol, "motion_limits", None) or sol.extras.get("motion_limits", {})
        row = {"name": name, "status": sol.status, "ok": bool(sol.success),
               "trace": sol.trace_final, "solve_s": sol.solve_time_s,
               # before typed records
               "attempts": [(a.label, a.status, a.iterations) if hasattr(a, "label") else
                            (a["hessian"], a["status"], a["iterations"])
                            for a in getattr(sol, "attempts", None)
                            or sol.extras.get("attempts", [])],
               "within": bool(rep.ok if hasattr(rep, "ok") else rep.get("ok", False))}
        if sol.success:
            q, _ = within_position_limits(np.array(sol.q, float), setup.robot)
            traj = time_parametrise(q, prob.timing.step_s, lm.problem_limits(setup),
                                    robot=setup.robot, tool_frame=setup.robot.frame)
            row.update(timing=traj.timing, export_s=traj.duration)
        print(json.dumps(row), flush=True)


def start(tree: Path, args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--configs",
           str(args.configs), "--horizon", str(args.horizon), "--step-s", str(args.step_s)]
    proc = subprocess.Popen(cmd, cwd=tree, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    ready = json.loads(proc.stdout.readline())["ready"]
    if Path(ready).resolve() != (tree / "surestep_ocp").resolve():
        raise SystemExit(f"worker for {tree} imported surestep_ocp from {ready}")
    return proc


def ask(proc: subprocess.Popen, k: int) -> dict:
    proc.stdin.write(f"{k}\n")
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-rev", default="21afa93", help="the old revision (git archive)")
    ap.add_argument("--rev", default="HEAD",
                    help="the new revision (git archive; uncommitted changes are not in it)")
    ap.add_argument("--configs", type=int, default=24)
    ap.add_argument("--horizon", type=int, default=40)
    ap.add_argument("--step-s", type=float, default=0.05)
    ap.add_argument("--repeats", type=int, default=3, help="solves per plan and tree (median time)")
    ap.add_argument("--output", default=str(ROOT / "benchmarks" / "results" / "enforced_speed.md"))
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args.horizon, args.step_s, args.configs)
    import harness as h  # the parent only (see `cases`)

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="enforced_speed_") as tmp:
        trees, names = {}, {}
        for tree, rev in (("old", args.baseline_rev), ("new", args.rev)):
            trees[tree] = Path(tmp) / tree
            trees[tree].mkdir()
            archive = subprocess.run(["git", "archive", rev, "surestep_ocp", "robots",
                                      "pyproject.toml"], cwd=ROOT,
                                     check=True, capture_output=True).stdout
            (trees[tree] / "tree.tar").write_bytes(archive)
            with tarfile.open(trees[tree] / "tree.tar") as tar:
                tar.extractall(trees[tree], filter="data")
            names[tree] = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, check=True,
                                         capture_output=True, text=True).stdout.strip()
        procs = {tree: start(path, args) for tree, path in trees.items()}
        n = args.configs + 1
        # the first solve of each tree builds (and may compile) the NLP: not counted
        for proc in procs.values():
            ask(proc, 0)
        runs = {tree: [[] for _ in range(n)] for tree in procs}
        for k in range(n):
            for _ in range(args.repeats):
                for tree, proc in procs.items():
                    runs[tree][k].append(ask(proc, k))
            o, w = runs["old"][k][-1], runs["new"][k][-1]
            print(f"{o['name']:10s} old {o['status']:27s} "
                  f"{h.median(r['solve_s'] for r in runs['old'][k]):.3f} s | new {w['status']:27s} "
                  f"{h.median(r['solve_s'] for r in runs['new'][k]):.3f} s | Tr new/old "
                  f"{w['trace'] / o['trace']:.9f}", flush=True)
        for proc in procs.values():
            proc.stdin.close()
            proc.wait()
    lines = [(f"# The enforced OCP solve: {names['new']} against {names['old']} (T = "
              f"{args.horizon}, {args.step_s:g} s per step)"), "",
             ("`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/enforced_speed.py "
              f"--baseline-rev {args.baseline_rev} --rev {args.rev} --configs {args.configs} "
              f"--horizon {args.horizon} --step-s {args.step_s:g} --repeats {args.repeats}` "
              f"({time.perf_counter() - t0:.0f} s; {platform.node()}, 2 cores shared with other "
              "jobs: times are noisy, old and new interleaved). Time: the solver's own "
              f"(`solve_time_s`, Newton's included, builds excluded), median of {args.repeats} "
              "solves; iterations: IPOPT's in the attempt kept; export: `time_parametrise`'s "
              "timing (planned = the played curve within every limit at the planned times, by the "
              "export's own dense check)."), "",
             *h.table(["plan", "old: status", "Tr", "solve [s]", "IPOPT it.", "new: status", "Tr",
                       "solve [s]", "IPOPT it.", "export old / new", "Tr new / old",
                       "time new / old"])]
    ratios, t_old, t_new, tr_rel = [], [], [], []
    for k in range(n):
        o, w = runs["old"][k][-1], runs["new"][k][-1]
        so = h.median(r["solve_s"] for r in runs["old"][k])
        sn = h.median(r["solve_s"] for r in runs["new"][k])
        t_old.append(so)
        t_new.append(sn)
        ratios.append(sn / so)
        tr_rel.append(w["trace"] / o["trace"] - 1)
        it = lambda r: next((a[2] for a in reversed(r["attempts"]) if a[0] != "newton"), 0)
        lines.append(f"| {o['name']} | {o['status']} | {o['trace']:.6e} | {so:.3f} | {it(o)} | "
                     f"{w['status']} | {w['trace']:.6e} | {sn:.3f} | {it(w)} | "
                     f"{o.get('timing', '-')} / {w.get('timing', '-')} | "
                     f"{w['trace'] / o['trace']:.9f} | {sn / so:.2f} |")
    last = lambda tree: [runs[tree][k][-1] for k in range(n)]
    lines.append("")
    for tree, ts in (("old", t_old), ("new", t_new)):
        rs = last(tree)
        lines.append(f"- {tree}: {sum(r['ok'] for r in rs)}/{n} successes "
                     f"({', '.join(sorted({r['status'] for r in rs}))}); within the limits "
                     f"{sum(r['within'] for r in rs)}/{n}; exported at the planned pace "
                     f"{sum(r.get('timing') == 'planned' for r in rs)}/{n}; solve median "
                     f"{h.median(ts):.3f} s, worst {max(ts):.3f} s")
    lines.append(f"- time new / old per plan: median {h.median(ratios):.3f}, worst "
                 f"{max(ratios):.3f}, best {min(ratios):.3f}; median time old / new "
                 f"{h.median(t_old) / h.median(t_new):.2f}x")
    lines.append(f"- Tr(Sigma_T) new / old - 1: largest {max(tr_rel):+.2e}, smallest "
                 f"{min(tr_rel):+.2e}")
    h.write_result(Path(args.output), "\n".join(lines) + "\n")
    print("\n".join(lines[-4:]))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
