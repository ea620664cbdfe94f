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
import ctypes
import hashlib
import json
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from ..model.grasp import within
from ..errors import SurestepError, shown
from ..model.limits.values import problem_limits
from .configs import ConfigurationSampler, load_evaluation
from .evaluation_report import write_outputs
from .pacing import paced
from .rollout import METRICS, MODES, plan_metrics
from .run_lock import hold
from ..output.files import check_output_dir, check_output_file
from ..output.solution import _jsonable, write_json_atomic, write_text_atomic
from ..method_grammar import is_closed_loop
from ..methods.registry import CLOSED_LOOP_NEEDS, method_setup, parse_method, run_method
from .closed_loop import ClosedLoop

MAX_CONFIGS = 100_000
MAX_ROLLOUTS = 100_000
MAX_JOBS = 256

DEFAULT_METHODS = ("baseline", "gradient", "gradient-no-pose-loss", "gradient-no-depth",
                   "gradient-no-fov", "gradient-no-orientation", "ocp", "ocp-no-depth",
                   "ocp-no-fov", "ocp-no-orientation")

# ------------------------------------------------------------------ one configuration (worker side)
_SAMPLERS: dict = {}


def _sampler(eval_path: str):
    key = str(Path(eval_path).resolve())
    if key not in _SAMPLERS:
        _SAMPLERS[key] = ConfigurationSampler(load_evaluation(eval_path))
    return _SAMPLERS[key]


def executed_poses(setup, poses, pace: str) -> np.ndarray:
    """The waypoints the rollouts follow: the plan's (`planned`) or the plan's run at the tool's
    limits (`limits`: the problem's `limits:` tool speeds, one rollout step of `timing.step_s` each;
    pacing.py)."""
    poses = np.asarray(poses, float)
    if pace == "planned":
        return poses
    lim = problem_limits(setup)
    return paced(poses, setup.ocp.timing.step_s, lim.tool_speed, lim.tool_rotation)


def evaluate_configuration(eval_path: str, seed: int, index: int, methods: tuple[str, ...],
                           rollouts: int, modes: tuple[str, ...]) -> dict:
    """Plan with every method on configuration `index` and roll each plan out; a JSON-able record.

    Picklable arguments only (each process builds its own set-up and solvers). A method
    that raises is recorded with its error (no plan, no metrics); a plan whose solver
    reports failure is still rolled out, and flagged.
    """
    smp = _sampler(eval_path)
    cfg = smp.sample(seed, index)
    setup = smp.setup_of(cfg)
    spec = smp.spec
    rec = {"config": index, "seed": seed, "rollouts": rollouts, **cfg.to_dict(), "solves": {},
           "metrics": {m: {} for m in modes},
           "pos_errors": {m: {} for m in modes}, "ori_errors": {m: {} for m in modes},
           "success": {m: {} for m in modes}, "detected": {m: {} for m in modes}}
    per_rollout = ("pos_errors", "ori_errors", "success", "detected")
    cache = {}
    for name in methods:
        t0 = time.perf_counter()
        policy = None
        try:
            if is_closed_loop(name):  # re-plans in every rollout, from this first plan
                policy = ClosedLoop(method_setup(setup, name))
                sol = policy.first_plan
                sol.method = name
            else:
                sol = run_method(setup, name, cache)
        except Exception as exc:  # noqa: BLE001 - recorded in solves.csv and counted in the table
            rec["solves"][name] = {"success": False,
                                   "status": f"error: {type(exc).__name__}: {exc}",
                                   "solve_time_s": time.perf_counter() - t0, "iterations": 0,
                                   "evaluated": False}
            continue
        cache[name] = sol
        solve = {"success": sol.success, "status": sol.status, "solve_time_s": sol.solve_time_s,
                 "iterations": sol.iterations, "evaluated": True}
        if sol.status == "Initial_Guess_Kept":  # why: what every solver attempt ended with
            solve["kept_start"] = ("; ".join(f"{a.label}: {a.status}" for a in sol.attempts)
                                   or sol.run.solver or "")
        try:
            # a closed loop runs within the limits: at the robot's pace already
            poses = (np.asarray(sol.poses, float) if policy is not None
                     else executed_poses(setup, sol.poses, spec.pace))
            solve["rollout_steps"] = len(poses) - 1
            for mode in modes:
                rng = np.random.default_rng([seed, index, MODES.index(mode)])
                if policy is not None:
                    policy.reset()
                met, ro = plan_metrics(setup.eval_model, poses, setup.x_goal, rollouts, rng, mode,
                                       sol.sigma_final, detection=spec.detection, policy=policy)
                if policy is not None:
                    summary = policy.summary()
                    solve.setdefault("replans", {})[mode] = {
                        k: summary[k] for k in ("replans", "failed", "late_replans", "median_ms",
                                                "worst_ms", "late_worst", "violations")}
                rec["metrics"][mode][name] = met
                rec["pos_errors"][mode][name] = ro.pos_err.tolist()
                rec["ori_errors"][mode][name] = ro.ori_err.tolist()
                ok = within(ro.pos_err, ro.ori_err, spec.grasp_position, spec.grasp_angle)
                rec["success"][mode][name] = float(np.mean(ok))
                rec["detected"][mode][name] = (float(np.mean(ro.detected))
                                               if ro.detected is not None else 1.0)
        except (ValueError, np.linalg.LinAlgError) as exc:  # e.g. NaN waypoints of a failed solve
            solve.update(evaluated=False, status=f"{sol.status}; rollout error: {exc}")
            for mode in modes:
                rec["metrics"][mode].pop(name, None)
                for key in per_rollout:
                    rec[key][mode].pop(name, None)
        rec["solves"][name] = solve
    return rec


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops the workers
    # a parent killed outright (SIGKILL) takes its workers with it
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # 1: PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            return
        parent = multiprocessing.parent_process()
        if parent is not None and os.getppid() != parent.pid:  # it died before the prctl
            os._exit(1)


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


