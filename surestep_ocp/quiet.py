"""`quiet_fd`: keeps C libraries' chatter off the terminal (urdfdom prints URDF parse errors on
stderr; the callers say them in one line instead). Used by every layer, like `errors.py`."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator


@contextlib.contextmanager
def quiet_fd(fd: int = 2) -> Iterator[None]:
    """Silence a file descriptor (C libraries printing to stderr) for the duration of the block."""
    try:
        saved = os.dup(fd)
    except OSError:  # no such descriptor: nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
