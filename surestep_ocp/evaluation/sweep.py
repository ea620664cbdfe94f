"""`surestep sweep SWEEP.yaml`: one evaluation file expanded into several `surestep evaluate` runs.

A sweep file names an evaluation file and the settings shared by its runs, then the
runs, each a name plus overrides:

    evaluation: evaluations/evaluation.yaml   # relative to the sweep file (or a shipped name)
    configs: 100
    rollouts: 50
    seed: 0
    rollout_mode: model                       # model | true | both
    methods: [baseline, gradient, gradient-no-pose-loss]
    runs:
      - name: paper
        gradient: {preset: paper}             # any evaluation-file key: gradient, detection,
                                              # grasp, accept, ...
        methods: [baseline, gradient]         # per-run methods / configs / rollouts / rollout_mode
      - name: noisy-camera
        noise: {V_f0: 4.0e-2}                 # merged into the base problem's noise section
    grid:                                     # optional: the cartesian product of these lists,
      detection.falloff: [0.0, 0.1]           #   added as runs named key=value,...; a dotted key
                                              #   reaches into a section

Each run gets its own folder `OUT/<name>/` holding the derived `evaluation.yaml` (and
`base.yaml` when `noise` is overridden) and the usual outputs of `surestep evaluate`
(resume, progress, `--jobs` or `--scheduler` as there); `OUT/sweep.md` sums the runs up
(the mean ratio to the baseline of the final position error and of Tr ML, and the
grasp success share, per method and mode).

A sweep has at most 1,000 runs (its `runs` plus the grid's product, checked before the grid is
expanded); a run's name is a folder name (no '/', '\\', control characters, leading '.'; at most
200 characters); `evaluation:` must name an evaluation file (one with a `base:`). Every file the
sweep writes is checked before any run starts: none may be one of its inputs (the sweep file, the
evaluation file, its base problem) or a symbolic link; each is written whole (a temporary file
renamed over it). The output folder is locked for the sweep (`run_lock.py`), each run's folder for
its run.
"""

from __future__ import annotations

import copy
import itertools
import json
import math
from pathlib import Path
from typing import Any

import yaml

from ..errors import SurestepError, shown
from ..output.files import check_output_dir, check_output_file
from ..output.solution import write_text_atomic
from ..problem.load import read_yaml
from ..problem.paths import find_shipped
from ..problem.schema import Reader
from .configs import load_evaluation
from .evaluation import Terminated, _sigterm_raises, read_progress, run_evaluation, say_terminated
from .evaluation_report import relative_stats, success_share
from .run_lock import hold

_TOP = {"evaluation", "configs", "rollouts", "seed", "rollout_mode", "methods", "runs", "grid",
        "description"}
_RUN_SETTINGS = {"name", "methods", "configs", "rollouts", "rollout_mode", "noise"}
_MODES = {"model": ("model",), "true": ("true",), "both": ("model", "true")}
# runs of one sweep (its `runs` plus the grid's product), checked before the grid is expanded
MAX_RUNS = 1000
MAX_NAME = 200  # characters of a run's name (a folder name)


