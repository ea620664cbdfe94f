"""The compile cache (issue 29 item 4): where it is (XDG), its compile notes with an estimate, its
size bound (least recently used first), and `surestep cache --info/--clear/--prune`."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import pytest

from surestep_ocp.cli import main
from surestep_ocp.ocp import codegen

REPO = Path(__file__).resolve().parents[1]
needs_cc = pytest.mark.skipif(not codegen.available(), reason="no C compiler on this machine")


@pytest.fixture()
def cache_env(monkeypatch, tmp_path):
    for name in ("SURESTEP_CACHE", "XDG_CACHE_HOME", "SURESTEP_CACHE_MAX_MB"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    return tmp_path


def test_the_folder_follows_xdg_and_the_override(cache_env, monkeypatch):
    assert codegen.cache_dir() == cache_env / "home" / ".cache" / "surestep_ocp"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache_env / "xdg"))
    assert codegen.cache_dir() == cache_env / "xdg" / "surestep_ocp"
    # the XDG specification: relative paths are ignored
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")
    assert codegen.cache_dir() == cache_env / "home" / ".cache" / "surestep_ocp"
    monkeypatch.setenv("SURESTEP_CACHE", str(cache_env / "mine"))
    assert codegen.cache_dir() == cache_env / "mine"


def test_the_bound(cache_env, monkeypatch):
    assert codegen.max_bytes() == codegen.DEFAULT_MAX_MB * 10**6
    monkeypatch.setenv("SURESTEP_CACHE_MAX_MB", "0")
    assert codegen.max_bytes() is None
    monkeypatch.setenv("SURESTEP_CACHE_MAX_MB", "2.5")
    assert codegen.max_bytes() == 2_500_000
    monkeypatch.setenv("SURESTEP_CACHE_MAX_MB", "lots")
    with pytest.raises(codegen.SurestepError, match="SURESTEP_CACHE_MAX_MB"):
        codegen.max_bytes()


def _fake_library(folder: Path, name: str, size: int, age_s: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    lib = folder / f"{name}_0123456789abcdef0123.so"
    lib.write_bytes(b"x" * size)
    check = lib.with_name(lib.name + ".sha256")
    check.write_text("0" * 64 + "\n")
    t = time.time() - age_s
    os.utime(lib, (t, t))
    os.utime(check, (t, t))
    return lib


def test_prune_removes_the_least_recently_used_first(tmp_path):
    folder = tmp_path / "c"
    libs = {n: _fake_library(folder, n, 1000, age)
            for n, age in (("old", 300), ("mid", 200), ("new", 100))}
    # "old" loaded just now: the most recent use
    os.utime(libs["old"].with_name(libs["old"].name + ".sha256"))
    (folder / "unrelated.txt").write_text("not the cache's")
    removed = codegen.prune(2 * 1065 + 10, folder)  # room for two libraries with their checksums
    assert [e.lib.name for e in removed] == [libs["mid"].name]
    assert (not libs["mid"].exists()
            and not libs["mid"].with_name(libs["mid"].name + ".sha256").exists())
    assert libs["old"].exists() and libs["new"].exists()
    assert codegen.prune(None, folder) == []
    assert codegen.clear(folder) > 2000
    # only the cache's own files are removed
    assert [p.name for p in folder.iterdir()] == ["unrelated.txt"]


@needs_cc
def test_a_compile_is_announced_with_an_estimate_and_timed(cache_env, monkeypatch, capsys):
    monkeypatch.setenv("SURESTEP_CACHE", str(cache_env / "c"))
    x = ca.SX.sym("x", 3)
    fns = [ca.Function(f"cache_probe_{i}", [x], [ca.sin(x) * (i + 1)]) for i in range(3)]
    done = codegen.compiled_all(fns)
    assert [fresh for _, fresh in done] == [True] * 3
    for i, (f, _) in enumerate(done):
        assert float(f([1, 2, 3])[1]) == pytest.approx((i + 1) * __import__("math").sin(2))
    err = [ln for ln in capsys.readouterr().err.splitlines()
           if ln.startswith("note: solver.codegen:")]
    assert len(err) == 2, err
    assert ("compiling 3 functions" in err[0]
            and "cache_probe_0, cache_probe_1, cache_probe_2; inputs 3x1" in err[0])
    assert "about" in err[0]
    assert "a first guess" in err[0] and str(cache_env / "c") in err[0]
    assert err[1].startswith("note: solver.codegen: compiling took")
    record = json.loads((cache_env / "c" / codegen.TIMING_FILE).read_text())
    assert record["s_per_mb"] > 0
    # the next compile's estimate is this cache's measured rate; a cached load says nothing
    assert codegen.compiled_all(fns[:1])[0][1] is False and capsys.readouterr().err == ""
    codegen.compiled(ca.Function("cache_probe_new", [x], [ca.cos(x)]))
    assert "measured here before" in capsys.readouterr().err


@needs_cc
def test_a_compile_keeps_the_cache_within_its_bound(cache_env, monkeypatch):
    folder = cache_env / "c"
    monkeypatch.setenv("SURESTEP_CACHE", str(folder))
    stale = _fake_library(folder, "stale", 50_000, 3600)
    # 40 kB: the fake library must go, the new one stays
    monkeypatch.setenv("SURESTEP_CACHE_MAX_MB", "0.04")
    x = ca.SX.sym("x", 2)
    f, fresh = codegen.compiled(ca.Function("cache_bound_probe", [x], [x * 2]))
    assert fresh and not stale.exists() and [e.lib.name for e in codegen.entries(folder)] == [
        p.name for p in folder.glob("cache_bound_probe_*.so")]


def test_the_cache_command(cache_env, monkeypatch, capsys):
    folder = cache_env / "xdg" / "surestep_ocp"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache_env / "xdg"))
    for n, age in (("a", 300), ("b", 200), ("c", 100)):
        _fake_library(folder, n, 400_000, age)
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert (str(folder) in out and "$XDG_CACHE_HOME/surestep_ocp" in out
            and "libraries   3 (1.2 MB" in out)
    assert "surestep cache --clear" in out
    assert main(["cache", "--prune", "--max-mb", "0.9"]) == 0
    assert "pruned      1 libraries" in capsys.readouterr().out
    assert sorted(p.name.split("_")[0] for p in folder.glob("*.so")) == ["b", "c"]
    assert main(["cache", "--clear"]) == 0
    assert "cleared" in capsys.readouterr().out and not list(folder.iterdir())
    assert main(["cache", "--max-mb", "3"]) == 2  # --max-mb without --prune
    assert "--max-mb applies to --prune only" in capsys.readouterr().err


def test_the_cache_command_runs_as_a_program(cache_env):
    env = {**os.environ, "SURESTEP_CACHE": str(cache_env / "empty")}
    res = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "cache", "--info"],
                         capture_output=True, text=True, cwd=REPO, env=env, timeout=120,
                         check=False)
    assert (res.returncode == 0 and "not created yet" in res.stdout
            and "$SURESTEP_CACHE" in res.stdout), res.stderr


# ------------------------------------------------------------ a checksum rewritten with the library
# (issue 30): the checksum beside a library proves only that the two were written together. Each
# case runs in its own process: a library cut short kills its loader with SIGBUS, and a library once
# loaded stays loaded in that process under its path.
_TAMPER_SCRIPT = """
import json, sys
import casadi as ca
from surestep_ocp.ocp import codegen