# ------------------------------------------------------------------ the run (parent side)
def _fingerprint(spec) -> str:
    h = hashlib.sha256()
    for p in (spec.path, spec.base_path):
        h.update(Path(p).read_bytes())
    return h.hexdigest()[:16]


def _record_problem(rec) -> str | None:
    """None if `rec` has the structure `evaluate_configuration` writes, else what is wrong."""
    if not isinstance(rec, dict):
        return f"a JSON {type(rec).__name__}, not an object"
    if (isinstance(rec.get("config"), bool) or not isinstance(rec.get("config"), int)
        or rec["config"] < 0):
        return "no 'config' index (an integer >= 0)"
    solves = rec.get("solves")
    if not isinstance(solves, dict) or not all(
            isinstance(v, dict) and isinstance(v.get("success"), bool) for v in solves.values()):
        return "'solves' is not a mapping of method -> {success, ...}"
    # written by every record since the settings' check (older records: absent)
    for key in ("seed", "rollouts"):
        if key in rec and (isinstance(rec[key], bool) or not isinstance(rec[key], int)):
            return f"'{key}' is not an integer"
    for key in ("metrics", "pos_errors"):
        if (not isinstance(rec.get(key), dict)
            or not all(isinstance(v, dict) for v in rec[key].values())):
            return f"'{key}' is not a mapping of mode -> method -> values"
    return None


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _record_gap(rec: dict, methods, modes, rollouts: int, configs: int) -> str | None:
    """None if the record is a whole, finite record of this run (every method, mode, metric,
    rollout), else what is wrong with it: such a record is run again, never copied into the
    results."""
    if rec["config"] >= configs:
        return None  # beyond this run's --configs: kept in the file, not used
    if not isinstance(rec.get("x_goal"), list):
        return "no 'x_goal'"
    for m in methods:
        s = rec["solves"].get(m)
        if s is None:
            return f"no solve of method '{m}'"
        if not isinstance(s.get("status"), str) or not isinstance(s.get("evaluated"), bool):
            return f"solves.{m}: no 'status' text or 'evaluated' flag"
        if not _real(s.get("solve_time_s")) or s["solve_time_s"] < 0:
            return f"solves.{m}.solve_time_s is not a finite number >= 0"
        if (isinstance(s.get("iterations"), bool) or not isinstance(s.get("iterations"), int)
            or s["iterations"] < 0):
            return f"solves.{m}.iterations is not an integer >= 0"
        if not s["evaluated"]:
            continue
        for mode in modes:
            met = rec["metrics"].get(mode, {}).get(m)
            if not isinstance(met, dict):
                return f"no metrics of '{m}' in mode '{mode}'"
            for k in METRICS:
                if not _real(met.get(k)):
                    return (f"metrics.{mode}.{m}.{k} is "
                            f"{'missing' if k not in met else repr(met[k])}, not a finite number")
            for key in ("pos_errors", "ori_errors"):
                e = ((rec.get(key) or {}).get(mode, {}).get(m) if isinstance(rec.get(key), dict)
                     else None)
                if not isinstance(e, list) or len(e) != rollouts or not all(_real(x) for x in e):
                    return f"{key}.{mode}.{m} is not {rollouts} finite numbers"
            for key in ("success", "detected"):
                node = rec.get(key)
                v = (node.get(mode, {}).get(m)
                     if isinstance(node, dict) and isinstance(node.get(mode), dict) else None)
                if not _real(v) or not 0.0 <= v <= 1.0:
                    return f"{key}.{mode}.{m} is {v!r}, not a share in [0, 1]"
    return None