def _set_dotted(tree: dict, key: str, value: Any) -> None:
    parts = key.split(".")
    node = tree
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise SurestepError(f"grid key '{key}': '{p}' is not a section")
    node[parts[-1]] = value


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def load_sweep(path: str | Path) -> dict:
    """Read a sweep file strictly and expand it: {'evaluation': Path, 'runs': [run dicts]}."""
    path = Path(path)
    tree = read_yaml(path)
    rd = Reader(str(path))
    top = rd.mapping(tree, "", _TOP, {"evaluation"})
    ev_text = rd.string(top["evaluation"], "evaluation")
    ev = path.parent / ev_text
    if not ev.is_file():
        ev = find_shipped(ev_text)
        if not ev.is_file():
            raise rd.fail("evaluation", f"file '{ev_text}' not found (relative to {path.parent})")
    ev_tree = read_yaml(ev)
    if not isinstance(ev_tree, dict) or not isinstance(ev_tree.get("base"), str):
        raise rd.fail("evaluation",
                      f"'{ev_text}' is not an evaluation file (it has no 'base:' naming its "
                      "problem file; a problem file is named by an evaluation file's 'base')")
    shared = {
        "configs": rd.integer(top.get("configs", 100), "configs", minimum=1),
        "rollouts": rd.integer(top.get("rollouts", 50), "rollouts", minimum=2),
        "seed": rd.integer(top.get("seed", 0), "seed", minimum=0),
        "rollout_mode": rd.string(top.get("rollout_mode", "both"), "rollout_mode", tuple(_MODES)),
        "methods": _methods(rd, top.get("methods", ["baseline", "gradient", "ocp"]), "methods"),
    }
    raw_runs = list(top.get("runs", []) or [])
    if not isinstance(raw_runs, list):
        raise rd.fail("runs", "expected a list of runs")
    grid = top.get("grid") or {}
    if not isinstance(grid, dict):
        raise rd.fail("grid", "expected a mapping of keys to lists of values")
    if len(raw_runs) > MAX_RUNS:
        raise rd.fail("runs", f"{len(raw_runs)} runs: at most {MAX_RUNS} in one sweep")
    if grid:
        keys = list(grid)
        for k in keys:
            if not isinstance(k, str) or not k:
                raise rd.fail("grid", f"key {shown(repr(k), 60)}: expected a (dotted) key name")
            if not isinstance(grid[k], list) or not grid[k]:
                raise rd.fail(f"grid.{k}", "expected a non-empty list of values")
        points = math.prod(len(grid[k]) for k in keys)
        if points + len(raw_runs) > MAX_RUNS:
            raise rd.fail("grid",
                          f"{points} grid "
                          f"points{f' and {len(raw_runs)} runs' if raw_runs else ''}: at most "
                          f"{MAX_RUNS} runs in one sweep")
        for combo in itertools.product(*(grid[k] for k in keys)):
            run: dict = {"name": ",".join(f"{k}={v}" for k, v in zip(keys, combo))}
            for k, v in zip(keys, combo):
                _set_dotted(run, k, v)
            raw_runs.append(run)
    if not raw_runs:
        raise rd.fail("runs", "a sweep needs at least one run (runs or grid)")
    runs, names = [], set()
    for i, r in enumerate(raw_runs):
        key = f"runs[{i}]"
        if not isinstance(r, dict) or "name" not in r:
            raise rd.fail(key, "each run is a mapping with a name")
        name = rd.string(r["name"], f"{key}.name")
        if any(ord(c) < 32 or ord(c) == 127 for c in name) or "\\" in name or len(name) > MAX_NAME:
            raise rd.fail(f"{key}.name",
                          f"{shown(repr(name), 80)}: a run's name is a folder name: printable, "
                          f"without control characters or '\\', at most {MAX_NAME} characters")
        if not name or "/" in name or name in names or name.startswith("."):
            raise rd.fail(f"{key}.name", f"'{name}': names must be unique, non-empty, without '/'")
        names.add(name)
        run = {**shared, "name": name, "overrides": {k: v for k, v in r.items()
                                                     if k not in _RUN_SETTINGS}}
        for k in ("configs", "rollouts"):
            if k in r:
                run[k] = rd.integer(r[k], f"{key}.{k}", minimum=1 if k == "configs" else 2)
        if "rollout_mode" in r:
            run["rollout_mode"] = rd.string(r["rollout_mode"], f"{key}.rollout_mode", tuple(_MODES))
        if "methods" in r:
            run["methods"] = _methods(rd, r["methods"], f"{key}.methods")
        if "noise" in r and not isinstance(r["noise"], dict):
            raise rd.fail(f"{key}.noise",
                          "expected a mapping (keys of the base problem's noise section)")
        run["noise"] = r.get("noise")
        runs.append(run)
    return {"path": path, "evaluation": ev, "runs": runs}


