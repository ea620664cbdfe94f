"""The compile cache's folder and its files, apart from compiling into it (`codegen.py`).

Where it is (`cache_dir`), how large it may grow (`max_bytes`), which files are its own (`own_file`:
libraries `<function>_<20 hex digits>.so`, their `.sha256`, `timing.json` and the partial writes
of these), reading one safely (`read_cache_file`: regular files within a size bound only), and the
cache as a whole as `surestep cache` shows, prunes and clears it (`entries`, `prune`, `clear`;
they touch no other file in its folder). The rules it keeps: `codegen.py`'s module docstring.
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from ..errors import SurestepError, shown

# the cache's size bound [MB] unless $SURESTEP_CACHE_MAX_MB says otherwise (0: unbounded)
DEFAULT_MAX_MB = 1024
TIMING_FILE = "timing.json"
# the largest cache files read [bytes]: a library, a checksum, the timing record
LIBRARY_LIMIT, CHECKSUM_LIMIT, TIMING_LIMIT = 256 * 2**20, 4096, 65536
_LIBRARY = r"[A-Za-z_][A-Za-z0-9_]*_[0-9a-f]{20}\.so"
_OWN = re.compile(rf"(?:{_LIBRARY}(?:\.sha256)?|{re.escape(TIMING_FILE)})"
                  r"(?:\.(?P<pid>[0-9]+)(?:\.[0-9]+)?\.part)?")


def cache_dir() -> Path:
    """The compile cache's folder (`codegen.py`'s docstring): `$SURESTEP_CACHE`, else
    `$XDG_CACHE_HOME/surestep_ocp`, else `~/.cache/surestep_ocp`."""
    override = os.environ.get("SURESTEP_CACHE")
    if override:
        return Path(override)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "surestep_ocp"


def max_bytes() -> int | None:
    """The cache's size bound in bytes (`$SURESTEP_CACHE_MAX_MB`, default `DEFAULT_MAX_MB`; 0: None,
    unbounded)."""
    text = os.environ.get("SURESTEP_CACHE_MAX_MB", "").strip()
    return megabytes(text or str(DEFAULT_MAX_MB), "SURESTEP_CACHE_MAX_MB")


def megabytes(text, name: str) -> int | None:
    """A cache bound given as a number of megabytes (text or number) in bytes, None for 0
    (unbounded); anything but a finite number >= 0 (a word, NaN, inf, -1) is an error naming
    `name`."""
    try:
        mb = float(text)
    except (TypeError, ValueError):
        mb = math.nan
    if not (math.isfinite(mb) and mb >= 0):
        raise SurestepError(f"{name} must be a finite number of megabytes >= 0 (0: unbounded), "
                            f"got {shown(str(text), 40)}")
    return None if mb == 0 else int(mb * 1e6)


def read_cache_file(path: Path, limit: int) -> bytes:
    """The bytes of the cache file `path` if it is a regular file (a symbolic link to one is) of
    at most `limit` bytes, else OSError saying why: a FIFO is never opened for a blocking read, a
    device never read."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise OSError(errno.EINVAL, "not a regular file", str(path))
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(fd)  # (the file opened, not one swapped in after the check)
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        data = f.read(limit + 1)
    if len(data) > limit:
        raise OSError(errno.EFBIG, f"larger than {limit} bytes", str(path))
    return data


def _checksum_file(lib: Path) -> Path:
    return lib.with_name(lib.name + ".sha256")


def _unlink_quietly(path: Path) -> None:
    """Remove `path` if it is there; an error doing so is not raised (a cleanup inside an error
    path must not replace that error, e.g. under a folder that is not a directory)."""
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


# ------------------------------------------------------------ the cache as a whole (surestep cache)

@dataclass(frozen=True)
class Entry:
    """A compiled library in the cache, its checksum file, their bytes and its last use [s since the
    epoch]."""

    lib: Path
    size: int
    last_use: float