def read_progress(path: Path, check=None) -> dict[int, dict]:
    """Finished configurations of `progress.jsonl`; a torn last line (interrupted write) is dropped.

    `check(rec)` (a resume): None, or why a record of the right shape cannot be used (a missing
    method, mode, metric or rollout, a non-finite or non-numeric value): it is then dropped from the
    file, said on stderr, and its configuration run again; never copied into the results.

    Raises:
        SurestepError: a line that is JSON but not a record of an evaluation (named by its number).
    """
    done: dict[int, dict] = {}
    if not path.is_file():
        return done
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SurestepError(f"{path}: cannot read the progress record ({exc}); use another "
                            "--output-dir") from None
    good = []
    for n, line in enumerate(lines, 1):
        try:
            rec = json.loads(line)
        except (ValueError, RecursionError):
            continue  # a torn (interrupted) write
        problem = _record_problem(rec)
        # not the shape of a record at all: another file, not a torn or partial record
        if problem is not None:
            raise SurestepError(f"{path}: line {n} is not a record of this evaluation ({problem}); "
                                "remove the line, or run without --resume into another "
                                "--output-dir")
        gap = check(rec) if check is not None else None
        if gap is not None:
            print(f"surestep: {path}: line {n} (configuration {rec['config']}) is not a whole "
                  f"record of this run ({gap}); it is dropped and run again", file=sys.stderr)
            continue
        done[rec["config"]] = rec
        good.append(line)
    if len(good) != len(lines):  # rewrite without the torn line so appends start on a fresh line
        write_text_atomic(path, "".join(g + "\n" for g in good))
    return done


def append_line(path: Path, obj: dict) -> None:
    """Append one JSON line with a single O_APPEND write, then fsync."""
    data = (json.dumps(obj, default=_jsonable) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)


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
        # the settings were compared with run.json above
        checked = resume and (out / "run.json").is_file()

        def check(rec: dict) -> str | None:
            for key, want in (("seed", seed), ("rollouts", rollouts)):
                if key not in rec:
                    if not checked:
                        return f"no '{key}' recorded and no run.json to compare with"
                elif rec[key] != want:
                    raise SurestepError(f"{out}: --resume of a run with other settings ({key}: "
                                        f"{rec[key]} vs {want}, configuration {rec['config']} of "
                                        "progress.jsonl); use another --output-dir")
            return _record_gap(rec, methods, modes, rollouts, configs)

        done = read_progress(prog, check) if resume else {}
        # fail before writing
        client, own_client = _dask_client(scheduler) if scheduler is not None else (None, False)
        write_json_atomic(out / "run.json", header)
        if not resume:
            write_text_atomic(prog, "")
        todo = [i for i in range(configs) if i not in done]
        args = (eval_path, seed)
        rest = (methods, rollouts, modes)

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
                _run_dask(todo, args, rest, client, finish)
            elif jobs == 1 or len(todo) <= 1:
                for i in todo:
                    finish(evaluate_configuration(*args, i, *rest))
            else:
                _run_pool(todo, args, rest, jobs, finish)
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
        records = [done[i] for i in range(configs)]
        return write_outputs(records, out, methods, modes, header, spec)


