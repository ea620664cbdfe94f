"""CasADi code generation: a Function as C, compiled once into a shared library, cached by content.

The cache directory is `$SURESTEP_CACHE`, else `~/.cache/surestep_ocp`. A library's name
carries a hash of its C source, the compiler flags and the CasADi version, so a change in
the problem's structure (robot, horizon, noise constants) compiles anew and an unchanged
one is loaded in milliseconds. Libraries are written to a temporary name and renamed, so
concurrent processes never load a half-written file.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

from .errors import SurestepError

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


def compiled(fn: ca.Function) -> tuple[ca.Function, bool]:
    """`fn` compiled to C (same name, inputs and outputs); and whether it was compiled now (not cached)."""
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
        if fresh:
            part = lib.with_name(f"{lib.name}.{os.getpid()}.part")
            try:
                lib.parent.mkdir(parents=True, exist_ok=True)
                run = subprocess.run([cc, *FLAGS, str(source), "-o", str(part)], capture_output=True, text=True,
                                     check=False)
                if run.returncode != 0:
                    part.unlink(missing_ok=True)
                    raise SurestepError(f"solver.codegen: {cc} failed on the generated code:\n{run.stderr[-2000:]}")
                os.replace(part, lib)
            except OSError as exc:
                raise SurestepError(f"solver.codegen: cannot write the compiled code to {lib.parent} ({exc}); "
                                    "set SURESTEP_CACHE to a writable directory, or codegen: false") from None
    return ca.external(name, str(lib)), fresh