def probe(n, k):  # one function name, as a horizon's functions share theirs: n inputs, constant k
    x = ca.SX.sym("x", n)
    return ca.Function("tamper_probe", [x], [ca.sin(x) * x * k])

mode = sys.argv[1]
if mode == "build":
    libs = {}
    for case, (n, k) in {"own": (3, 2.0), "horizon": (4, 2.0), "constant": (3, 2.5)}.items():
        before = set(codegen.cache_dir().glob("tamper_probe_*.so"))
        codegen.compiled(probe(n, k))
        (libs[case],) = map(str, set(codegen.cache_dir().glob("tamper_probe_*.so")) - before)
    print(json.dumps(libs))
else:
    fn = probe(3, 2.0)
    if mode == "deferred":
        f, fresh = codegen.Deferred({"f": fn}, required=True).result()[0]["f"], None
    else:
        f, fresh = codegen.compiled(fn)
    print(json.dumps({"fresh": fresh, "value": list(map(float, f([1, 2, 3]).nonzeros()))}))
"""


def _tamper_run(cache: Path, *args: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    env = {**os.environ, "SURESTEP_CACHE": str(cache)}
    res = subprocess.run([sys.executable, "-c", _TAMPER_SCRIPT, *args], capture_output=True,
                         text=True, env=env, cwd=REPO, timeout=300, check=False)
    return res, [ln for ln in res.stderr.splitlines() if "was not loaded" in ln]


def _replace_with_checksum(lib: Path, data: bytes) -> None:
    """`lib`'s bytes replaced and its checksum file rewritten to match them (hashlib, not the
    cache's code)."""
    import hashlib

    lib.write_bytes(data)
    lib.with_name(lib.name + ".sha256").write_text(hashlib.sha256(data).hexdigest() + "\n")


