"""Where commands may write: output files and folders checked before the work starts.

A command's outputs are checked up front (`check_output_file`, `check_output_dir`,
`check_new_dir`) and written whole or not at all (`solution.write_text_atomic`: a temporary
file beside the target, renamed over it; `write_dir_atomic`: a temporary directory beside it,
renamed onto a missing or empty one). An output may replace a regular file, never one of the
command's inputs (the same file under any name), a directory, a device or another
special file; its folder must exist or be creatable, and be writable. Every refusal is a
one-line `SurestepError` (exit 2).

Also here: `check_finite`, which refuses to write NaN or Infinity (naming the key that
diverged).
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import stat
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from ..errors import SolverError, SurestepError, shown


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _probe_writable(folder: Path, what: str) -> None:
    """Create and delete a temporary file in `folder` (the one sure test of writability)."""
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".surestep-probe-")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise SurestepError(f"{shown(str(folder), 200)}: cannot write {what} there "
                            f"({exc.strerror or exc})") from None


def _nearest_existing(folder: Path) -> Path:
    p = folder
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


# a solution file read (10,000 waypoints with their covariances: about 10 MB)
MAX_SOLUTION_BYTES = 50_000_000
MAX_URDF_BYTES = 10_000_000  # a URDF read (the dVRK's are about 20 kB; meshes are separate files)


def input_file_problem(path: str | Path, max_bytes: int) -> str | None:
    """Why `path` is not read as an input file, or None: it must be a regular file (a device such as
    /dev/zero would be read until memory runs out, a pipe would block forever) of at most
    `max_bytes`. A missing file raises OSError (the caller says what was missing)."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file (a directory, device or pipe)"
    if st.st_size > max_bytes:
        return f"a file of {st.st_size} bytes; at most {max_bytes} bytes are read"
    return None


def _named_apart_from_inputs(path: Path, inputs: Iterable[str | Path], what: str, kind: str) -> str:
    """`path` shown for messages, once it is a real name (not empty, `.` or `..`) and
    none of `inputs`."""
    name = shown(str(path), 200)
    if str(path) == "" or path.name in ("", ".", ".."):
        raise SurestepError(f"'{name}': {what} must be a {kind} name")
    for inp in inputs:
        if inp is not None and _same_file(path, Path(inp)):
            raise SurestepError(f"{name}: {what} would overwrite the input {shown(str(inp), 200)}; "
                                f"choose another {kind}")
    return name


def named_path(path: str | Path, what: str, kind: str) -> Path:
    """`path` as a Path; an empty one is an error (`Path('')` would be the current folder)."""
    if str(path).strip() == "":
        raise SurestepError(f"{shown(repr(str(path)))}: an empty path; {what} must be a named "
                            f"{kind}")
    return Path(path)


def check_output_file(path: str | Path, inputs: Iterable[str | Path] = (),
                      what: str = "the output") -> Path:
    """Check, before any work, that `path` can be written whole and replaces nothing it must not.

    Creates the missing parent folders (so the check is the real one).
    """
    path = named_path(path, what, "file")
    name = _named_apart_from_inputs(path, inputs, what, "file")
    if path.exists() or path.is_symlink():
        try:
            mode = path.stat().st_mode
        except OSError as exc:
            raise SurestepError(f"{name}: cannot use it as {what} "
                                f"({exc.strerror or exc})") from None
        if stat.S_ISDIR(mode):
            raise SurestepError(f"{name}: is a directory; {what} must be a file")
        if not stat.S_ISREG(mode):
            raise SurestepError(f"{name}: not a regular file (a device, pipe or socket); {what} is "
                                "only written to a new or regular file")
        if path.is_symlink():
            raise SurestepError(f"{name}: is a symbolic link; {what} would replace the link, not "
                                "its target; give the target's path")
    parent = path.parent
    existing = _nearest_existing(parent)
    if not existing.is_dir():
        raise SurestepError(f"{name}: {shown(str(existing), 200)} is not a directory")
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SurestepError(f"{name}: cannot create the folder {shown(str(parent), 200)} "
                            f"({exc.strerror or exc})") from None
    _probe_writable(parent, what)
    return path


def check_output_dir(path: str | Path, inputs: Iterable[str | Path] = (),
                     what: str = "the output") -> Path:
    """Check, before any work, that `path` is (or can be created as) a writable
    directory; create it."""
    path = named_path(path, what, "directory")
    name = shown(str(path), 200)
    if path.exists() and not path.is_dir():
        raise SurestepError(f"{name}: exists and is not a directory; {what} directory must be a "
                            "directory")
    existing = _nearest_existing(path)
    if not existing.is_dir():
        raise SurestepError(f"{name}: {shown(str(existing), 200)} is not a directory")
    for inp in inputs:
        if inp is not None and _same_file(path, Path(inp)):
            raise SurestepError(f"{name}: is an input of this command; choose another directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SurestepError(f"{name}: cannot create {what} directory "
                            f"({exc.strerror or exc})") from None
    _probe_writable(path, what)
    return path