def _run_pool(todo, args, rest, jobs, finish) -> None:
    ex = ProcessPoolExecutor(max_workers=min(jobs, len(todo)),
                             mp_context=multiprocessing.get_context("spawn"),
                             initializer=_worker_init)
    futures = []
    try:
        futures = [ex.submit(evaluate_configuration, *args, i, *rest) for i in todo]
        for fut in as_completed(futures):
            finish(fut.result())
    except BaseException:
        for f in futures:
            f.cancel()
        for p in list((getattr(ex, "_processes", None) or {}).values()):
            p.terminate()
        raise
    finally:
        ex.shutdown(wait=True, cancel_futures=True)


DASK_CONNECT_TIMEOUT = "10s"


def _dask_client(scheduler):
    """(client, whether we opened it) for a scheduler address, or a `distributed.Client` passed
    in."""
    try:
        from distributed import Client  # optional: the `dask` extra
    except ImportError as exc:
        raise SurestepError("--scheduler needs dask.distributed (pip install "
                            f"'surestep_ocp[dask]'): {exc}") from None
    if not isinstance(scheduler, str):
        return scheduler, False
    _check_scheduler_address(scheduler)
    try:
        return Client(scheduler, timeout=DASK_CONNECT_TIMEOUT, set_as_default=False), True
    except (OSError, TimeoutError, ValueError) as exc:
        raise SurestepError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler "
                            f"({type(exc).__name__}: {exc})") from None


def _check_scheduler_address(scheduler: str) -> None:
    """Refuse an address dask.distributed cannot parse before a `Client` is made of it.

    A `Client` whose address fails to parse is left half-started: its `__del__` then waits 20 s
    and prints a traceback. The checks are distributed's own parsers (scheme, then host:port).
    """
    from distributed.comm import registry
    from distributed.comm.addressing import parse_address

    allowed = "an address like tcp://host:8786 (or tls://, ws://, wss://, inproc://)"
    scheme, loc = parse_address(scheduler)
    try:
        backend = registry.get_backend(scheme)
    except ValueError:
        raise SurestepError(f"--scheduler {scheduler!r}: unknown scheme {scheme!r}; "
                            f"expected {allowed}") from None
    try:
        try:
            host, port = backend.get_address_host_port(loc)
        except NotImplementedError:  # not an IP transport (inproc): its own form and checks
            backend.get_address_host(loc)
            return
    except (ValueError, TypeError) as exc:
        raise SurestepError(f"--scheduler {scheduler!r}: not a {scheme}:// address ({exc}); "
                            f"expected {allowed}") from None
    if not host or not 0 < port < 65536:
        raise SurestepError(f"--scheduler {scheduler!r}: needs a host and a port in 1..65535; "
                            f"expected {allowed}")


def _run_dask(todo, args, rest, client, finish) -> None:
    """The configurations as Dask futures on the client's cluster; records handed to `finish` as
    they complete."""
    from distributed import as_completed  # optional (the `dask` extra), loaded on use

    futures = []
    tag = uuid.uuid4().hex[:8]
    try:
        # pure=False: every configuration is its own task; retries=1 rescues a worker lost mid-task
        futures = [client.submit(evaluate_configuration, *args, i, *rest,
                                 key=f"surestep-config-{i}-{tag}", pure=False,
                                 retries=1) for i in todo]
        with client.as_current():
            for fut in as_completed(futures):
                finish(fut.result())
    except BaseException:
        client.cancel(futures)
        raise


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