def _methods(rd: Reader, node: Any, key: str) -> tuple[str, ...]:
    if isinstance(node, str):
        node = [m for m in node.replace(",", " ").split() if m]
    if not isinstance(node, list) or not node or not all(isinstance(m, str) for m in node):
        raise rd.fail(key, "expected a list of method names")
    return tuple(node)


def write_run_files(sweep: dict, run: dict, out: Path) -> Path:
    """The run's evaluation file (and derived base problem) in `out`; returns the evaluation file's
    path."""
    ev_path = Path(sweep["evaluation"]).resolve()
    tree = read_yaml(ev_path)
    base = (ev_path.parent / tree["base"]).resolve()
    if not base.is_file():
        spec = load_evaluation(ev_path)  # resolves shipped names; raises a clear error otherwise
        base = Path(spec.base_path).resolve()
    tree["base"] = str(base)
    tree = _merge(tree, run["overrides"])
    inputs = sweep_inputs(sweep)
    for name in run_files(run):  # never onto an input, nor through a symbolic link
        check_output_file(out / name, inputs, f"the run '{run['name']}'")
    if run["noise"]:
        btree = read_yaml(base)
        if not isinstance(btree.get("noise", {}), dict):
            raise SurestepError(f"{base}: its 'noise' is not a section; the run '{run['name']}' "
                                "cannot override it")
        btree["noise"] = _merge(btree.get("noise", {}), run["noise"])
        _absolutise(btree, base.parent)
        write_text_atomic(out / "base.yaml", yaml.safe_dump(btree, sort_keys=False))
        tree["base"] = str((out / "base.yaml").resolve())
    path = out / "evaluation.yaml"
    write_text_atomic(path, yaml.safe_dump(tree, sort_keys=False))
    return path


def run_files(run: dict) -> tuple[str, ...]:
    """The files a sweep writes into a run's folder before its evaluation."""
    return ("evaluation.yaml", "base.yaml") if run["noise"] else ("evaluation.yaml",)


def sweep_inputs(sweep: dict) -> list[Path]:
    """The files a sweep reads: the sweep file, its evaluation file and that file's base problem."""
    ev = Path(sweep["evaluation"]).resolve()
    inputs = [Path(sweep["path"]), ev]
    tree = read_yaml(ev)
    if isinstance(tree, dict) and isinstance(tree.get("base"), str):
        inputs.append(ev.parent / tree["base"])
    return inputs


def _absolutise(tree: Any, folder: Path) -> None:
    """Make the `urdf` paths of a copied problem tree absolute where they resolve from its old
    folder."""
    if isinstance(tree, dict):
        for k, v in tree.items():
            if k == "urdf" and isinstance(v, str) and not Path(v).is_absolute():
                for cand in (folder / v, folder.parent / v):
                    if cand.is_file():
                        tree[k] = str(cand.resolve())
                        break
            else:
                _absolutise(v, folder)
    elif isinstance(tree, list):
        for v in tree:
            _absolutise(v, folder)


def run_sweep(sweep_path: str | Path, out_dir: str | Path, jobs: int = 1, scheduler=None,
              resume: bool = False, progress: bool = True, only: tuple[str, ...] = ()) -> str:
    """Run every run of a sweep (or those named in `only`); returns the summary table (Markdown)."""
    with _sigterm_raises():  # between runs too: SIGTERM raises Terminated, files whole or absent
        try:
            return _run_sweep(sweep_path, out_dir, jobs, scheduler, resume, progress, only)
        except Terminated as exc:
            if not exc.args:
                raise Terminated(f"the files in {out_dir} are whole or absent; continue with the "
                                 "same command plus --resume") from None
            raise