def own_file(name: str) -> bool:
    """Whether a file named `name` is one of the cache's (module docstring: its naming scheme)."""
    return _OWN.fullmatch(name) is not None


def _own(folder: Path) -> list[Path]:
    """The cache's files in `folder` (none if it cannot be listed); never a directory."""
    try:
        names = [p for p in folder.iterdir() if own_file(p.name)]
    except OSError:
        return []
    out = []
    for p in names:
        try:
            if not stat.S_ISDIR(p.lstat().st_mode):
                out.append(p)
        except OSError:
            pass
    return out


def partial_writes(folder: Path | None = None) -> tuple[list[Path], list[Path]]:
    """The cache's partial writes: (orphaned ones, whose process is gone (a compile killed
    midway), those of a live process)."""
    folder = cache_dir() if folder is None else folder
    orphans, live = [], []
    for p in _own(folder):
        pid = _OWN.fullmatch(p.name).group("pid")
        if pid is not None:
            (live if _alive(int(pid)) else orphans).append(p)
    return orphans, live


def _alive(pid: int) -> bool:
    """Whether process `pid` exists (on this machine)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except PermissionError:  # (another user's)
        return True
    except (ProcessLookupError, OverflowError, ValueError):
        return False
    return True


def _size(path: Path) -> int:
    """Bytes of `path` if it is a regular file (not following links), else 0."""
    try:
        st = path.lstat()
    except OSError:
        return 0
    return st.st_size if stat.S_ISREG(st.st_mode) else 0


def entries(folder: Path | None = None) -> list[Entry]:
    """The cache's libraries (named by its scheme), least recently used first."""
    folder = cache_dir() if folder is None else folder
    out = []
    for lib in _own(folder):
        if not lib.name.endswith(".so"):
            continue
        try:
            st = lib.stat()
        except OSError:
            continue
        size, last = st.st_size, st.st_mtime
        try:
            cs = _checksum_file(lib).stat()
            size, last = size + cs.st_size, max(last, cs.st_mtime)
        except OSError:
            pass
        out.append(Entry(lib, size, last))
    return sorted(out, key=lambda e: (e.last_use, e.lib.name))


def total_bytes(folder: Path | None = None) -> int:
    """Bytes of the cache's own files (libraries, checksums, partial writes, the timing record;
    other files in its folder are not counted)."""
    folder = cache_dir() if folder is None else folder
    return sum(_size(p) for p in _own(folder))


def _remove(entry: Entry) -> bool:
    try:
        entry.lib.unlink(missing_ok=True)  # (a process that loaded it keeps its mapping)
        _checksum_file(entry.lib).unlink(missing_ok=True)
        return True
    except OSError:
        return False


def _remove_files(paths: list[Path]) -> int:
    """Remove `paths` (the cache's own files); the bytes freed."""
    freed = 0
    for p in paths:
        size = _size(p)
        try:
            p.unlink()
            freed += size
        except OSError:
            pass
    return freed


def prune(limit: int | None, folder: Path | None = None) -> list[Entry]:
    """Remove the orphaned partial writes, then the least recently used libraries until the
    cache's libraries take at most `limit` bytes (None: no library removed). Returns the libraries
    removed."""
    _remove_files(partial_writes(folder)[0])
    if limit is None:
        return []
    all_entries = entries(folder)
    total = sum(e.size for e in all_entries)
    removed = []
    for e in all_entries:
        if total <= limit:
            break
        if _remove(e):
            total -= e.size
            removed.append(e)
    return removed


def clear(folder: Path | None = None) -> int:
    """Remove the cache's own files (`own_file`: libraries, checksums, the timing record, orphaned
    partial writes; a live compile's are left to it); the bytes freed. Nothing else in its folder
    is touched (a folder given as SURESTEP_CACHE may hold others)."""
    folder = cache_dir() if folder is None else folder
    live = set(partial_writes(folder)[1])
    return _remove_files([p for p in _own(folder) if p not in live])

