"""The stored plans that pin the solvers' behaviour across refactors (issue 26's invariant).

Cases: every compare method on the default problem and the scenario files, the OCP on the first 100
evaluation configurations at T = 20 and 40 (the worst-case study's set, docs/findings.md), and a
short re-planning loop. Each case is solved through the public API (`ss.solve`, `ss.Planner`), so
the stored arrays do not depend on internal names.

    .venv/bin/python tests/stored_plans.py   # regenerate tests/data/stored_plans.npz (only on
                                              # purpose: it is the reference that
                                              # `tests/test_stored_plans.py` checks against)
    .venv/bin/python tests/stored_plans.py needle_regrasp/baseline   # these keys only
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STORE = ROOT / "tests" / "data" / "stored_plans.npz"
SCENARIOS = ("needle_regrasp", "needle_regrasp_paper_pace", "type1_easy", "type1_medium",
             "type1_hard", "type2_needle_arm_moves", "type3_camera_moves_once",
             "type4_camera_moves", "ur5_fixed_camera")
METHODS = ("baseline", "gradient", "gradient-no-pose-loss", "ocp", "ocp-from-gradient")
CONFIGS, HORIZONS, SEED = 100, (20, 40), 0
GROUP = 10  # configurations per test case (the cases spread over pytest-xdist's workers)
REPLANS = 6


def scenario_plans(name: str) -> dict[str, tuple[np.ndarray, str]]:
    """Every compare method's plan of one problem file: key -> (joints, status)."""
    import surestep_ocp as ss

    problem = ss.load_problem(ROOT / "problems" / f"{name}.yaml")
    return {f"{name}/{m}": (np.asarray(s.q, float), s.status)
            for m in METHODS for s in [ss.solve(problem, m)]}


def config_plans(T: int, first: int, count: int) -> dict[str, tuple[np.ndarray, str]]:
    """The OCP's plans of evaluation configurations `first .. first + count - 1` at horizon T."""
    import surestep_ocp as ss
    from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation

    sampler = ConfigurationSampler(load_evaluation(ROOT / "problems" / "evaluations"
                                                   / "evaluation.yaml"))
    out = {}
    for c in range(first, first + count):
        sol = ss.solve(sampler.problem(sampler.sample(SEED, c)).with_horizon(T), "ocp")
        out[f"config/T{T}/{c}"] = (np.asarray(sol.q, float), sol.status)
    return out


def replan_plans() -> dict[str, tuple[np.ndarray, str]]:
    """A planner on the paper-pace problem at T = 10 and its re-plans from a seeded simulated
    tracker."""
    import surestep_ocp as ss

    problem = ss.load_problem(ROOT / "problems" / "needle_regrasp_paper_pace.yaml").with_horizon(10)
    planner = ss.Planner(problem)
    out = {"replan/0": (np.asarray(planner.plan.q, float), planner.plan.status)}
    tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=7)
    for k in range(1, REPLANS + 1):
        mean, cov = tracker.move_to(planner.plan.poses[k - planner.step])
        plan = planner.replan(mean, cov, step=k)
        out[f"replan/{k}"] = (np.asarray(plan.q, float), plan.status)
    return out


def cases() -> list[tuple[str, tuple]]:
    """(case id, arguments of `plans`): the units the test checks one at a time."""
    out = [(f"scenario-{n}", ("scenario", n)) for n in SCENARIOS]
    out += [(f"configs-T{T}-{g}", ("configs", T, g, GROUP)) for T in HORIZONS
            for g in range(0, CONFIGS, GROUP)]
    return out + [("replan", ("replan",))]


def plans(kind: str, *args) -> dict[str, tuple[np.ndarray, str]]:
    if kind == "scenario":
        return scenario_plans(*args)
    if kind == "configs":
        return config_plans(*args)
    return replan_plans()


def case_keys(kind: str, *args) -> set[str]:
    """The keys of the plans a case makes (without solving them)."""
    if kind == "scenario":
        return {f"{args[0]}/{m}" for m in METHODS}
    if kind == "configs":
        T, first, count = args
        return {f"config/T{T}/{c}" for c in range(first, first + count)}
    return {f"replan/{k}" for k in range(REPLANS + 1)}


def machine() -> str:
    """What decides a plan's last bits on this machine: OpenBLAS's kernels (the core it picked) and
    the SIMD extensions NumPy dispatches its loops on (AVX-512 ones change rounding)."""
    import ctypes
    import glob

    from numpy._core._multiarray_umath import __cpu_features__ as features

    libs = sorted(glob.glob(str(Path(np.__file__).parent.parent / "numpy.libs" / "*openblas*")))
    core = "unknown"
    for lib in libs[:1]:
        fn = getattr(ctypes.CDLL(lib), "scipy_openblas_get_corename64_", None)
        if fn is not None:
            fn.restype = ctypes.c_char_p
            core = fn().decode()
    simd = ",".join(sorted(k for k, v in features.items() if v and k.startswith(("AVX", "FMA"))))
    return f"openblas {core}; numpy {np.__version__} {simd}"


def load() -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The stored joints and statuses, by plan key."""
    with np.load(STORE) as data:
        statuses = json.loads(str(data["statuses"]))
        return {k: data[k] for k in statuses}, statuses


def stored_machine() -> str | None:
    """`machine()` where the store was made (None: not recorded)."""
    with np.load(STORE) as data:
        return str(data["machine"]) if "machine" in data.files else None


def main(keys: list[str]) -> None:
    """Solve every case and store its plans; given `keys`, only the cases holding them, and only
    those keys (the others kept as stored)."""
    if keys and stored_machine() != machine():
        sys.exit(f"the store was made on another machine ({stored_machine()}; here: {machine()}): "
                 "store every plan here, not some")
    arrays, statuses = load() if keys else ({}, {})
    unknown = set(keys) - set(statuses)
    if unknown:
        sys.exit(f"not stored keys: {', '.join(sorted(unknown))}")
    for case, args in cases():
        if keys and not set(keys) & case_keys(*args):
            continue
        for key, (q, status) in plans(*args).items():
            if not keys or key in keys:
                arrays[key], statuses[key] = q, status
        print(case, flush=True)
    STORE.parent.mkdir(exist_ok=True)
    tmp = STORE.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, statuses=json.dumps(statuses), machine=machine(), **arrays)
    tmp.replace(STORE)
    print(f"{len(statuses)} plans -> {STORE}", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
