"""CasADi code generation: a Function as C, compiled once into a shared library, cached by content.

Where: `$SURESTEP_CACHE` when set, else `$XDG_CACHE_HOME/surestep_ocp` (`~/.cache/surestep_ocp` when
`XDG_CACHE_HOME` is unset or not an absolute path, as the XDG base directory specification says).
`surestep cache --info` shows it, `surestep cache --clear` empties it (docs/cli.md, "The compile
cache").

A library's name carries a hash of its C source, the compiler flags and the CasADi version, so a
change in the problem's structure (robot, horizon, noise constants) compiles anew and an unchanged
one is loaded in milliseconds. Libraries are written to a temporary name and renamed, so concurrent
processes never load a half-written file, and each is loaded only after its SHA-256 matches the
checksum stored beside it (`<lib>.so.sha256`) and its ELF headers say it is whole; once loaded, it
must be the function it replaces (name, input and output sparsity, the same values at one point). A
checksum can be rewritten with the file, so the checks after it do not trust it: a library failing
one is rebuilt, said on stderr.

First use compiles: each batch of functions compiled says so on stderr (what, how much C, an
estimate from the seconds per megabyte of C measured by this cache's previous compiles, kept in
`timing.json`), the functions of a batch are compiled in parallel (one compiler per core), and the
line after says how long it took. The cache is bounded: after a compile, when it holds more than
`$SURESTEP_CACHE_MAX_MB` (default `DEFAULT_MAX_MB`) the least recently used libraries are removed
until it holds at most that (a library's last use is the modification time of its checksum file,
touched at each load).

The cache never stops a solve: a folder that cannot be written (read-only, not a directory, a
device, full) makes `compiled_or_interpreted` fall back to the interpreted functions with one note,
and no later compile in the process tries that folder again. Cache files are read only when they
are regular files and within a size bound (`read_cache_file`: no hang on a FIFO, no endless read of
a link to /dev/zero). The cache's files are those named by its own scheme (`own_file`): libraries
`<function>_<20 hex digits>.so`, their `.sha256`, `timing.json` and the partial writes of these
(`<name>.<pid>[.<thread>].part`); `clear` and `prune` touch nothing else, and remove the partial
writes whose process is gone (a compile killed midway).

Here: the C generation, the compile and the loading. The cache's folder and its files (where, its
bound, its naming scheme, listing, pruning, clearing): `compile_cache.py`; the checks of a
library before and after it is loaded: `library_check.py`.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import casadi as ca

from ..errors import SurestepError
from .compile_cache import (LIBRARY_LIMIT, TIMING_LIMIT, _checksum_file, _unlink_quietly,
                            cache_dir, max_bytes, prune, read_cache_file)
from .library_check import _differs, verified
# (the cache's and the checks' names as they were here: `surestep cache`, the tests)
from .compile_cache import (  # noqa: F401
    CHECKSUM_LIMIT, DEFAULT_MAX_MB, TIMING_FILE, Entry, clear, entries, megabytes, own_file,
    partial_writes, total_bytes)
from .library_check import elf_problem  # noqa: F401


def _vector_flags(cpuinfo: str | None = None, machine: str | None = None) -> tuple[str, ...]:
    """("-mavx2", "-ffp-contract=off") on an x86-64 CPU with AVX2, else (): GCC then vectorises
    the straight-line C of the tool functions; without fused multiply-adds (AVX2 alone has none,
    -ffp-contract=off says so) each result is bitwise the one of the plain build (docs/realtime.md).
    A library built with them is chosen only where the CPU has AVX2 (the flags are in its key)."""
    if (machine or platform.machine()).lower() not in ("x86_64", "amd64"):
        return ()
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
        except OSError:
            return ()
    flags = re.search(r"^flags\s*:(.*)$", cpuinfo, re.MULTILINE)
    return ("-mavx2", "-ffp-contract=off") if flags and "avx2" in flags.group(1).split() else ()


_VECTOR = _vector_flags()
# -O1: faster code than CasADi's virtual machine and -O0 (docs/solve_speed.md, "The compile")
FLAGS = ("-O1", "-fPIC", "-shared")
# the CPU's vector instructions where they keep every result bit (above); for functions a caller
# names (`compiled_or_interpreted`'s `vectorised`: the interior point's end-game curvature, 0.89x
# the time of the -O1 build at the same compile time)
VECTOR_FLAGS = ("-O1", *_VECTOR, "-fPIC", "-shared")
# -O3 with them for small functions evaluated several times an iteration whose compile is short
# (the interior point's tool rows and their Jacobians: about 0.81x and 0.82x the time at -O1,
# bitwise the same values; docs/realtime.md); callers name them (`fast`)
FAST_FLAGS = ("-O3", *_VECTOR, "-fPIC", "-shared")
# options of the per-stage SX Functions the Newton and interior-point iterations map: CasADi's
# structural common-subexpression elimination, which shares repeated nodes (the same values
# bitwise, fewer instructions: the FK's sines and products its derivatives repeat; docs/realtime.md)
SX_OPTIONS = {"cse": True}
# wall-clock seconds per megabyte of generated C at -O1 (the batch's compilers in parallel) before
# this cache has measured its own: a figure within the range measured on the default problem's
# Newton functions (docs/solve_speed.md, "The compile")
PRIOR_S_PER_MB = 5.0
# folders found unwritable in this process -> why (no compile tries them again)
_UNWRITABLE: dict[str, str] = {}


def compiler() -> str:
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        raise SurestepError("solver.codegen: no C compiler found (install gcc or set CC), "
                            "or set codegen: false")
    return cc


def available() -> bool:
    """Whether a C compiler is found (`$CC`, else gcc)."""
    return shutil.which(os.environ.get("CC", "gcc")) is not None


def compiled_or_interpreted(fns: dict[str, ca.Function], required: bool,
                            fast: tuple[str, ...] = (), vectorised: tuple[str, ...] = ()
                            ) -> tuple[dict[str, ca.Function], str | None]:
    """`fns` compiled (those keyed in `fast` with FAST_FLAGS, in `vectorised` with VECTOR_FLAGS);
    if compiling fails and it is not `required` (`solver.codegen: auto`), the interpreted ones and
    a note saying why (`solver.codegen: true` keeps the error). A bad `$SURESTEP_CACHE_MAX_MB` is
    the user's error either way (exit 2), not a reason to fall back."""
    max_bytes()
    try:
        done = compiled_all(list(fns.values()),
                            [FAST_FLAGS if k in fast else VECTOR_FLAGS if k in vectorised
                             else FLAGS for k in fns])
        return {k: f for k, (f, _) in zip(fns, done)}, None
    except (SurestepError, OSError) as exc:  # (OSError: a cache problem not foreseen below)
        if required:
            raise
        return fns, f"interpreted: {_said(exc)}"