@pytest.fixture(scope="module")
def tamper_libs(tmp_path_factory) -> tuple[Path, dict[str, bytes]]:
    """A cache holding the probe's library, and the bytes of the three probes' libraries."""
    cache = tmp_path_factory.mktemp("tamper")
    res, _ = _tamper_run(cache, "build")
    assert res.returncode == 0, res.stderr[-2000:]
    libs = {case: Path(p) for case, p in json.loads(res.stdout).items()}
    assert len(set(libs.values())) == 3  # three structures or constants: three names
    return libs["own"], {case: p.read_bytes() for case, p in libs.items()}


@needs_cc
@pytest.mark.parametrize("tamper, words", [
    ("half", "cut short"), ("most", "cut short"), ("header", "cut short"),
    ("horizon", "input 0 is 4x1"), ("constant", "other values")])
@pytest.mark.parametrize("mode", ["compiled", "deferred"])
def test_a_library_with_a_rewritten_checksum_is_checked_and_rebuilt(tamper_libs, tmp_path, tamper,
                                                                   words, mode):
    """Cut short (the load died of SIGBUS), or another horizon's or other constants' library under
    the name (an internal error, or other values used as the function's): each said once, rebuilt,
    the right values."""
    import math

    own, data = tamper_libs
    cache = tmp_path / "cache"
    shutil.copytree(own.parent, cache)
    lib = cache / own.name
    good = data["own"]
    bad = {"half": good[: len(good) // 2], "most": good[: len(good) * 9 // 10], "header": good[:64],
           "horizon": data["horizon"], "constant": data["constant"]}[tamper]
    _replace_with_checksum(lib, bad)
    res, notes = _tamper_run(cache, mode)
    assert res.returncode == 0, (res.returncode, res.stderr[-2000:])  # -7: SIGBUS
    out = json.loads(res.stdout)
    assert out["value"] == pytest.approx([2.0 * math.sin(v) * v for v in (1, 2, 3)], rel=1e-12)
    assert len(notes) == 1 and lib.name in notes[0] and words in notes[0], res.stderr
    assert lib.read_bytes() == good  # rebuilt: the same bytes as the first build
    res, notes = _tamper_run(cache, mode)  # and then loaded as it is, without a note
    assert res.returncode == 0 and notes == [] and "compiling" not in res.stderr, res.stderr


def test_the_elf_check_reads_the_headers(tmp_path):
    """`elf_problem` on a real library (whole), and on it cut at every 1/16 of its length."""
    lib = Path(ca.__file__).parent / "libcasadi.so"
    if not lib.is_file():
        lib = next(Path(ca.__file__).parent.glob("*.so*"))
    data = lib.read_bytes()
    whole = tmp_path / "whole.so"
    whole.write_bytes(data)
    assert codegen.elf_problem(whole) is None
    for k in range(16):
        cut = tmp_path / f"cut{k}.so"
        cut.write_bytes(data[: len(data) * k // 16])
        assert codegen.elf_problem(cut) is not None, k


@needs_cc
def test_the_fast_flags_build_their_own_library_with_the_same_values(cache_env, monkeypatch):
    """A function named in `fast` (`vectorised`) is compiled with FAST_FLAGS (VECTOR_FLAGS) into a
    library of its own (the flags are part of the cache key), and gives bitwise the values of the
    FLAGS build."""
    monkeypatch.setenv("SURESTEP_CACHE", str(cache_env / "c"))
    x = ca.SX.sym("x", 4)
    fn = ca.Function("cache_probe_fast", [x], [ca.sin(x) * ca.sqrt(ca.sumsqr(x)) + x[0] / x])
    plain, _ = codegen.compiled_or_interpreted({"f": fn}, True)
    fast, _ = codegen.compiled_or_interpreted({"f": fn}, True, fast=("f",))
    vector, _ = codegen.compiled_or_interpreted({"f": fn}, True, vectorised=("f",))
    builds = 3 if codegen.VECTOR_FLAGS != codegen.FLAGS else 2
    assert len(list((cache_env / "c").glob("cache_probe_fast_*.so"))) == builds
    arg = [0.3, -1.7, 2.9, 1e-3]
    assert (plain["f"](arg).full() == fast["f"](arg).full()).all()
    assert (plain["f"](arg).full() == vector["f"](arg).full()).all()
    assert abs(fast["f"](arg).full() - fn(arg).full()).max() <= 1e-14


def test_vector_instructions_only_where_the_cpu_has_them():
    """AVX2 (without fused multiply-adds) is asked for only on an x86-64 CPU whose flags list it."""
    avx2 = "processor\t: 0\nflags\t\t: fpu sse2 avx avx2 fma\n"
    assert codegen._vector_flags(avx2, "x86_64") == ("-mavx2", "-ffp-contract=off")
    assert codegen._vector_flags("flags\t\t: fpu sse2 avx\n", "x86_64") == ()
    assert codegen._vector_flags("flags\t\t: fpu sse2 avx2x\n", "x86_64") == ()
    assert codegen._vector_flags(avx2, "aarch64") == ()
    assert codegen._vector_flags("", "x86_64") == ()


# ------------------------------------------------------------ a hostile disk (issue 48)
def _probe_fn(k: float = 3.0) -> ca.Function:
    x = ca.SX.sym("x", 2)
    return ca.Function("hostile_probe", [x], [ca.cos(x) * k])


@needs_cc
@pytest.mark.parametrize("where", ["a file", "/dev/null", "under a file"])
def test_a_cache_that_cannot_be_written_falls_back_with_one_note(cache_env, monkeypatch, capsys,
                                                                 where):
    """`SURESTEP_CACHE` naming a file, /dev/null or a path under a file: `codegen: auto` gets the
    interpreted functions and a note (the cleanup of the partial file raised NotADirectoryError
    before); a second compile in the process does not try that folder again; `codegen: true`
    keeps the error, one line."""
    plain = cache_env / "plain"
    plain.write_text("not a folder")
    folder = {"a file": plain, "/dev/null": Path("/dev/null"), "under a file": plain / "c"}[where]
    monkeypatch.setenv("SURESTEP_CACHE", str(folder))
    monkeypatch.setattr(codegen, "_UNWRITABLE", {})
    fns = {"f": _probe_fn()}
    got, note = codegen.compiled_or_interpreted(fns, required=False)
    assert got == fns and note.startswith("interpreted: solver.codegen: cannot write")
    capsys.readouterr()
    got, again = codegen.compiled_or_interpreted({"f": _probe_fn(4.0)}, required=False)
    assert again == note and "compiling" not in capsys.readouterr().err
    with pytest.raises(codegen.SurestepError, match="SURESTEP_CACHE to a writable directory"):
        codegen.compiled_or_interpreted(fns, required=True)
    assert plain.read_text() == "not a folder"


def test_cache_reads_are_of_regular_files_within_a_bound(tmp_path):
    """A FIFO (no writer: a blocking read never returns), a link to /dev/zero (endless) and a file
    over the bound are refused at once; a regular file is read."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    zero = tmp_path / "zero"
    zero.symlink_to("/dev/zero")
    big = tmp_path / "big"
    big.write_bytes(b"x" * 101)
    for path, why in ((fifo, "not a regular file"), (zero, "not a regular file"),
                      (big, "larger than 100 bytes")):
        with pytest.raises(OSError, match=why):
            codegen.read_cache_file(path, 100)
    assert codegen.read_cache_file(big, 101) == b"x" * 101


_HOSTILE_SCRIPT = """
import sys
import casadi as ca
from surestep_ocp.ocp import codegen
x = ca.SX.sym("x", 2)
f, fresh = codegen.compiled(ca.Function("hostile_probe", [x], [ca.cos(x) * 3.0]))
print(fresh, list(map(float, f([1, 2]).nonzeros())))
"""


@needs_cc
def test_fifos_and_devices_in_the_cache_never_hang(cache_env):
    """A FIFO `timing.json`, a FIFO with the library's name and its checksum a link to /dev/zero:
    `cache` and a compile return (they hung forever / read until memory ran out); the library is
    rebuilt over the FIFO, said on stderr. (In a subprocess, so that a regression is a timeout.)"""
    folder = cache_env / "c"
    env = {**os.environ, "SURESTEP_CACHE": str(folder)}
    first = subprocess.run([sys.executable, "-c", _HOSTILE_SCRIPT], capture_output=True, text=True,
                           env=env, timeout=300, check=True)
    (lib,) = folder.glob("hostile_probe_*.so")
    lib.unlink()
    os.mkfifo(lib)
    check = lib.with_name(lib.name + ".sha256")
    check.unlink()
    check.symlink_to("/dev/zero")
    (folder / "timing.json").unlink()
    os.mkfifo(folder / "timing.json")
    info = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "cache"], capture_output=True,
                          text=True, env=env, timeout=120, check=False)
    assert info.returncode == 0 and "first guess" in info.stdout, info.stderr
    again = subprocess.run([sys.executable, "-c", _HOSTILE_SCRIPT], capture_output=True,
                           text=True, env=env, timeout=300, check=False)
    assert again.returncode == 0, again.stderr
    assert again.stdout.split(" ", 1)[1] == first.stdout.split(" ", 1)[1]
    assert "was not loaded: its checksum cannot be read (not a regular file)" in again.stderr
    assert lib.is_file() and not check.is_symlink()


def test_clear_and_prune_touch_only_the_caches_own_files(cache_env, monkeypatch, capsys):
    """`--clear` removed any *.so or *.part (a user's mylib.so, a download.part); now only the
    cache's naming scheme is touched. A compile killed midway leaves partial writes of a process
    that is gone: `cache` counts them, `--prune` and `--clear` remove them, a live one is left."""
    folder = cache_env / "mine"
    monkeypatch.setenv("SURESTEP_CACHE", str(folder))
    lib = _fake_library(folder, "newton_step", 1000, 100)
    gone = 2**31 - 1  # above any pid_max: no such process
    orphans = [folder / f"{lib.name}.{gone}.140539578177216.part",
               folder / f"{lib.name}.sha256.{gone}.7.part", folder / f"timing.json.{gone}.part"]
    live = folder / f"{lib.name}.{os.getpid()}.1.part"
    others = [folder / "mylib.so", folder / "download.part", folder / "notes.txt",
              folder / "x.so.sha256"]
    for p in orphans + [live] + others:
        p.write_bytes(b"y" * 10)
    assert main(["cache"]) == 0
    assert "partial     3 orphaned partial writes" in capsys.readouterr().out
    assert main(["cache", "--prune", "--max-mb", "0"]) == 0
    assert not any(p.exists() for p in orphans) and lib.exists() and live.exists()
    assert main(["cache", "--clear"]) == 0
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in others + [live])


@pytest.mark.parametrize("value", ["inf", "nan", "-1", "lots", "1e400"])
def test_the_bound_is_a_finite_number(cache_env, monkeypatch, capsys, value):
    """`SURESTEP_CACHE_MAX_MB=inf` and `--max-mb inf` were `internal error: OverflowError`; now
    every non-finite or negative bound is one line naming the setting, exit 2."""
    assert main(["cache", "--prune", "--max-mb", value]) == 2
    assert "--max-mb must be a finite number of megabytes >= 0" in capsys.readouterr().err
    monkeypatch.setenv("SURESTEP_CACHE_MAX_MB", value)
    assert main(["cache", "--prune"]) == 2
    assert "SURESTEP_CACHE_MAX_MB must be a finite number" in capsys.readouterr().err
    # a solve's compile: the user's error (exit 2), not a fall-back to interpreted code
    with pytest.raises(codegen.SurestepError, match="SURESTEP_CACHE_MAX_MB must be a finite"):
        codegen.compiled_or_interpreted({"f": _probe_fn()}, required=False)
