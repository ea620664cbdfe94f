"""One writer per output folder: an exclusive, non-blocking `fcntl.flock`, held for the whole run.

The lock is taken on the output folder itself (its directory descriptor), so nothing is left in the
folder, even after SIGKILL, and the kernel releases it when the process ends however it ends. Where
a file system cannot lock a directory, a lock file `FOLDER/.surestep.lock` is locked instead.

A second `surestep evaluate` (or `sweep`) into the same folder is refused at once with a one-line
`SurestepError` naming the folder, instead of both appending to one `progress.jsonl`.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator
from pathlib import Path

from ..errors import SurestepError, shown

LOCK_NAME = ".surestep.lock"
_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES)


def _busy(folder: Path, what: str) -> SurestepError:
    return SurestepError(f"{shown(str(folder), 200)}: another surestep process is writing {what} "
                         "in this folder (it holds the folder's lock); wait for it to finish or "
                         "choose another --output-dir")


@contextlib.contextmanager
def hold(folder: str | Path, what: str = "a run") -> Iterator[None]:
    """Hold the folder's exclusive lock while inside; `SurestepError` at once if another process
    holds it."""
    import fcntl  # POSIX only; imported on use

    folder = Path(folder)
    name = shown(str(folder), 200)
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as exc:
        raise SurestepError(f"{name}: cannot open the folder to lock it "
                            f"({exc.strerror or exc})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in _BUSY:
                raise _busy(folder, what) from None
            os.close(fd)  # a file system without directory locks: a lock file instead
            fd = -1
            try:
                fd = os.open(folder / LOCK_NAME,
                             os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc2:
                if exc2.errno in _BUSY:
                    raise _busy(folder, what) from None
                raise SurestepError(f"{name}: cannot lock the folder "
                                    f"({exc2.strerror or exc2})") from None
        yield
    finally:
        if fd >= 0:
            os.close(fd)  # releases the lock