def _said(exc: BaseException) -> str:
    """An error's text for the fall-back note (an OSError's as `strerror: file`)."""
    if isinstance(exc, OSError) and not isinstance(exc, SurestepError) and exc.strerror:
        return f"solver.codegen: the compile cache failed ({exc.strerror}: {exc.filename})"
    return str(exc)


_BACKGROUND = ThreadPoolExecutor(max_workers=1, thread_name_prefix="surestep-compile")


class Deferred:
    """Functions compiled in the background: their C is generated now, in the calling thread, and
    only the C compiler runs in a worker thread (no CasADi call off the calling thread); `result()`
    waits for it and loads them, as `compiled_or_interpreted` returns them (the interpreted ones and
    a note if compiling failed and it is not `required`)."""

    def __init__(self, fns: dict[str, ca.Function], required: bool):
        self.fns, self.required, self.future, self.error = fns, required, None, None
        max_bytes()  # (a bad $SURESTEP_CACHE_MAX_MB is the user's error: exit 2, not a fall-back)
        self._tmp = tempfile.TemporaryDirectory()
        try:
            self.cc, self.folder = cc, folder = compiler(), cache_dir()
            self.jobs = [_job(fn, Path(self._tmp.name), folder) for fn in fns.values()]
        except (SurestepError, OSError) as exc:
            self.jobs, self.error = None, exc
            return
        todo = list({j.lib: j for j in self.jobs if j.fresh}.values())
        if todo:
            self.future = _BACKGROUND.submit(_compile, cc, todo, folder,
                                             _what([j.fn for j in todo]))

    def result(self) -> tuple[dict[str, ca.Function], str | None]:
        try:
            if self.error is not None:
                raise self.error
            if self.future is not None:
                self.future.result()
            return dict(zip(self.fns, _load_all(self.jobs, self.cc, self.folder))), None
        except (SurestepError, OSError) as exc:
            if self.required:
                raise
            return self.fns, f"interpreted: {_said(exc)}"
        finally:
            self._tmp.cleanup()


