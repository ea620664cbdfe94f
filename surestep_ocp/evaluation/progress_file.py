"""`progress.jsonl` of `surestep evaluate`: one JSON line per finished configuration, appended in
one write each (so an interrupted run keeps its work), read back on `--resume`, where a record that
is not whole is dropped and its configuration run again.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

from ..errors import SurestepError
from ..output.solution import _jsonable, write_text_atomic
from .rollout import METRICS


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


def record_gap(rec: dict, methods, modes, rollouts: int, configs: int) -> str | None:
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
