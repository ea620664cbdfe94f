"""The optimality certificate (ocp/certificate.py) against an independent check, per backend and
belief-model family; how often a backend's own success was not certified; what it costs.

For N evaluation configurations (problems/evaluations/evaluation.yaml, T = 20; the `limits` family
at T = 40 with the default limits enforced at 0.05 s per step) and each family (paper, full V_d0,
correlated V_d0, joint-space motion noise, the paper's model lifted, limits) and backend
(`solver.name` newton, interior, ipopt; the gradient variant): the plan's certificate, and the same
certificate with the objective's gradient taken by central differences of a NumPy EKF (step 1e-6)
instead of CasADi's reverse mode: agreement is the same verdict (certified or not). A backend that
does not apply to a family (newton within enforced limits, ...) is `n/a`.

The cost: the certificate's time (`Certificate.time_s`, the per-structure builds and compiles
excluded) over the plan's cold solve time. `--against REV` also loads REV's
surestep_ocp/ocp/certificate.py (`git show`, beside this one in the package) and certifies
every plan with both, interleaved (which one first alternates per configuration), so the cost
before and after is measured on the same plans in the same process; their verdicts are compared.

`--polish`: the independent check of issue 46's item 3 by IPOPT instead: from each plan's joints,
IPOPT on the condensed NLP (exact Hessian, the problem's options, bound push 1e-8 so that it starts
at the plan, barrier 1e-6); the plan passes when IPOPT ends successfully having lowered the
objective (1 at the start, by the independent NumPy EKF) by at most the problem's `solver.tol`
(no better point near it); agreement is the certificate's verdict (certified or not) being that
pass. How far IPOPT moved the joints is reported beside it, not judged: within enforced limits an
acceptable-level plan (rows within the acceptable 1e-6 of their bound) is moved by millimetres to
IPOPT's strict feasibility, its objective rising.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/certificate.py [--instances 100]
        [--families ...] [--backends ...] [--against REV] [--polish]

Writes benchmarks/results/certificate.md; the last line is
`certificate: instances=N disagreements=... uncertified_successes=... cost_median=...
cost_worst=...` (and `against=REV against_cost_median=... against_cost_worst=...
interleaved_cost_median=... interleaved_cost_worst=... verdicts_differ=...`).
"""

from __future__ import annotations

import harness as h  # first: one BLAS thread

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402

from general_models import JOINT_SIGMA, correlated_depth, full_depth  # noqa: E402

FAMILIES = {
    "paper": {},
    "full": {"noise": {"V_d0": full_depth()}},
    "correlated": {"noise": {"V_d0": correlated_depth()}},
    "joint-space": {"noise": {"joint_sigma": JOINT_SIGMA}},
    "lifted": {"covariance": "full"},
    "limits": {"limits": True},
}
BACKENDS = ("newton", "interior", "ipopt", "gradient")
FD_STEP = 1e-6
# the polish: IPOPT starts at the plan (bound push 1e-8) with a small barrier; a plan passes when it
# ends with the objective lowered by at most solver.tol
POLISH_OPTIONS = {"ipopt.bound_push": 1e-8, "ipopt.bound_frac": 1e-8, "ipopt.mu_init": 1e-6,
                  "ipopt.print_level": 0}


def family_problem(problem, family: str, backend: str):
    """The configuration's problem in `family`, solved by `backend`."""
    spec = FAMILIES[family]
    p = replace(problem, noise=replace(problem.noise, **spec.get("noise", {})))
    solver = replace(p.solver, covariance=spec.get("covariance", p.solver.covariance),
                     name=backend if backend != "gradient" else p.solver.name)
    p = replace(p, solver=solver)
    if spec.get("limits"):
        p = replace(p, horizon=40, limits=h.limits_spec(True), timing=h.timing_spec(0.05))
    return p