def check_new_dir(path: str | Path, inputs: Iterable[str | Path] = (),
                  what: str = "the output") -> Path:
    """Check, before any work, that `path` can become a new directory written whole
    (`write_dir_atomic`): missing or an empty directory, never replacing files; its parent is
    created and must be writable."""
    path = named_path(path, what, "directory")
    name = _named_apart_from_inputs(path, inputs, what, "directory")
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise SurestepError(f"{name}: exists and is not a directory; {what} is a new directory")
    if path.is_dir() and any(path.iterdir()):
        raise SurestepError(f"{name}: exists and is not empty; {what} is written to a new or empty "
                            "directory (remove it or choose another)")
    existing = _nearest_existing(path.parent)
    if not existing.is_dir():
        raise SurestepError(f"{name}: {shown(str(existing), 200)} is not a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SurestepError(f"{name}: cannot create the folder {shown(str(path.parent), 200)} "
                            f"({exc.strerror or exc})") from None
    _probe_writable(path.parent, what)
    return path


@contextlib.contextmanager
def write_dir_atomic(path: Path, what: str = "the output") -> Iterator[Path]:
    """Yield a fresh directory beside `path` to fill (named as `path`); on success it is renamed
    onto `path` (which must be missing or empty, as `check_new_dir` checked), on any error removed:
    the directory whole or not at all."""
    path = Path(path)
    tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.tmp-"))
    try:
        yield tmp / path.name
        try:
            os.rename(tmp / path.name, path)  # replaces an empty directory, never a non-empty one
        except OSError as exc:
            raise SurestepError(f"{shown(str(path), 200)}: cannot write {what} there "
                                f"({exc.strerror or exc}; a new or empty directory only)") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def written_together(targets: list[Path], what: str = "the output") -> Iterator[dict[Path, Path]]:
    """Several outputs (files or directories side by side) written all or none: yields, for each
    target, where to write it (under its own name in one fresh folder beside them); when the block
    ends without an error each is renamed onto its target, SIGINT and SIGTERM held meanwhile (an
    interrupt lands before any rename or after the last); on any error or interrupt the folder is
    removed and no target touched. Errors naming a staged path name its target."""
    targets = [Path(t) for t in targets]
    parent = targets[0].parent
    if any(t.parent != parent for t in targets):
        raise ValueError("written_together: the targets must share their folder")
    try:
        tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{targets[0].name}.tmp-"))
    except OSError as exc:
        raise SurestepError(f"{shown(str(targets[0]), 200)}: cannot write {what} there "
                            f"({exc.strerror or exc})") from None
    staged = {t: tmp / t.name for t in targets}
    try:
        try:
            yield staged
        except SurestepError as exc:
            text = " ".join(map(str, exc.args))
            for t, s in staged.items():
                text = text.replace(str(s), str(t))
            exc.args = (text,)
            raise
        with _signals_held():
            for t, s in staged.items():
                if s.exists():
                    if not s.is_dir():
                        check_replaceable(t)
                    os.replace(s, t)  # (a directory onto a missing or empty one: check_new_dir)
    except OSError as exc:
        raise SurestepError(f"{shown(str(targets[0]), 200)}: cannot write {what} "
                            f"({exc.strerror or exc})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back (delivered when the block ends); in the main thread only."""
    held = {signal.SIGINT, signal.SIGTERM}
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def check_replaceable(path: Path) -> None:
    """Refuse to rename a file over `path` when it is a directory or not a regular file
    (last-moment check)."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise SurestepError(f"{shown(str(path), 200)}: cannot write it "
                            f"({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise SurestepError(f"{shown(str(path), 200)}: is a directory; not replaced")
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise SurestepError(f"{shown(str(path), 200)}: not a regular file (a device, pipe or "
                            "socket); not replaced")


class NonFinite(SolverError):
    """A computation produced NaN or Infinity; nothing holding it is written."""

    def __init__(self, what: str, where: str, value: float):
        self.where = where
        super().__init__(what, "diverged", message=f"{where} is {value} (nothing is written with a "
                                                    "non-finite number; the inputs are likely too "
                                                    "extreme for the model)")


def first_non_finite(obj: Any, path: str = "") -> tuple[str, float] | None:
    """The key path and value of the first NaN or Infinity in a JSON-like tree (numpy
    arrays included)."""
    stack = [(path, obj)]
    while stack:
        where, o = stack.pop()
        if isinstance(o, float):
            if not math.isfinite(o):
                return where or "<value>", o
        elif isinstance(o, dict):
            stack.extend((f"{where}.{k}" if where else str(k), v)
                         for k, v in reversed(list(o.items())))
        elif isinstance(o, (list, tuple)):
            stack.extend((f"{where}[{i}]", v) for i, v in reversed(list(enumerate(o))))
        elif hasattr(o, "dtype") and hasattr(o, "tolist"):
            stack.append((where, o.tolist()))
        elif hasattr(o, "item") and hasattr(o, "dtype"):
            stack.append((where, o.item()))
    return None


def check_finite(obj: Any, what: str) -> None:
    """Raise `NonFinite` naming the first key of `obj` holding NaN or Infinity."""
    bad = first_non_finite(obj)
    if bad is not None:
        raise NonFinite(what, *bad)
