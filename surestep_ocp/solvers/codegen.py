"""CasADi code generation: a Function as C, compiled once into a shared library, cached by content.

The cache directory is `$SURESTEP_CACHE`, else `~/.cache/surestep_ocp`. A library's name
carries a hash of its C source, the compiler flags and the CasADi version, so a change in
the problem's structure (robot, horizon, noise constants) compiles anew and an unchanged
one is loaded in milliseconds. Libraries are written to a temporary name and renamed, so
concurrent processes never load a half-written file, and each is loaded only after its SHA-256
matches the checksum stored beside it (`<lib>.so.sha256`); a corrupt or truncated one is rebuilt.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca

from ..errors import SurestepError

FLAGS = ("-O1", "-fPIC", "-shared")  # measured on the T = 20 Hessian: -O1 5x faster than the VM, -O0 2x


def cache_dir() -> Path:
    return Path(os.environ.get("SURESTEP_CACHE") or Path.home() / ".cache" / "surestep_ocp")


def compiler() -> str:
    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        raise SurestepError("solver.codegen: no C compiler found (install gcc or set CC), or set codegen: false")
    return cc


def available() -> bool:
    """Whether a C compiler is found (`$CC`, else gcc)."""
    return shutil.which(os.environ.get("CC", "gcc")) is not None


def compiled_or_interpreted(fns: dict[str, ca.Function], required: bool) -> tuple[dict[str, ca.Function], str | None]:
    """`fns` compiled; if compiling fails and it is not `required` (`solver.codegen: auto`), the interpreted
    ones and a note saying why (`solver.codegen: true` keeps the error)."""
    try:
        return {k: compiled(fn)[0] for k, fn in fns.items()}, None
    except SurestepError as exc:
        if required:
            raise
        return fns, f"interpreted: {exc}"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _checksum_file(lib: Path) -> Path:
    return lib.with_name(lib.name + ".sha256")


def verified(lib: Path) -> str | None:
    """None if the cached library `lib` matches the SHA-256 stored beside it, else why not."""
    try:
        stored = _checksum_file(lib).read_text().strip()
    except FileNotFoundError:
        return "it has no checksum beside it"
    except (OSError, UnicodeDecodeError) as exc:
        return f"its checksum cannot be read ({exc})"
    try:
        actual = _digest(lib)
    except OSError as exc:
        return f"it cannot be read ({exc.strerror or exc})"
    return None if actual == stored else "its content does not match its checksum (corrupt or truncated)"


_ANNOUNCED = False  # the compile note is said once per process


def _note(text: str) -> None:
    print(f"note: solver.codegen: {text}", file=sys.stderr, flush=True)


def compiled(fn: ca.Function) -> tuple[ca.Function, bool]:
    """`fn` compiled to C (same name, inputs and outputs); and whether it was compiled now (not cached).

    A cached library is loaded only when its SHA-256 matches the checksum file written beside it when
    it was built (`<lib>.so.sha256`); otherwise it is rebuilt, with a note on stderr (a truncated shared
    library loaded as such kills the process with SIGBUS).
    """
    cc = compiler()
    name = fn.name()
    with tempfile.TemporaryDirectory() as tmp:
        gen = ca.CodeGenerator(f"{name}.c")
        gen.add(fn)
        gen.generate(tmp + os.sep)
        source = Path(tmp, f"{name}.c")
        key = hashlib.sha256(source.read_bytes() + " ".join(FLAGS).encode() + ca.__version__.encode()).hexdigest()
        lib = cache_dir() / f"{name}_{key[:20]}.so"
        fresh = not lib.exists()
        if not fresh:
            problem = verified(lib)
            if problem is not None:  # (no checksum: built by an older version; rebuilt without a note)
                if not problem.startswith("it has no checksum"):
                    _note(f"the cached {lib.name} was not loaded: {problem}; rebuilding it")
                fresh = True
        if fresh:
            global _ANNOUNCED
            if not _ANNOUNCED:  # long work made visible: seconds per structure, minutes on a loaded machine
                _note(f"compiling derivatives to C (a new problem structure or horizon; cached in {lib.parent})")
                _ANNOUNCED = True
            _build(cc, source, lib)
    try:
        return ca.external(name, str(lib)), fresh
    except RuntimeError as exc:
        raise SurestepError(f"solver.codegen: cannot load the compiled {lib} ({str(exc).strip().splitlines()[-1]})"
                            ) from None


def _build(cc: str, source: Path, lib: Path) -> None:
    """Compile `source` into `lib` with its checksum beside it (both written to temporary names, then renamed;
    compiled in the source's folder by relative name, so the library's bytes do not depend on the temp path)."""
    part = lib.with_name(f"{lib.name}.{os.getpid()}.part")
    check = _checksum_file(lib)
    check_part = check.with_name(f"{check.name}.{os.getpid()}.part")
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        run = subprocess.run([cc, *FLAGS, source.name, "-o", str(part.resolve())], capture_output=True, text=True,
                             check=False, cwd=source.parent)
        if run.returncode != 0:
            part.unlink(missing_ok=True)
            raise SurestepError(f"solver.codegen: {cc} failed on the generated code: "
                                f"{' '.join(run.stderr.split())[-300:]}")
        check_part.write_text(_digest(part) + "\n")
        os.replace(check_part, check)
        os.replace(part, lib)
    except OSError as exc:
        part.unlink(missing_ok=True)
        check_part.unlink(missing_ok=True)
        raise SurestepError(f"solver.codegen: cannot write the compiled code to {lib.parent} ({exc.strerror or exc}); "
                            "set SURESTEP_CACHE to a writable directory, or codegen: false") from None