def _digest(path: Path) -> str:
    return hashlib.sha256(read_cache_file(path, LIBRARY_LIMIT)).hexdigest()


def _note(text: str) -> None:
    print(f"note: solver.codegen: {text}", file=sys.stderr, flush=True)


@dataclass
class _Job:
    fn: ca.Function
    source: Path
    lib: Path
    fresh: bool = False
    seconds: float = 0.0
    flags: tuple[str, ...] = FLAGS


def compiled(fn: ca.Function) -> tuple[ca.Function, bool]:
    """`fn` compiled to C (same name, inputs and outputs); and whether it was compiled now (not
    cached).

    A cached library is loaded only when its SHA-256 matches the checksum file written beside it
    when it was built (`<lib>.so.sha256`); otherwise it is rebuilt, with a note on stderr (a
    truncated shared library loaded as such kills the process with SIGBUS).
    """
    return compiled_all([fn])[0]


def compiled_all(fns: list[ca.Function], flags: list[tuple[str, ...]] | None = None
                 ) -> list[tuple[ca.Function, bool]]:
    """Each of `fns` compiled (as `compiled`; each with its `flags`, default FLAGS): the cached
    ones loaded, the others compiled in parallel (one compiler per core), announced on stderr with
    an estimate, then timed; the cache pruned after a compile."""
    max_bytes()  # (a bad $SURESTEP_CACHE_MAX_MB is the user's error: exit 2, not a fall-back)
    cc = compiler()
    folder = cache_dir()
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [_job(fn, Path(tmp), folder, fl)
                for fn, fl in zip(fns, flags or [FLAGS] * len(fns))]
        # (a function given twice: compiled once)
        todo = list({j.lib: j for j in jobs if j.fresh}.values())
        if todo:
            _compile(cc, todo, folder)
        loaded = _load_all(jobs, cc, folder)  # (a failing cached library: rebuilt from tmp)
    return [(f, j.fresh) for f, j in zip(loaded, jobs)]


def _load_all(jobs: list[_Job], cc: str, folder: Path) -> list[ca.Function]:
    """The jobs' libraries loaded, each checked against its function (`_differs`); the cached ones
    that fail are rebuilt (said on stderr) and loaded again, a fresh one that fails is an error."""
    loaded: list[ca.Function | None] = []
    bad: dict[Path, _Job] = {}
    for j in jobs:
        f, problem = (None, None) if j.lib in bad else _checked_load(j)
        if problem is not None:
            if j.fresh:
                raise SurestepError(f"solver.codegen: the compiled {j.lib} {problem}")
            _note(f"the cached {j.lib.name} was not loaded: {problem}; rebuilding it")
            bad[j.lib] = j
        loaded.append(f)
    if bad:  # (no Function of a bad library is left, so it is unloaded before its file is replaced)
        loaded = [None if j.lib in bad else f for f, j in zip(loaded, jobs)]
        for j in jobs:
            j.fresh = j.fresh or j.lib in bad
        _compile(cc, list(bad.values()), folder)
        for k, j in enumerate(jobs):
            if loaded[k] is None:
                f, problem = _checked_load(j)
                if problem is not None:
                    raise SurestepError(f"solver.codegen: the compiled {j.lib} {problem}")
                loaded[k] = f
    return loaded


