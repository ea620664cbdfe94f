"""Checks of a compiled library from the compile cache, before and after it is loaded.

Before: its SHA-256 matches the checksum stored beside it (`verified`) and its ELF headers say
the file is whole (`elf_problem`: a library cut short, mapped as such, kills the process with
SIGBUS). After: the loaded function is the one it replaces (`_differs`: its name, its inputs' and
outputs' sparsity, its values at one point). `codegen.py` rebuilds a library failing any of them.
"""

from __future__ import annotations

import hashlib
import struct
import sys
from pathlib import Path

import casadi as ca
import numpy as np

from .compile_cache import CHECKSUM_LIMIT, LIBRARY_LIMIT, _checksum_file, read_cache_file


def verified(lib: Path) -> str | None:
    """None if the cached library `lib` matches the SHA-256 stored beside it, else why not."""
    try:
        stored = read_cache_file(_checksum_file(lib), CHECKSUM_LIMIT).decode().strip()
    except FileNotFoundError:
        return "it has no checksum beside it"
    except (OSError, UnicodeDecodeError) as exc:
        return f"its checksum cannot be read ({getattr(exc, 'strerror', None) or exc})"
    try:
        data = read_cache_file(lib, LIBRARY_LIMIT)
    except OSError as exc:
        return f"it cannot be read ({exc.strerror or exc})"
    if hashlib.sha256(data).hexdigest() != stored:
        return "its content does not match its checksum (corrupt or truncated)"
    return _elf_problem(data)


# the ELF header after e_ident, a program header (with the index of p_offset and p_filesz) and
# a section header, for 32- and 64-bit files; the byte order is prefixed as the file says
_ELF_HEADER = {1: "HHIIIIIHHHHHH", 2: "HHIQQQIHHHHHH"}
_PHDR = {1: ("IIIIIIII", 1, 4), 2: ("IIQQQQQQ", 2, 5)}
_SHDR = {1: "IIIIIIIIII", 2: "IIQQQQIIQQ"}


def elf_problem(lib: Path) -> str | None:
    """None if `lib` is a whole ELF file, else why not: its header, its program and section
    header tables, every loaded segment and every section with bytes in the file end within it.

    dlopen maps a library's segments as its headers say; a file cut short is mapped past its
    end and the first access there kills the process (SIGBUS), so this is checked before
    loading. Off Linux a file that is not ELF is not checked (another object format).
    """
    try:
        data = read_cache_file(lib, LIBRARY_LIMIT)
    except OSError as exc:
        return f"it cannot be read ({exc.strerror or exc})"
    return _elf_problem(data)


def _elf_problem(data: bytes) -> str | None:
    """`elf_problem` of a library's bytes."""
    size = len(data)
    if data[:4] != b"\x7fELF":
        return "it is not an ELF shared library" if sys.platform.startswith("linux") else None
    if size < 16 or data[4] not in _ELF_HEADER or data[5] not in (1, 2):
        return "its ELF header is not a 32- or 64-bit one of either byte order"
    cls, order = data[4], "<" if data[5] == 1 else ">"
    fmt = order + _ELF_HEADER[cls]
    if size < 16 + struct.calcsize(fmt):
        return f"it is cut short ({size} bytes: less than its ELF header)"
    head = struct.unpack_from(fmt, data, 16)
    phoff, shoff, phentsize, phnum, shentsize, shnum = head[4], head[5], *head[8:12]
    for what, off, entsize, num in (("program", phoff, phentsize, phnum),
                                    ("section", shoff, shentsize, shnum)):
        if num and off + entsize * num > size:
            return f"it is cut short ({size} bytes; its {what} header table ends at " \
                   f"{off + entsize * num})"
    pfmt, i_off, i_size = _PHDR[cls]
    sfmt = order + _SHDR[cls]
    pfmt = order + pfmt
    if (phnum and phentsize < struct.calcsize(pfmt)) or (
            shnum and shentsize < struct.calcsize(sfmt)):
        return "its ELF header gives too small a program or section header size"
    for k in range(phnum):
        ph = struct.unpack_from(pfmt, data, phoff + k * phentsize)
        if ph[0] == 1 and ph[i_off] + ph[i_size] > size:  # PT_LOAD
            end = ph[i_off] + ph[i_size]
            return f"it is cut short ({size} bytes; a loaded segment ends at {end})"
    for k in range(shnum):
        sh = struct.unpack_from(sfmt, data, shoff + k * shentsize)
        if sh[1] != 8 and sh[4] + sh[5] > size:  # (SHT_NOBITS, 8, has no bytes in the file)
            return f"it is cut short ({size} bytes; a section ends at {sh[4] + sh[5]})"
    return None


def _differs(loaded: ca.Function, fn: ca.Function) -> str | None:
    """None if the loaded `loaded` is `fn` as far as one call can tell, else how it differs: its
    name, its inputs' and outputs' sparsity, and its values at a fixed point (to 1e-6 of each
    output's largest: loose enough for another compiler's rounding; NaN where `fn` gives NaN).
    A library of another horizon or of other constants fails it."""
    if loaded.name() != fn.name():
        return f"it holds the function '{loaded.name()}', not '{fn.name()}'"
    for kind, f_n, f_sp, n, sp in (
            ("input", loaded.n_in(), loaded.sparsity_in, fn.n_in(), fn.sparsity_in),
            ("output", loaded.n_out(), loaded.sparsity_out, fn.n_out(), fn.sparsity_out)):
        if f_n != n:
            return f"its function has {f_n} {kind}s, not {n}"
        for i in range(n):
            if f_sp(i) != sp(i):
                a, b = f_sp(i), sp(i)
                return (f"its {kind} {i} is {a.size1()}x{a.size2()} ({a.nnz()} nonzeros), not "
                        f"{b.size1()}x{b.size2()} ({b.nnz()})")
    golden = (5 ** 0.5 - 1) / 2  # a point with no two entries alike, no zeros, no symmetry
    args = [ca.DM(fn.sparsity_in(i), list(0.1 + 0.8 * ((np.arange(fn.nnz_in(i)) + 1 + 7 * i)
                                                         * golden % 1)))
            for i in range(fn.n_in())]
    try:
        want = fn.call(args)
    except RuntimeError:
        return None  # no value to compare with (the structure matched)
    try:
        got = loaded.call(args)
    except RuntimeError as exc:
        return f"it fails where the function does not ({str(exc).strip().splitlines()[-1][:200]})"
    for i, (a, b) in enumerate(zip(got, want)):
        a, b = np.array(a.nonzeros(), dtype=float), np.array(b.nonzeros(), dtype=float)
        scale = float(np.max(np.abs(b[np.isfinite(b)]), initial=1.0))
        if not np.allclose(a, b, rtol=0.0, atol=1e-6 * scale, equal_nan=True):
            return (f"its output {i} has other values than the function's (by up to "
                    f"{np.nanmax(np.abs(a - b)):.3g})")
    return None