def certificate_at(rev: str):
    """REV's certificate module (surestep_ocp/ocp/certificate.py at REV), loaded beside this
    revision's in the same package (its relative imports resolve to this checkout's modules)."""
    path = "surestep_ocp/ocp/certificate.py"
    source = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=h.ROOT, capture_output=True,
                            text=True, check=True).stdout
    package = h.certify.__module__.rpartition(".")[0]
    name = f"{package}._certificate_at_{rev.replace('^', '_').replace('~', '_')}"
    spec = importlib.util.spec_from_loader(name, loader=None, origin=f"{rev}:{path}")
    module = importlib.util.module_from_spec(spec)
    module.__package__ = package
    sys.modules[name] = module
    exec(compile(source, f"{rev}:{path}", "exec"), module.__dict__)
    return module


def polish(ms, sol, cert) -> dict:
    """IPOPT polishing from the plan's joints (module docstring): its status, the objective's
    decrease (trace by the NumPy EKF over the plan's trace_ref, plus the smoothness term), the
    largest joint move, and whether the plan passes."""
    setup = h.with_solver(ms, name="ipopt")
    # (the harness exposes no transcription builder; the solver cache's is the solvers' own)
    tr = h._nlp_cache.transcription(setup, form="condensed", extra_options=POLISH_OPTIONS)
    q = np.asarray(sol.q, float)
    out, _ = tr.solve(setup, h.guess(q, "the plan"), method="polish")
    qp = np.asarray(out.q, float)
    ref = sol.run.initial_trace or cert.trace
    after = h.certify(ms, out)

    def f(trace, qq):
        return trace / ref + ms.ocp.smoothness * float(np.sum(np.diff(qq, axis=0) ** 2))

    drop = f(cert.trace, q) - f(after.trace, qp) if after is not None else float("nan")
    move = float(np.max(np.abs(qp - q)))
    ok = bool(out.success) and drop <= float(ms.ocp.solver.tol)
    return {"status": out.status, "drop": drop, "move": move, "ok": ok,
            "level_after": after.level if after is not None else "none"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instances", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", nargs="*", choices=list(FAMILIES), default=list(FAMILIES))
    ap.add_argument("--backends", nargs="*", choices=BACKENDS, default=list(BACKENDS))
    ap.add_argument("--against", metavar="REV",
                    help="also time REV's certificate on the same plans, interleaved")
    ap.add_argument("--polish", action="store_true",
                    help="also check every plan by IPOPT polishing from it (module docstring)")
    ap.add_argument("--output", default=str(h.RESULTS / "certificate.md"))
    args = ap.parse_args()
    sampler = h.sampler()
    before = certificate_at(args.against) if args.against else None
    res = {(f, b): {"n": 0, "claimed": 0, "certified": 0, "false": 0, "agree": 0, "na": None,
                    "cost": [], "t_cert": [], "t_solve": [], "levels": {}, "status": {},
                    "t_now": [], "t_before": [], "cost_now": [], "cost_before": [], "same": 0,
                    "polished": 0, "polish_agree": 0, "drop_cert": [], "drop_not": [],
                    "move_cert": [], "move_not": [], "polish_status": {}}
           for f in args.families for b in args.backends}
    for c, base in h.configurations(sampler, args.instances, args.seed):
        line = [f"{c:3d}"]
        for f in args.families:
            for b in args.backends:
                r = res[f, b]
                if r["na"]:
                    continue
                name = "gradient" if b == "gradient" else "ocp"
                try:
                    setup = h.setup(family_problem(base, f, b))
                    sol = h.method(setup, name)
                except h.SurestepError as exc:
                    r["na"] = str(exc)[:120]
                    continue
                cert = sol.certificate
                ms = h.method_setup(setup, name)
                fd = h.certify(ms, sol, fd_step=FD_STEP)
                if before is not None and cert is not None:
                    # both on the same plan, which one first alternating per configuration
                    order = (before.certify, h.certify)[::1 if c % 2 else -1]
                    got = {fn: fn(ms, sol) for fn in order}
                    old, now = got[before.certify], got[h.certify]
                    r["t_before"].append(old.time_s)
                    r["t_now"].append(now.time_s)
                    r["cost_before"].append(old.time_s / sol.solve_time_s)
                    r["cost_now"].append(now.time_s / sol.solve_time_s)
                    r["same"] += old.level == now.level
                if args.polish and cert is not None:
                    pol = polish(ms, sol, cert)
                    r["polished"] += 1
                    r["polish_agree"] += pol["ok"] == cert.certified
                    side = "cert" if cert.certified else "not"
                    r[f"drop_{side}"].append(pol["drop"])
                    r[f"move_{side}"].append(pol["move"])
                    r["polish_status"][pol["status"]] = r["polish_status"].get(pol["status"], 0) + 1
                    if pol["ok"] != cert.certified:
                        print(f"  polish disagrees: {f}/{b} config {c}: certificate {cert.level} "
                              f"(stationarity {cert.stationarity:.2e}), polish {pol}", flush=True)
                r["n"] += 1
                r["claimed"] += bool(sol.backend_success)
                ok = cert is not None and cert.certified
                r["certified"] += ok
                r["false"] += bool(sol.backend_success) and not ok
                r["agree"] += ok == (fd is not None and fd.certified)
                level = "none" if cert is None else cert.level
                r["levels"][level] = r["levels"].get(level, 0) + 1
                key = sol.backend_status if not ok and sol.backend_success else None
                if key:
                    r["status"][key] = r["status"].get(key, 0) + 1
                if cert is not None and sol.solve_time_s > 0:
                    r["cost"].append(cert.time_s / sol.solve_time_s)
                    r["t_cert"].append(cert.time_s)
                    r["t_solve"].append(sol.solve_time_s)
                line.append(f"{f}/{b}: {sol.backend_status} -> {level}")
        print(" | ".join(line), flush=True)
    header = ["family", "backend", "plans", "backend success", "certified", "success not certified",
              "their backend status", "agrees with FD", "levels", "certificate ms (median)",
              "solve ms (median)", "cost / solve (median)"]
    rows = []
    for (f, b), r in res.items():
        if r["na"] and not r["n"]:
            rows.append(h.row(f, b, "n/a", r["na"], "", "", "", "", "", "", "", ""))
            continue
        rows.append(h.row(
            f, b, r["n"], r["claimed"], r["certified"], r["false"],
            ", ".join(f"{k} {v}" for k, v in sorted(r["status"].items())) or "-",
            f"{r['agree']}/{r['n']}",
            ", ".join(f"{k} {v}" for k, v in sorted(r["levels"].items())),
            f"{h.median(r['t_cert']) * 1e3:.2f}" if r["t_cert"] else "-",
            f"{h.median(r['t_solve']) * 1e3:.1f}" if r["t_solve"] else "-",
            f"{h.median(r['cost']) * 100:.1f} %" if r["cost"] else "-"))
    ocp = [x for (f, b), r in res.items() if b != "gradient" for x in r["cost"]]
    n_all = sum(r["n"] for r in res.values())
    disagree = sum(r["n"] - r["agree"] for r in res.values())
    false = sum(r["false"] for (f, b), r in res.items() if b != "gradient")
    summary = [f"Certificate cost over a cold OCP solve (as run, in `run_method`): median "
               f"{h.median(ocp) * 100:.1f} %, p90 {h.percentile(ocp, 90) * 100:.1f} %, worst "
               f"{max(ocp) * 100:.1f} % ({len(ocp)} OCP plans; a structure's first certificate in "
               "the process is interpreted, the later ones compiled)."]
    keys = dict(instances=args.instances, plans=n_all, disagreements=disagree,
                uncertified_successes=false, cost_median=round(h.median(ocp), 4),
                cost_worst=round(max(ocp), 4))
    against = []
    if before is not None:
        now = [x for (f, b), r in res.items() if b != "gradient" for x in r["cost_now"]]
        old = [x for (f, b), r in res.items() if b != "gradient" for x in r["cost_before"]]
        timed = sum(len(r["t_now"]) for r in res.values())
        same = sum(r["same"] for r in res.values())
        against = [
            "", f"## Against {args.against}, interleaved on the same plans", "",
            f"Each plan certified again by {args.against}'s `certify` and by this revision's, "
            "which one first alternating per configuration (both after their builds).", "",
            *h.table(["family", "backend", "plans", f"{args.against} ms (median)",
                      "this ms (median)", "speed-up (median of ratios)",
                      f"{args.against} cost / solve (median, worst)",
                      "this cost / solve (median, worst)", "same level"],
                     [(f, b, len(r["t_now"]), f"{h.median(r['t_before']) * 1e3:.2f}",
                       f"{h.median(r['t_now']) * 1e3:.3f}",
                       f"{h.median_ratio(r['t_before'], r['t_now']):.1f}x",
                       f"{h.median(r['cost_before']) * 100:.1f} %, "
                       f"{max(r['cost_before']) * 100:.1f} %",
                       f"{h.median(r['cost_now']) * 100:.2f} %, {max(r['cost_now']) * 100:.2f} %",
                       f"{r['same']}/{len(r['t_now'])}")
                      for (f, b), r in res.items() if r["t_now"]]), "",
            f"Over the {len(now)} OCP plans: {args.against} median {h.median(old) * 100:.1f} %, "
            f"worst {max(old) * 100:.1f} %; this revision median {h.median(now) * 100:.2f} %, "
            f"worst {max(now) * 100:.2f} % of a cold solve. Same level on {same}/{timed} plans."]
        keys.update(against=args.against, against_cost_median=round(h.median(old), 4),
                    against_cost_worst=round(max(old), 4),
                    interleaved_cost_median=round(h.median(now), 4),
                    interleaved_cost_worst=round(max(now), 4), verdicts_differ=timed - same)
    polished = []
    if args.polish:
        def span(xs, fmt):
            return f"{fmt(h.median(xs))} / {fmt(max(xs))}" if xs else "-"

        def e(x):
            return f"{x:.1e}"

        done = sum(r["polished"] for r in res.values())
        agree = sum(r["polish_agree"] for r in res.values())
        polished = [
            "", "## IPOPT polishing from each plan", "",
            "From each plan's joints IPOPT on the condensed NLP (exact Hessian, the problem's "
            "options, bound push 1e-8, barrier 1e-6); a plan passes when IPOPT ends successfully "
            "having lowered the objective (1 at the start, by the NumPy EKF) by at most "
            "solver.tol. `agrees`: the certificate's verdict (certified or not) is the pass. "
            "Objective drop (negative: it rose) and largest joint move [rad, m]: median / "
            "largest.", "",
            *h.table(["family", "backend", "plans", "agrees", "IPOPT's status",
                      "drop, certified", "move, certified", "drop, not certified",
                      "move, not certified"],
                     [(f, b, r["polished"], f"{r['polish_agree']}/{r['polished']}",
                       ", ".join(f"{k} {v}" for k, v in sorted(r["polish_status"].items())),
                       span(r["drop_cert"], e), span(r["move_cert"], e),
                       span(r["drop_not"], e), span(r["move_not"], e))
                      for (f, b), r in res.items() if r["polished"]]), "",
            f"The certificate agrees with the polish on {agree}/{done} plans."]
        keys.update(polished=done, polish_disagreements=done - agree)
    text = "\n".join([
        "# The optimality certificate against finite differences; uncertified successes",
        "",
        f"`OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/certificate.py --instances "
        f"{args.instances}{' --against ' + args.against if args.against else ''}"
        f"{' --polish' if args.polish else ''}` (seed "
        f"{args.seed}; T = 20, limits T = 40 at 0.05 s per step). "
        "`backend success`: the backend's own claim (`sol.backend_success`, the old `success`); "
        "`success not certified`: of those, the certificate is neither optimal nor acceptable (the "
        "gradient variant claims a completed run, not an optimum: its column is informational); "
        "`agrees with FD`: the same verdict with the objective's gradient by central differences "
        "of a NumPy EKF. Cost: the certificate's time over the plan's solve time (builds "
        "excluded).",
        "",
        *h.table(header, rows),
        "",
        *summary,
        *against,
        *polished,
    ])
    h.write_result(args.output, text + "\n")
    print(text)
    print(f"certificate_cost: median={h.median(ocp) * 100:.2f}% worst={max(ocp) * 100:.2f}% of a "
          f"cold OCP solve (p90 {h.percentile(ocp, 90) * 100:.2f}%)")
    print(h.last_line("certificate", h.key_values(**keys)))


if __name__ == "__main__":
    main()