def _checked_load(job: _Job) -> tuple[ca.Function | None, str | None]:
    """`job`'s library loaded and checked: (the Function, None), or (None, what is wrong)."""
    try:
        f = ca.external(job.fn.name(), str(job.lib))
    except RuntimeError as exc:
        return None, f"cannot be loaded ({str(exc).strip().splitlines()[-1][:300]})"
    problem = _differs(f, job.fn)
    return (f, None) if problem is None else (None, problem)


def _job(fn: ca.Function, tmp: Path, folder: Path, flags: tuple[str, ...] = FLAGS) -> _Job:
    """`fn`'s C source generated in its own folder under `tmp`, its library's name, and whether it
    is to be compiled (absent, or failing its checksum: said on stderr); a cached one's last use
    recorded."""
    name = fn.name()
    where = Path(tempfile.mkdtemp(dir=tmp))
    gen = ca.CodeGenerator(f"{name}.c")
    gen.add(fn)
    gen.generate(str(where) + os.sep)
    source = where / f"{name}.c"
    key = hashlib.sha256(source.read_bytes() + " ".join(flags).encode()
                         + ca.__version__.encode()).hexdigest()
    job = _Job(fn, source, folder / f"{name}_{key[:20]}.so", flags=flags)
    try:
        job.fresh = not job.lib.exists()
    except OSError:  # (e.g. a folder that cannot be searched): compiled, its write then fails
        job.fresh = True
    if not job.fresh:
        problem = verified(job.lib)
        if problem is not None:  # (no checksum: built by an older version; rebuilt without a note)
            if not problem.startswith("it has no checksum"):
                _note(f"the cached {job.lib.name} was not loaded: {problem}; rebuilding it")
            job.fresh = True
        else:
            _touch(_checksum_file(job.lib))  # its last use, for the least-recently-used bound
    return job


def _touch(path: Path) -> None:
    try:
        os.utime(path)
    except OSError:
        pass  # a read-only cache is still usable


def _inputs(fn: ca.Function) -> str:
    return ", ".join(f"{fn.size1_in(i)}x{fn.size2_in(i)}" for i in range(fn.n_in()))


def _what(fns: list[ca.Function]) -> str:
    """The functions' names with their input sizes (said once when they all take the same, as a
    horizon's do)."""
    sizes = {_inputs(f) for f in fns}
    if len(sizes) == 1:
        return f"{', '.join(f.name() for f in fns)}; inputs {sizes.pop()}"
    return ", ".join(f"{f.name()}({_inputs(f)})" for f in fns)


def _compile(cc: str, todo: list[_Job], folder: Path, what: str | None = None) -> None:
    """Compile `todo` (in parallel), announced with an estimate and timed on stderr; the measured
    rate kept for the next estimate; the cache pruned to its bound. A folder found unwritable
    before in this process is not tried again (the same error at once)."""
    _check_writable(folder)
    sizes = [j.source.stat().st_size for j in todo]
    workers = max(1, min(len(todo), os.cpu_count() or 1))
    rate, basis = _rate(folder)
    estimate = sum(sizes) / 1e6 * rate
    what = _what([j.fn for j in todo]) if what is None else what
    _note(f"compiling {len(todo)} function{'s' if len(todo) > 1 else ''} to C ({what}; "
          f"{sum(sizes) / 1e6:.2f} MB of C, {workers} at a time): "
          f"about {_duration(estimate)} ({basis}); "
          f"once per problem structure and horizon, cached in {folder}")
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for _ in pool.map(lambda j: _timed_build(cc, j), todo):
            pass
    took = time.perf_counter() - t0
    measured = took / (sum(sizes) / 1e6)
    _note(f"compiling took {_duration(took)} "
          f"(estimated {_duration(estimate)}; {measured:.1f} s per MB of C)")
    _record_rate(folder, measured, sum(sizes))
    prune(max_bytes())


def _timed_build(cc: str, job: _Job) -> None:
    t = time.perf_counter()
    _build(cc, job.source, job.lib, job.flags)
    job.seconds = time.perf_counter() - t


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds >= 10 else f"{seconds:.1f} s"