def _run_sweep(sweep_path, out_dir, jobs, scheduler, resume, progress, only) -> str:
    sweep = load_sweep(sweep_path)
    out = Path(out_dir)
    runs = [r for r in sweep["runs"] if not only or r["name"] in only]
    if only and len(runs) != len(set(only)):
        missing = sorted(set(only) - {r["name"] for r in sweep["runs"]})
        raise SurestepError(f"{sweep_path}: no run named {', '.join(missing)}")
    inputs = sweep_inputs(sweep)
    out = check_output_dir(out, inputs, "the sweep")
    with hold(out, "a sweep"):
        # every file the sweep writes, checked before any run starts: none is an input or a symbolic
        # link
        check_output_file(out / "sweep.md", inputs, "the sweep's summary")
        for run in runs:
            d = out / run["name"]
            check_output_dir(d, inputs, f"the run '{run['name']}'")
            for name in run_files(run):
                check_output_file(d / name, inputs, f"the run '{run['name']}'")
        for run in runs:
            d = out / run["name"]
            ev = write_run_files(sweep, run, d)
            run_evaluation(ev, d, run["configs"], run["rollouts"], run["seed"], run["methods"],
                           _MODES[run["rollout_mode"]], jobs, resume,
                           progress=progress, scheduler=scheduler)
        table = summary(out, sweep["runs"])
        write_text_atomic(out / "sweep.md", table + "\n")
        return table


def summary(out: Path, runs: list[dict]) -> str:
    """One line per run, method and mode from each run's progress.jsonl."""
    lines = [("| run | mode | method | pos mean | pos med | Tr ML mean | Tr ML med | grasp "
              "| configs |"),
             "|---|---|---|---|---|---|---|---|---|"]
    for run in runs:
        d = out / run["name"]
        if not (d / "progress.jsonl").is_file():
            continue
        recs = list(read_progress(d / "progress.jsonl").values())
        if not recs:
            continue
        header = json.loads((d / "run.json").read_text())
        methods, modes = header["methods"], header["modes"]
        st = relative_stats(recs, methods, modes)
        for mode in modes:
            for m in methods:
                s = st[mode][m]
                succ = success_share(recs, mode, m)[0]
                lines.append(f"| {run['name']} | {mode} | {m} | {s['pos_err_mean']['mean']:.3f} | "
                             f"{s['pos_err_mean']['median']:.3f} | {s['trace_ml']['mean']:.3f} | "
                             f"{s['trace_ml']['median']:.3f} | {succ:.1%} | {len(recs)} |")
    return "\n".join(lines)


def cmd_sweep(args) -> int:
    try:
        table = run_sweep(args.sweep, args.output_dir, args.jobs, args.scheduler, args.resume,
                          not args.quiet, tuple(args.only or ()))
    except Terminated as exc:
        return say_terminated(exc)
    print(table)
    print(f"\nwrote {args.output_dir}/{{<run>/..., sweep.md}}")
    return 0


def register(subparsers):
    """Add the `sweep` subcommand."""
    s = subparsers.add_parser("sweep",
                              help="expand a sweep file into several evaluations and run them",
                              description="Run every run of SWEEP.yaml as a `surestep evaluate` in "
                                          "OUT/<run>/ and write OUT/sweep.md.")
    s.add_argument("sweep", metavar="SWEEP.yaml",
                   help="a sweep file: an evaluation file and its runs' overrides "
                   "(e.g. problems/evaluations/table1_readings.yaml)")
    s.add_argument("--output-dir", required=True,
                   help="folder for each run's evaluation (<run>/) and sweep.md")
    s.add_argument("--jobs", type=int, default=1, help="worker processes per run (default 1)")
    s.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on an existing Dask cluster (see evaluate)")
    s.add_argument("--resume", action="store_true",
                   help="continue runs already started in OUTPUT_DIR")
    s.add_argument("--only", nargs="+", metavar="RUN", help="run only these runs (by name)")
    s.add_argument("--quiet", action="store_true", help="no progress bars")
    s.set_defaults(func=cmd_sweep)
    return s
