"""`surestep evaluate`: the paper's Table I protocol over random configurations.

For each configuration (see `configs.py`) every method plans once; every plan is
then executed by N noisy closed-loop rollouts per rollout mode (`rollout.py`),
all evaluated with every observation component. Per finished configuration one
JSON line goes to `DIR/progress.jsonl` (so an interrupted run keeps its work and
`--resume` continues it); at the end `table.md`, `raw.csv`, `solves.csv` and
`boxplot.png` are written from all finished configurations (`evaluation_report.py`).

Randomness: configuration i uses `default_rng([seed, i])`; its rollouts in mode m
use `default_rng([seed, i, k_m])` (k_model = 0, k_true = 1), the same generator
state for every method (common random numbers).

The rollouts run each plan at its planned pace, or split its steps so that the tool moves no faster
than its speed limits (the evaluation file's `execution.pace`, `pacing.py`).

Rollouts observe only when the true pose is detectable (the evaluation file's
`detection`, `rollout.Detection`); a rollout is a successful grasp when its final true
pose is within the file's `grasp` tolerances of the goal (the simulated Table II).

One writer per output folder: the run holds an exclusive lock on `DIR` (`run_lock.py`); a second
`evaluate` into it is refused. Every record carries its `seed` and `rollouts`, so `--resume` checks
the settings even when `run.json` is gone; a record that is not whole (a method, mode, metric or
rollout missing, a value not a finite number) is dropped and its configuration run again (said on
stderr).

Where the configurations run: in this process (`--jobs 1`), a process pool
(`--jobs N`), or an existing Dask cluster (`--scheduler ADDRESS`, dask.distributed):
the same records, the same `progress.jsonl`, resume and progress bar in each case.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import signal
import sys
import threading
from pathlib import Path

from ..errors import SurestepError, shown
from ..method_grammar import is_closed_loop
from ..methods.registry import CLOSED_LOOP_NEEDS, parse_method
from ..output.files import check_output_dir, check_output_file
from ..output.solution import write_json_atomic, write_text_atomic
# evaluate_configuration, _SAMPLERS and read_progress: imported from here too (the tests, sweep.py)
from .configuration_record import _SAMPLERS, evaluate_configuration  # noqa: F401
from .configs import load_evaluation
from .evaluation_report import write_outputs
from .parallel import dask_client, run_dask, run_pool
from .progress_file import append_line, read_progress, record_gap
from .rollout import MODES
from .run_lock import hold

MAX_CONFIGS = 100_000
MAX_ROLLOUTS = 100_000
MAX_JOBS = 256

DEFAULT_METHODS = ("baseline", "gradient", "gradient-no-pose-loss", "gradient-no-depth",
                   "gradient-no-fov", "gradient-no-orientation", "ocp", "ocp-no-depth",
                   "ocp-no-fov", "ocp-no-orientation")
DASK_CONNECT_TIMEOUT = "10s"


class Terminated(KeyboardInterrupt):
    """SIGTERM during `run_evaluation`: raised in the main thread (once), so the pool's workers are
    stopped and every output file is left whole or absent, as after Ctrl-C; `surestep evaluate` then
    exits 143."""


@contextlib.contextmanager
def _sigterm_raises():
    """While inside: SIGTERM raises `Terminated` (in the main thread only; elsewhere nothing
    changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        # one raise: a second SIGTERM does not break the clean-up
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated()

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _fingerprint(spec) -> str:
    h = hashlib.sha256()
    for p in (spec.path, spec.base_path):
        h.update(Path(p).read_bytes())
    return h.hexdigest()[:16]


def run_evaluation(eval_path: str | Path, out_dir: str | Path, configs: int = 100,
                   rollouts: int = 50, seed: int = 0, methods: tuple[str, ...] = DEFAULT_METHODS,
                   modes: tuple[str, ...] = MODES, jobs: int = 1,
                   resume: bool = False, progress: bool = True,
                   scheduler: str | None = None) -> str:
    """Run (or continue) an evaluation and write its files; returns the table (Markdown).

    `scheduler`: address of a running Dask scheduler (e.g. tcp://host:8786), or a
    `distributed.Client` / `LocalCluster`-backed client object; the configurations then run
    on its workers (`jobs` is ignored), which must be able to import surestep_ocp and read
    the evaluation file at the same path.

    SIGTERM (in the main thread) stops the workers and raises `Terminated`, the files left whole or
    absent.

    Raises:
        SurestepError: bad arguments, a bad evaluation file, or a directory holding another run.
    """
    with _sigterm_raises():
        try:
            return _run_evaluation(eval_path, out_dir, configs, rollouts, seed, methods, modes,
                                   jobs, resume, progress, scheduler)
        except Terminated as exc:
            if not exc.args:  # outside the configurations' loop (set-up, or the tables at the end)
                raise Terminated(f"the files in {out_dir} are whole or absent; continue with the "
                                 "same command plus --resume") from None
            raise


def _run_evaluation(eval_path, out_dir, configs, rollouts, seed, methods, modes, jobs, resume,
                    progress, scheduler) -> str:
    """`run_evaluation` within its SIGTERM handling: the arguments checked, the output folder held,
    the configurations not yet done run, the outputs written."""
    eval_path, methods, spec = _checked_arguments(eval_path, configs, rollouts, seed, methods, jobs)
    inputs = (spec.path, spec.base_path)
    out = check_output_dir(out_dir, inputs, "the evaluation")
    with hold(out, "an evaluation"):  # one writer per folder, for the whole run
        for name in ("run.json", "progress.jsonl", "table.md", "raw.csv", "solves.csv",
                     "boxplot.png"):
            check_output_file(out / name, inputs, "the evaluation")
        prog = out / "progress.jsonl"
        header = {"evaluation": str(Path(eval_path).resolve()), "fingerprint": _fingerprint(spec),
                  "seed": seed, "rollouts": rollouts, "methods": list(methods),
                  "modes": list(modes), "horizon": spec.horizon}
        _check_resume(out, prog, header, resume)
        # the settings were compared with run.json above
        checked = resume and (out / "run.json").is_file()
        check = _record_check(out, seed, rollouts, methods, modes, configs, checked)
        done = read_progress(prog, check) if resume else {}
        # fail before writing
        client, own_client = (dask_client(scheduler, DASK_CONNECT_TIMEOUT)
                              if scheduler is not None else (None, False))
        write_json_atomic(out / "run.json", header)
        if not resume:
            write_text_atomic(prog, "")
        todo = [i for i in range(configs) if i not in done]
        args = (eval_path, seed)
        rest = (methods, rollouts, modes)
        _run_configurations(todo, args, rest, done, prog, configs, jobs, progress, client,
                            own_client)
        records = [done[i] for i in range(configs)]
        return write_outputs(records, out, methods, modes, header, spec)


def _checked_arguments(eval_path, configs, rollouts, seed, methods, jobs):
    """(the evaluation file's path as text, the methods with the baseline first, its evaluation
    spec), or a SurestepError for a bad argument."""
    if configs < 1 or rollouts < 2 or jobs < 1:
        raise SurestepError(f"need --configs >= 1, --rollouts >= 2, --jobs >= 1 (got {configs}, "
                            f"{rollouts}, {jobs})")
    for flag, value, most in (("--configs", configs, MAX_CONFIGS),
                              ("--rollouts", rollouts, MAX_ROLLOUTS), ("--jobs", jobs, MAX_JOBS)):
        if value > most:
            raise SurestepError(f"{flag} {value}: at most {most}")
    if not 0 <= seed < 2**63:
        raise SurestepError(f"--seed {seed}: expected an integer in [0, 2^63)")
    for m in methods:
        parse_method(m)
    # the baseline is the reference of the table
    methods = tuple(dict.fromkeys(("baseline", *methods)))
    eval_path = str(eval_path)
    spec = load_evaluation(eval_path)
    closed = [m for m in methods if is_closed_loop(m)]
    if closed and not spec.base.limits.enforce:
        raise SurestepError(f"{eval_path}: --methods {' '.join(closed)}: {CLOSED_LOOP_NEEDS}; set "
                            "`limits: {enforce: true}` and `horizon: 40` in the evaluation file "
                            "(as problems/evaluations/robot_pace.yaml does)")
    return eval_path, methods, spec


def _check_resume(out: Path, prog: Path, header: dict, resume: bool) -> None:
    """A --resume continues a run of the same settings (run.json); without it, the folder holds no
    run yet."""
    if resume and (out / "run.json").is_file():
        try:
            old = json.loads((out / "run.json").read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise SurestepError(f"{out / 'run.json'}: not a run record ({exc}); use another "
                                "--output-dir") from None
        if not isinstance(old, dict):
            raise SurestepError(f"{out / 'run.json'}: not a run record (a JSON "
                                f"{type(old).__name__}, not an object); use another "
                                "--output-dir")
        diff = [k for k in header if k != "evaluation" and old.get(k) != header[k]]
        if diff:
            raise SurestepError(f"{out}: --resume of a run with other settings "
                                f"({', '.join(diff)}: "
                                f"{', '.join(f'{old.get(k)} vs {header[k]}' for k in diff)}); "
                                "use another --output-dir")
    elif not resume and prog.is_file() and prog.stat().st_size > 0:
        raise SurestepError(f"{out} already holds a run (progress.jsonl); pass --resume to "
                            "continue it or choose another --output-dir")


def _record_check(out: Path, seed: int, rollouts: int, methods, modes, configs: int,
                  checked: bool):
    """The resume's check of a record: its seed and rollouts those of this run (a SurestepError if
    not), then None or what keeps it from being a whole record of this run (`record_gap`)."""

    def check(rec: dict) -> str | None:
        for key, want in (("seed", seed), ("rollouts", rollouts)):
            if key not in rec:
                if not checked:
                    return f"no '{key}' recorded and no run.json to compare with"
            elif rec[key] != want:
                raise SurestepError(f"{out}: --resume of a run with other settings ({key}: "
                                    f"{rec[key]} vs {want}, configuration {rec['config']} of "
                                    "progress.jsonl); use another --output-dir")
        return record_gap(rec, methods, modes, rollouts, configs)

    return check


def _run_configurations(todo, args, rest, done: dict, prog: Path, configs: int, jobs: int,
                        progress: bool, client, own_client: bool) -> None:
    """The configurations `todo` here, on a pool of `jobs` processes or on the Dask `client`: each
    record appended to `prog` and put in `done` as it completes, under a progress bar."""
    from tqdm import tqdm  # loaded on use: only a run draws the bar

    bar = tqdm(total=configs, initial=configs - len(todo), desc="configurations", unit="config",
               file=sys.stderr, disable=not progress, dynamic_ncols=True, mininterval=0.5)
    failed = sum(not s["success"] for i in range(configs) if i in done
                 for s in done[i]["solves"].values())

    def finish(rec: dict) -> None:
        nonlocal failed
        append_line(prog, rec)
        done[rec["config"]] = rec
        failed += sum(not s["success"] for s in rec["solves"].values())
        bar.set_postfix(failed_solves=failed)
        bar.update(1)

    try:
        if client is not None and todo:
            run_dask(todo, args, rest, client, finish)
        elif jobs == 1 or len(todo) <= 1:
            for i in todo:
                finish(evaluate_configuration(*args, i, *rest))
        else:
            run_pool(todo, args, rest, jobs, finish)
    except Terminated:
        bar.close()
        raise Terminated(f"{len(done)} of {configs} configurations kept in {prog}; continue "
                         "with the same command plus --resume") from None
    except KeyboardInterrupt:
        bar.close()
        print(f"\ninterrupted: {len(done)} of {configs} configurations kept in {prog}; "
              "continue with the same command plus --resume", file=sys.stderr)
        raise
    finally:
        bar.close()
        if own_client:
            client.close()


# ------------------------------------------------------------------ command line
def cmd_evaluate(args) -> int:
    methods = DEFAULT_METHODS
    if args.methods:
        methods = tuple(m for a in args.methods for m in a.split(","))
        if not all(methods):  # '' or ',': no method named, not the baseline alone
            raise SurestepError(f"--methods: an empty method name in "
                                f"{shown(' '.join(args.methods))}; give methods space- or "
                                "comma-separated")
    modes = MODES if args.rollout_mode == "both" else (args.rollout_mode,)
    out = args.output_dir or str(Path("out") / f"evaluate-{Path(args.evaluation).stem}")
    try:
        table = run_evaluation(args.evaluation, out, args.configs, args.rollouts, args.seed,
                               methods, modes, args.jobs, args.resume, progress=not args.quiet,
                               scheduler=getattr(args, "scheduler", None))
    except Terminated as exc:
        return say_terminated(exc)
    print(table)
    print(f"\nwrote {out}/{{table.md, raw.csv, solves.csv, boxplot.png, progress.jsonl, run.json}}")
    return 0


def say_terminated(exc: Terminated) -> int:
    """The one line after a SIGTERM; the exit code of a process ended by SIGTERM (128 + 15)."""
    try:
        print(f"surestep: terminated (SIGTERM): {exc}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
    return 143


def register(subparsers):
    """Add the `evaluate` subcommand to an argparse subparsers object; returns its parser."""
    e = subparsers.add_parser(
        "evaluate",
        help="noisy closed-loop rollouts of every method over random configurations (Table I)",
        description="Plan with each method on random configurations of EVAL.yaml, run noisy "
                    "closed-loop rollouts of each plan and write table.md, raw.csv, solves.csv and "
                    "boxplot.png.")
    e.add_argument("evaluation", metavar="EVAL.yaml",
                   help="evaluation file (e.g. problems/evaluations/evaluation.yaml)")
    e.add_argument("--configs", type=int, default=100,
                   help="number of random configurations (default 100)")
    e.add_argument("--rollouts", type=int, default=50,
                   help="noisy rollouts per plan and mode (default 50)")
    e.add_argument("--seed", type=int, default=0,
                   help="seed of the configurations and rollouts (default 0)")
    e.add_argument("--output-dir", help="output directory (default out/evaluate-<EVAL stem>)")
    e.add_argument("--methods", nargs="+", help="methods, space- or comma-separated (default: "
                   + ", ".join(DEFAULT_METHODS) + "); the baseline is always included")
    e.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    e.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the configurations on an existing Dask cluster (e.g. tcp://host:8786; "
                        "needs dask.distributed, the 'dask' extra); --jobs is then ignored")
    e.add_argument("--rollout-mode", choices=("model", "true", "both"), default="both",
                   help="where the observation noise is evaluated (default both)")
    e.add_argument("--resume", action="store_true",
                   help="continue the run in --output-dir (skip finished configs)")
    e.add_argument("--quiet", action="store_true", help="no progress bar")
    e.set_defaults(func=cmd_evaluate)
    return e