def _rate(folder: Path) -> tuple[float, str]:
    """Wall-clock seconds per MB of C: this cache's measurements, else `PRIOR_S_PER_MB`."""
    try:
        record = json.loads(read_cache_file(folder / TIMING_FILE, TIMING_LIMIT))
        rate = float(record["s_per_mb"])
        if rate > 0 and rate < 1e4:
            return rate, f"{rate:.1f} s per MB of C measured here before"
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return PRIOR_S_PER_MB, f"{PRIOR_S_PER_MB:g} s per MB of C, a first guess"


def _record_rate(folder: Path, rate: float, size: int) -> None:
    """Keep the measured rate (the mean with the previous one, weighted by megabytes compiled, the
    old weight capped so that the machine's present speed dominates)."""
    path = folder / TIMING_FILE
    try:
        old = json.loads(read_cache_file(path, TIMING_LIMIT))
        w_old, r_old = min(float(old["mb"]), 2.0), float(old["s_per_mb"])
    except (OSError, ValueError, KeyError, TypeError):
        w_old, r_old = 0.0, 0.0
    w = size / 1e6
    record = {"s_per_mb": (w_old * r_old + w * rate) / (w_old + w), "mb": w_old + w,
              "note": "wall-clock seconds per megabyte of generated C compiled "
                      "(the compile estimate)"}
    part = path.with_name(f"{path.name}.{os.getpid()}.part")
    try:
        part.write_text(json.dumps(record) + "\n")
        os.replace(part, path)
    except OSError:
        _unlink_quietly(part)


def _build(cc: str, source: Path, lib: Path, flags: tuple[str, ...] = FLAGS) -> None:
    """Compile `source` into `lib` with its checksum beside it (both written to temporary names,
    then renamed; compiled in the source's folder by relative name, so the library's bytes do not
    depend on the temp path)."""
    # one writer per name: processes and their compile threads
    tag = f"{os.getpid()}.{threading.get_ident()}"
    part = lib.with_name(f"{lib.name}.{tag}.part")
    check = _checksum_file(lib)
    check_part = check.with_name(f"{check.name}.{tag}.part")
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        run = subprocess.run([cc, *flags, source.name, "-o", str(part.resolve())],
                             capture_output=True, text=True, check=False, cwd=source.parent)
        if run.returncode != 0:
            _unlink_quietly(part)
            unwritable = _unwritable(lib.parent)
            if unwritable:
                raise unwritable
            raise SurestepError(f"solver.codegen: {cc} failed on the generated code: "
                                f"{' '.join(run.stderr.split())[-300:]}")
        check_part.write_text(_digest(part) + "\n")
        os.replace(check_part, check)
        os.replace(part, lib)
    except OSError as exc:
        _unlink_quietly(part)
        _unlink_quietly(check_part)
        raise _cannot_write(lib.parent, exc) from None


def _cannot_write(folder: Path, exc: OSError) -> SurestepError:
    """The error of a cache folder that cannot be written, remembered (`_UNWRITABLE`)."""
    why = "not a directory" if isinstance(exc, FileExistsError) else exc.strerror or str(exc)
    _UNWRITABLE[str(folder)] = text = (
        f"solver.codegen: cannot write the compiled code to {folder} ({why}); set "
        "SURESTEP_CACHE to a writable directory, or codegen: false")
    return SurestepError(text)


def _check_writable(folder: Path) -> None:
    """Before announcing a compile: `folder` created if missing and a file created in it, else
    the error (at once for a folder found unwritable before in this process)."""
    if str(folder) in _UNWRITABLE:
        raise SurestepError(_UNWRITABLE[str(folder)])
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _cannot_write(folder, exc) from None
    problem = _unwritable(folder)
    if problem is not None:
        raise _cannot_write(folder, problem)


def _unwritable(folder: Path) -> OSError | None:
    """Why no file can be created in `folder`, or None (the compiler's failure may be the
    cache's: read-only, not a directory)."""
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".surestep-probe-")
    except OSError as exc:
        return exc
    os.close(fd)
    _unlink_quietly(Path(tmp))
    return None
