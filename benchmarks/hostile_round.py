"""The hostile round of issue 48, reproducible: each defect the issue lists tried again as a hostile
user would (command line and public API), plus new attempts of the same kinds: cache folders that
are files, FIFOs, read-only or full; extreme but valid noise scales (1e-30 .. 1e6) in every problem
file and model family; exports to odd paths; Planner arguments; Ctrl-C.

    .venv/bin/python benchmarks/hostile_round.py [--only WORD] [--work DIR]

Every attempt runs in a subprocess (a hang is a timeout, not a stuck round) and prints one line:
`what | exit code | outcome`. An outcome is `ok: ...` or `BAD: ...`: a traceback, an internal error,
a Python warning, a hang, an exit code other than the one expected, more than one line for a bad
input (exit 2), a non-finite number in a written file, a changed input or a partial output. Exits 1
if any is BAD. Read-only and full file systems are tmpfs mounts (root); without them those attempts
say `skipped`. Results: docs/hostile_round.md.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import os
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PY = str(ROOT / ".venv" / "bin" / "python")
CLI = str(ROOT / ".venv" / "bin" / "surestep")
PACE = ROOT / "problems" / "needle_regrasp_paper_pace.yaml"
DEFAULT = ROOT / "problems" / "needle_regrasp.yaml"
SCALES = [(1e6, 1e-30), (1e-30, 1e6), (1e6, 1e6), (1e-30, 1e-30)]
BAD_WORDS = ("Traceback", "internal error", "Warning:", "RuntimeWarning")
rows: list[tuple[str, str, str]] = []
ONLY = ""


def line(what: str, code, outcome: str) -> None:
    rows.append((what, str(code), outcome))
    print(f"{what} | {code} | {outcome}", flush=True)


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "-"


def non_finite(folder: Path, since: float) -> str | None:
    """The first written file (after `since`) holding NaN or Infinity."""
    for p in folder.rglob("*"):
        if not p.is_file() or p.stat().st_mtime < since or p.suffix not in (".json", ".csv",
                                                                                  ".yaml", ".md"):
            continue
        text = p.read_text(errors="replace")
        if p.suffix == ".json":
            try:
                json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
            except ValueError as exc:
                return f"{p.name}: {exc}"
        elif re.search(r"(?<![\w.])-?(nan|inf|infinity)(?![\w])", text, re.I):
            return f"{p.name}: nan/inf"
    return None


def run(what: str, argv: list[str], expect=(0,), env: dict | None = None, cwd: Path | None = None,
        timeout: float = 300, check=None, interrupt_after: float | None = None,
        fsize: int | None = None, code: str | None = None) -> tuple[int, str, str]:
    """One attempt: the command (or `code` in the venv's Python), its exit code against `expect`,
    the generic checks, then `check(out, err)` -> a problem or None."""
    if ONLY and ONLY not in what:
        return -1, "", ""
    if code is not None:
        argv = [PY, "-c", code]
    full_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", **(env or {})}
    full_env = {k: v for k, v in full_env.items() if v is not None}

    def limits():
        os.setsid()
        # (a background shell starts its jobs with SIGINT ignored, and Python keeps it so: Ctrl-C
        # would not be tried)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    since = time.time() - 1
    work = cwd or Path.cwd()
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=full_env, cwd=work, preexec_fn=limits)
    try:
        if interrupt_after is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(interrupt_after)
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        line(what, "-", f"BAD: hang (no exit within {timeout:g} s)")
        return -9, out, err
    rc = p.returncode
    text = out + err
    bad = [w for w in BAD_WORDS if w in text]
    problem = None
    if bad:
        problem = f"{bad[0]}: " + next(x for x in text.splitlines() if bad[0] in x)[:160]
    elif rc not in expect:
        problem = f"exit {rc}, expected {'/'.join(map(str, expect))}: " + _last(err or out)
    elif rc == 2 and len([x for x in err.splitlines() if x.strip()]) != 1:
        problem = f"{len(err.splitlines())} lines for one bad input: " + err.replace("\n", " / ")
    else:
        problem = non_finite(work, since) if cwd else None
        if problem is None and check is not None:
            problem = check(out, err)
    line(what, rc, f"BAD: {problem}" if problem else f"ok: {_last(err if rc else out or err)}")
    return rc, out, err


def _last(text: str) -> str:
    lines = [x for x in text.strip().splitlines() if x.strip()]
    return (lines[-1] if lines else "(no output)")[:170].replace("|", "/")


@contextlib.contextmanager
def tmpfs(path: Path, size: str, readonly: bool = False):
    """A tmpfs at `path` (None when mounting is not allowed)."""
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if readonly else "")
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)],
                        capture_output=True).returncode == 0
    try:
        yield path if ok else None
    finally:
        if ok:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)


def fill(folder: Path) -> None:
    """Fill the file system of `folder` to its last byte."""
    for name, chunk in (("filler", 65536), ("filler2", 1)):
        with contextlib.suppress(OSError), open(folder / name, "wb") as f:
            while True:
                f.write(b"\0" * chunk)
                f.flush()


def write_problem(path: Path, base: Path, edit) -> Path:
    tree = yaml.safe_load(base.read_text())
    for arm in (tree["robot"], tree.get("camera", {}).get("ecm"),
                tree.get("goal", {}).get("relative", {}).get("arm")):
        if arm and ":" not in arm["urdf"]:  # (`package:path` names a package's file)
            arm["urdf"] = str(ROOT / arm["urdf"])
    edit(tree)
    path.write_text(yaml.safe_dump(tree))
    return path


def scaled(w, v, extra=None):
    def edit(tree):
        n = tree.setdefault("noise", {})
        n.update(W_p0=w, W_o0=w, V_d0=v, V_f0=v, V_o0=v)
        for k, val in (extra or {}).items():
            section, key = k.split(".")
            tree.setdefault(section, {})[key] = val(w, v) if callable(val) else val
    return edit


def solution_check(expect_success: bool | None = None):
    def check(out, err):
        m = re.search(r"wrote\s+(\S+)", out)
        if not m:
            return None
        d = json.loads(Path(m.group(1)).read_text())
        tr = d.get("trace")
        trace = tr[-1] if isinstance(tr, list) else tr
        if not (isinstance(trace, float) and math.isfinite(trace) and trace > 0):
            return f"Tr(Sigma_T) = {trace!r} (status {d.get('status')})"
        if "ABNORMAL" in str(d.get("status")) and d.get("success"):
            return f"status {d['status']!r} with success true"
        return None
    return check


# ----------------------------------------------------------------------------- the attempts
def cache_attempts(w: Path) -> None:
    solve = [CLI, "solve", str(PACE), "--method", "ocp"]
    afile = w / "a_file"
    afile.write_text("x")
    fifo = w / "a_fifo"
    os.mkfifo(fifo)
    loop = w / "loop"
    loop.symlink_to(loop)
    note = lambda out, err: None if "interpreted" in out + err else "no fall-back note"
    for name, value in (("/dev/null", "/dev/null"), ("a regular file", afile),
                        ("/dev/zero", "/dev/zero"), ("a FIFO", fifo),
                        ("a folder under a file", afile / "sub"), ("a symlink loop", loop),
                        ("/sys (not permitted)", "/sys/surestep_cache")):
        run(f"#1 solve, SURESTEP_CACHE = {name}", solve, env={"SURESTEP_CACHE": str(value)},
            check=note)
    run("#1 solve, XDG_CACHE_HOME = a file, no SURESTEP_CACHE", solve,
        env={"XDG_CACHE_HOME": str(afile), "SURESTEP_CACHE": None}, check=note)
    run("#1 solve, SURESTEP_CACHE = '' (empty)", solve, env={"SURESTEP_CACHE": ""}, expect=(0, 2))
    with tmpfs(w / "ro", "1m", readonly=True) as ro:
        if ro is None:
            line("#1 solve, SURESTEP_CACHE on a read-only file system", "-", "skipped (no mount)")
        else:
            run("#1 solve, SURESTEP_CACHE on a read-only file system", solve,
                env={"SURESTEP_CACHE": str(ro / "c")}, check=note)
    with tmpfs(w / "full", "256k") as full:
        if full is None:
            line("#1 solve, SURESTEP_CACHE on a full file system", "-", "skipped (no mount)")
        else:
            (full / "c").mkdir()
            fill(full)
            run("#1 solve, SURESTEP_CACHE on a full file system (a compile needed)", solve,
                env={"SURESTEP_CACHE": str(full / "c")}, check=note)
    # a working cache of its own (one compile), then hostile copies of it
    fresh = w / "cache_fresh"
    t0 = time.perf_counter()
    run("cache: a fresh cache compiles", solve, env={"SURESTEP_CACHE": str(fresh)})
    line("cache: the fresh compile's wall time", "-", f"ok: {time.perf_counter() - t0:.1f} s")
    libs = sorted(fresh.glob("*.so"))
    if not libs:
        line("cache: hostile copies", "-", "BAD: the fresh cache holds no library")
        return

    def copy_cache(name):
        d = w / name
        shutil.copytree(fresh, d, symlinks=True)
        return d
    d = copy_cache("c_fifo_lib")
    lib = d / libs[0].name
    lib.unlink()
    os.mkfifo(lib)
    run("#3 solve, a FIFO in a cached library's place", solve, env={"SURESTEP_CACHE": str(d)},
        timeout=300)
    run("#3 cache, a FIFO in a cached library's place", [CLI, "cache"],
        env={"SURESTEP_CACHE": str(d)}, timeout=60)
    d = copy_cache("c_fifo_timing")
    with contextlib.suppress(FileNotFoundError):
        (d / "timing.json").unlink()
    os.mkfifo(d / "timing.json")
    run("#3 solve, timing.json a FIFO", solve, env={"SURESTEP_CACHE": str(d)}, timeout=300)
    run("#3 cache, timing.json a FIFO", [CLI, "cache"], env={"SURESTEP_CACHE": str(d)},
        timeout=60)
    d = copy_cache("c_zero")
    sums = sorted(d.glob("*.sha256"))
    if sums:
        sums[0].unlink()
        sums[0].symlink_to("/dev/zero")
    (d / libs[-1].name).unlink()
    (d / libs[-1].name).symlink_to("/dev/zero")
    run("#3 solve, a checksum and a library linked to /dev/zero", solve,
        env={"SURESTEP_CACHE": str(d)}, timeout=300)
    run("#3 cache --prune, links to /dev/zero", [CLI, "cache", "--prune"],
        env={"SURESTEP_CACHE": str(d)}, timeout=60)
    d = copy_cache("c_foreign")
    foreign = {"mylib.so": b"user", "download.part": b"user", "notes.txt": b"user",
               "x.so.1.part": b"user", f"{libs[0].stem}.so.bak": b"user"}
    for k, v in foreign.items():
        (d / k).write_bytes(v)
    (d / "sub").mkdir()
    (d / "sub" / "inner.so").write_bytes(b"user")
    orphan = d / f"{libs[0].name}.999999.part"
    orphan.write_bytes(b"half")
    run("#13 cache counts an orphaned partial write (pid gone)", [CLI, "cache"],
        env={"SURESTEP_CACHE": str(d)},
        check=lambda out, err: None if re.search(r"partial\s+1 orphaned", out) else "not counted")
    run("#2 cache --clear beside a user's files", [CLI, "cache", "--clear"],
        env={"SURESTEP_CACHE": str(d)},
        check=lambda out, err: ("deleted a user's file" if not all((d / k).exists()
                                                                   for k in foreign)
                                or not (d / "sub" / "inner.so").exists()
                                else "the orphan stayed" if orphan.exists()
                                else "a library stayed" if list(d.glob("*_*.so")) else None))
    d = copy_cache("c_prune")
    (d / "mylib.so").write_bytes(b"user")
    orphan = d / f"{libs[0].name}.999999.part"
    orphan.write_bytes(b"half")
    run("#13 cache --prune --max-mb 0.001 removes the orphan, keeps mylib.so",
        [CLI, "cache", "--prune", "--max-mb", "0.001"], env={"SURESTEP_CACHE": str(d)},
        check=lambda out, err: "orphan stayed" if orphan.exists() else
        "mylib.so removed" if not (d / "mylib.so").exists() else None)
    for v in ("inf", "nan", "-1", "1e400", "abc", "", " 5", "1e309"):
        run(f"#4 solve, SURESTEP_CACHE_MAX_MB={v!r}", solve,
            env={"SURESTEP_CACHE_MAX_MB": v, "SURESTEP_CACHE": str(w / "c_maxmb")},
            expect=(0, 2) if v in ("", " 5") else (2,))
        run(f"#4 cache --prune --max-mb {v!r}", [CLI, "cache", "--prune", "--max-mb", v],
            env={"SURESTEP_CACHE": str(w / "c_maxmb")}, expect=(0, 2) if v == " 5" else (2,))
    for name, value in (("/dev/null", "/dev/null"), ("a file", afile), ("a FIFO", fifo)):
        for args in ([], ["--clear"], ["--prune"]):
            run(f"cache {' '.join(args)} with SURESTEP_CACHE = {name}", [CLI, "cache", *args],
                env={"SURESTEP_CACHE": str(value)}, expect=(0, 2), timeout=60)


def noise_attempts(w: Path) -> None:
    for f in sorted((ROOT / "problems").glob("*.yaml")):
        for wv in SCALES:
            p = write_problem(w / f"{f.stem}_{wv[0]:g}_{wv[1]:g}.yaml", f, scaled(*wv))
            for method in ("baseline", "ocp"):
                run(f"#3 {f.stem} W={wv[0]:g} V={wv[1]:g} solve {method}",
                    [CLI, "solve", str(p), "--method", method, "-o", str(w / (p.stem + method))
                     + ".json"], expect=(0, 1), cwd=w, check=solution_check())
    eye = lambda s: [[s * (1.0 if i == j else 0.2 if abs(i - j) == 1 else 0.0) for j in range(6)]
                     for i in range(6)]
    families = {
        "full matrices": {"noise.W_p0": lambda w_, v: eye(w_), "noise.V_d0": lambda w_, v: eye(v)},
        "expected noise": {"noise.observation_noise": "expected"},
        "joint-space noise": {"noise.joint_motion_sigma": 0.1},
        "noise floor V_min": {"noise.V_min": lambda w_, v: v},
        "lifted (covariance full)": {"noise.W_p0": lambda w_, v: eye(w_),
                                     "solver.covariance": "full"},
        "predicted objective": {"objective.covariance": "predicted"},
        "geodesic orientation": {"noise.orientation_formula": "geodesic"},
        "limits enforced": {"limits.enforce": True},
    }
    for fam, extra in families.items():
        for wv in SCALES:
            p = write_problem(w / f"fam_{len(rows)}.yaml", PACE, scaled(*wv, extra))
            for method in ("baseline", "ocp", "gradient"):
                if method == "gradient" and fam in ("joint-space noise",
                                                    "lifted (covariance full)"):
                    continue
                run(f"#3 {fam} W={wv[0]:g} V={wv[1]:g} solve {method}",
                    [CLI, "solve", str(p), "--method", method, "-o",
                     str(w / f"fam_{len(rows)}.json")], expect=(0, 1, 2), cwd=w,
                    check=solution_check())
    repro = write_problem(w / "repro.yaml", PACE, scaled(1e6, 1e-30))
    run("#8 the repro, solve gradient (ABNORMAL is not success)",
        [CLI, "solve", str(repro), "--method", "gradient", "-o", str(w / "grad.json")],
        expect=(0, 1), cwd=w, check=solution_check())
    run("#7 the repro, compare (no NaN / Infinity in comparison.json)",
        [CLI, "compare", str(repro), "--output-dir", str(w / "cmp")], expect=(0, 1), cwd=w,
        timeout=900)
    zero = write_problem(w / "zeroV.yaml", PACE, scaled(1e-3, 0.0))
    run("new: every observation noise 0, compare baseline ocp",
        [CLI, "compare", str(zero), "--methods", "baseline", "ocp", "--output-dir",
         str(w / "cmp0")], expect=(0, 1), cwd=w)


def export_attempts(w: Path) -> None:
    sol = w / "sol.json"
    run("export: the solution to export", [CLI, "solve", str(PACE), "--method", "ocp", "-o",
                                           str(sol)])
    if not sol.exists():
        return
    before = sha(sol)
    ex = lambda fmt, out, *more: [CLI, "export", str(sol), "--format", fmt, "-o", str(out), *more]
    run("#9 export rosbag2 to bag.1", ex("rosbag2", w / "bag.1"), cwd=w)
    run("#9 export rosbag2 to bag.2 (its own figure)", ex("rosbag2", w / "bag.2"), cwd=w,
        check=lambda o, e: None if (w / "bag.1_motion.png").exists()
        and (w / "bag.2_motion.png").exists() else "the figures share one name")
    for rate in ("1e-6", "0.5", "0", "-1", "nan", "inf", "1e300", "abc"):
        run(f"#9 export rosbag2 --rate {rate}", ex("rosbag2", w / f"r{rate}", "--rate", rate),
            expect=(2,), cwd=w)
    for fmt in ("csv", "json", "ros2", "rosbag2"):
        run(f"#9 export {fmt} -o ''", [CLI, "export", str(sol), "--format", fmt, "-o", ""],
            expect=(2,), cwd=w)
    nulldev = w / "nulldev"
    with contextlib.suppress(OSError):
        os.mknod(nulldev, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    fifo = w / "out_fifo"
    os.mkfifo(fifo)
    (w / "a_dir").mkdir()
    (w / "a_file").write_text("x")
    (w / "link_to_sol.csv").symlink_to(sol)
    (w / "full_bag").mkdir()
    (w / "full_bag" / "x").write_text("x")
    odd = {"an existing folder": (w / "a_dir", (2,)),
           "a character device (a copy of /dev/null)": (nulldev, (2,)),
           "a FIFO": (fifo, (2,)), "under a file": (w / "a_file" / "x.csv", (2,)),
           "the input itself": (sol, (2,)), "a symlink to the input": (w / "link_to_sol.csv", (2,)),
           "a 300-character name": (w / ("n" * 300 + ".csv"), (2,)),
           "a new folder chain": (w / "new" / "deeper" / "x.csv", (0, 2)),
           "a name with a newline and unicode": (w / "a\nb é.csv", (0,)),
           "'-'": (Path("-"), (0, 2)), "'.'": (Path("."), (2,))}
    for name, (out, expect) in odd.items():
        for fmt in ("csv", "ros2"):
            run(f"new: export {fmt} to {name}", ex(fmt, out), expect=expect, cwd=w,
                check=lambda o, e: "the input changed" if sha(sol) != before else None)
    run("new: export rosbag2 into a non-empty folder", ex("rosbag2", w / "full_bag"),
        expect=(2,), cwd=w)
    if nulldev.exists() and not stat.S_ISCHR(nulldev.lstat().st_mode):
        line("new: the device node after the exports", "-", "BAD: replaced by a file")
    # a full disk: every format a clean exit 2, nothing left behind
    with tmpfs(w / "fullx", "512k") as full:
        if full is None:
            line("#9 export to a full disk", "-", "skipped (no mount)")
        else:
            fill(full)
            for fmt in ("csv", "json", "ros2", "rosbag2"):
                out = full / f"x_{fmt}"
                run(f"#9 export {fmt} to a full disk", ex(fmt, out), expect=(2,),
                    check=lambda o, e: "left files" if sorted(p.name for p in full.iterdir())
                    != ["filler", "filler2"] else None)
    for fmt in ("csv", "rosbag2"):
        for delay in (0.2, 0.4, 0.6, 0.8, 1.0):
            out = w / f"int_{fmt}_{delay}"
            rc, _, _ = run(f"#9 Ctrl-C during export {fmt} after {delay} s", ex(fmt, out),
                           expect=(0, 130), cwd=w, interrupt_after=delay)
            names = [p.name for p in w.iterdir() if p.name.startswith(f"int_{fmt}_{delay}")
                     or p.name.startswith(f".int_{fmt}_{delay}")]
            whole = {out.name, f"{out.name}_motion.png"}
            if rc == 130 and names:
                line(f"#9   files after Ctrl-C ({fmt}, {delay} s)", "-", f"BAD: left {names}")
            elif rc == 0 and set(names) != whole:
                line(f"#9   files after a finished export ({fmt})", "-", f"BAD: {names}")
    # API numbers
    for arg, values in (("rate_hz", ["'100'", "None", "True", "[1]", "float('nan')",
                                     "float('inf')", "-1", "0"]),
                        ("step_s", ["'x'", "float('nan')", "-0.05", "0"]),
                        ("tool_speed", ["'x'", "float('inf')", "-1"])):
        for v in values:
            run(f"#11 ss.export({arg}={v})",
                [], code=("import surestep_ocp as ss\nfrom surestep_ocp.errors import "
                          "SurestepError\ntry:\n    ss.export(%r, 'csv', %r, %s=%s)\n"
                          "except SurestepError as e:\n    print('SurestepError:', e)\n"
                          "else:\n    print('accepted')" % (str(sol), str(w / "api.csv"), arg,
                                                             v)),
                check=lambda o, e: None if o.startswith("SurestepError") and len(
                    o.strip().splitlines()) == 1 else "accepted or not one line")


def cli_attempts(w: Path) -> None:
    inp = write_problem(w / "p.yaml", PACE, lambda t: None)
    before = sha(inp)
    run("#10 solve -o ''", [CLI, "solve", str(inp), "--method", "baseline", "-o", ""],
        expect=(2,), cwd=w)
    run("new: solve -o the problem file itself", [CLI, "solve", str(inp), "--method",
                                                  "baseline", "-o", str(inp)], expect=(2,),
        check=lambda o, e: "the problem was overwritten" if sha(inp) != before else None)
    spec = ROOT / "problems" / "evaluations" / "evaluation.yaml"
    for m in ("", ",", "baseline,", " "):
        run(f"#10 evaluate --methods {m!r}", [CLI, "evaluate", str(spec), "--methods", m,
                                             "--output-dir", str(w / "ev"), "--quiet"],
            expect=(2,), cwd=w)
    run("#10 compare --methods ''", [CLI, "compare", str(inp), "--methods", "",
                                     "--output-dir", str(w / "c1")], expect=(2,), cwd=w)
    run("new: compare --output-dir a file", [CLI, "compare", str(inp), "--methods", "baseline",
                                             "--output-dir", str(inp)], expect=(2,),
        check=lambda o, e: "the problem was overwritten" if sha(inp) != before else None)
    run("new: compare --output-dir the problem's folder", [CLI, "compare", str(inp), "--methods",
                                                           "baseline", "--output-dir", str(w)],
        expect=(0, 2), check=lambda o, e: "the problem was overwritten" if sha(inp) != before
        else None)
    for delay in (0.3, 1.0, 2.0):
        out = w / f"int_solve_{delay}.json"
        rc, _, _ = run(f"Ctrl-C during solve after {delay} s", [CLI, "solve", str(DEFAULT),
                                                               "--method", "ocp", "-o", str(out)],
                       expect=(0, 130), interrupt_after=delay)
        if rc == 130 and out.exists():
            line("  a solution after Ctrl-C", "-", "BAD: written")
        out = w / f"int_cmp_{delay}"
        rc, _, _ = run(f"Ctrl-C during compare after {delay} s",
                       [CLI, "compare", str(PACE), "--output-dir", str(out)],
                       expect=(0, 130), interrupt_after=delay * 3)
        if rc == 130 and out.exists() and any(out.iterdir()):
            line("  the comparison folder after Ctrl-C", "-",
                 f"BAD: left {sorted(p.name for p in out.iterdir())[:4]}")
    # #12: a start joint exactly at its limit (limits enforced): no RuntimeWarnings
    lims = [(-1.588, 1.588), (-0.925025, 0.925025), (0.0, 0.24), (-4.53786, 4.53786),
            (-1.39626, 1.39626), (-1.39626, 1.39626)]
    for j in (1, 2, 4, 5):
        for side in (0, 1):
            def edit(t, j=j, side=side):
                t["start"]["joints"][j] = lims[j][side]
            p = write_problem(w / f"atlim_{j}_{side}.yaml", DEFAULT, edit)
            run(f"#12 start joint {j} at its {'lower' if side == 0 else 'upper'} limit, ocp",
                [CLI, "solve", str(p), "--method", "ocp", "-o", str(w / f"atlim_{j}_{side}.json")],
                expect=(0, 1, 2), cwd=w)


PLANNER = """
import math, numpy as np, surestep_ocp as ss
from surestep_ocp.errors import SurestepError
problem = ss.load_problem(%r).with_horizon(10)
planner = ss.Planner(problem)
tracker = ss.SimulatedTracker(planner.setup.eval_model, planner.plan.poses[0], rng=0)
mean, _ = tracker.move_to(planner.plan.poses[1])
%s
try:
    out = %s
except SurestepError as e:
    print('SurestepError:', e)
else:
    print('accepted', getattr(out, 'status', out))
"""


def planner_attempts(w: Path) -> None:
    for v in ("float('nan')", "float('inf')", "'3'", "-1", "2.5", "True", "None", "10**30"):
        run(f"#11 Planner(replan_iterations={v})", [], code=(
            "import surestep_ocp as ss\nfrom surestep_ocp.errors import SurestepError\n"
            f"p = ss.load_problem({str(PACE)!r})\ntry:\n    ss.Planner(p, replan_iterations={v})\n"
            "except SurestepError as e:\n    print('SurestepError:', e)\nelse:\n"
            "    print('accepted')"), check=_refused if v != "10**30" else None)
    cov = "np.eye(6) * 1e-4"
    cases = {
        "mean NaN": ("m = mean.copy(); m[0] = math.nan", f"planner.replan(m, {cov}, step=1)"),
        "mean of 5": ("", f"planner.replan(mean[:5], {cov}, step=1)"),
        "mean a string": ("", f"planner.replan('abc', {cov}, step=1)"),
        "covariance not symmetric": ("c = np.eye(6); c[0, 1] = 1",
                                     "planner.replan(mean, c, step=1)"),
        "covariance indefinite": ("", "planner.replan(mean, -np.eye(6), step=1)"),
        "covariance inf": ("c = np.eye(6); c[0, 0] = math.inf", "planner.replan(mean, c, step=1)"),
        "covariance 1e-30 I": ("", "planner.replan(mean, np.eye(6) * 1e-30, step=1)"),
        "covariance 1e6 I": ("", "planner.replan(mean, np.eye(6) * 1e6, step=1)"),
        "step -1": ("", f"planner.replan(mean, {cov}, step=-1)"),
        "step beyond the horizon": ("", f"planner.replan(mean, {cov}, step=99)"),
        "step 2.5": ("", f"planner.replan(mean, {cov}, step=2.5)"),
        "step True": ("", f"planner.replan(mean, {cov}, step=True)"),
        "camera_pose not rigid": ("", f"planner.replan(mean, {cov}, camera_pose=np.ones((4, 4)), "
                                      "step=1)"),
        "camera_pose NaN": ("", f"planner.replan(mean, {cov}, camera_pose=np.full((4, 4), "
                                "math.nan), step=1)"),
    }
    for name, (pre, call) in cases.items():
        ok_ranges = ("covariance 1e-30 I", "covariance 1e6 I")
        run(f"new: Planner.replan, {name}", [], code=PLANNER % (str(PACE), pre, call),
            check=None if name in ok_ranges else _refused)


def _refused(out: str, err: str) -> str | None:
    lines = out.strip().splitlines()
    return None if lines and lines[-1].startswith("SurestepError") else "accepted: " + _last(out)


SECTIONS = {"cache": cache_attempts, "noise": noise_attempts, "export": export_attempts,
            "cli": cli_attempts, "planner": planner_attempts}


def main() -> None:
    global ONLY
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="run the attempts whose name holds this")
    ap.add_argument("--work", default=None, help="work folder (default: a new temporary one)")
    ap.add_argument("--output", help="also write the table (markdown) here")
    ap.add_argument("--sections", nargs="*", default=list(SECTIONS), choices=list(SECTIONS))
    args = ap.parse_args()
    ONLY = args.only
    work = Path(args.work or tempfile.mkdtemp(prefix="hostile_round_"))
    print(f"# work folder {work}; what | exit | outcome", flush=True)
    for name in args.sections:
        attempts = SECTIONS[name]
        sub = work / name
        sub.mkdir(parents=True, exist_ok=True)
        attempts(sub)
    bad = [r for r in rows if r[2].startswith("BAD")]
    summary = f"hostile_round: attempts={len(rows)} bad={len(bad)}"
    if args.output:
        table = "\n".join(f"| {w.replace(chr(10), ' ')} | {c} | {o} |" for w, c, o in rows)
        text = (f"`{' '.join(['.venv/bin/python', 'benchmarks/hostile_round.py', *sys.argv[1:]])}`"
                f"\n\n{summary}\n\n| attempt | exit | outcome |\n|---|---|---|\n{table}\n")
        tmp = Path(args.output).with_suffix(".part")
        tmp.write_text(text)
        tmp.replace(args.output)
    print(summary, flush=True)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
