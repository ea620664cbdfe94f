"""Where `surestep evaluate`'s configurations run besides this process: a pool of worker processes
(`--jobs N`, spawned) or an existing Dask cluster (`--scheduler ADDRESS`; dask.distributed, an
optional dependency, loaded on use). Each hands the records to `finish` as they complete.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed

from ..errors import SurestepError
from .configuration_record import evaluate_configuration


def worker_init() -> None:
    """A pool worker's start: Ctrl-C left to the parent, and ended with it (Linux)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and stops the workers
    # a parent killed outright (SIGKILL) takes its workers with it
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))  # 1: PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            return
        parent = multiprocessing.parent_process()
        if parent is not None and os.getppid() != parent.pid:  # it died before the prctl
            os._exit(1)


def run_pool(todo, args, rest, jobs, finish) -> None:
    """The configurations on a pool of `jobs` spawned worker processes; records handed to `finish`
    as they complete."""
    ex = ProcessPoolExecutor(max_workers=min(jobs, len(todo)),
                             mp_context=multiprocessing.get_context("spawn"),
                             initializer=worker_init)
    futures = []
    try:
        futures = [ex.submit(evaluate_configuration, *args, i, *rest) for i in todo]
        for fut in as_completed(futures):
            finish(fut.result())
    except BaseException:
        for f in futures:
            f.cancel()
        for p in list((getattr(ex, "_processes", None) or {}).values()):
            p.terminate()
        raise
    finally:
        ex.shutdown(wait=True, cancel_futures=True)


def dask_client(scheduler, timeout: str):
    """(client, whether we opened it) for a scheduler address (connecting within `timeout`, e.g.
    "10s"), or a `distributed.Client` passed in (`dask_cluster.py`, loaded here: the `dask` extra
    is optional)."""
    return _dask_cluster().client(scheduler, timeout)


def run_dask(todo, args, rest, client, finish) -> None:
    """The configurations as Dask futures on the client's cluster (`dask_cluster.run`; the client
    exists, so `distributed` is there); records handed to `finish` as they complete."""
    _dask_cluster().run(todo, args, rest, client, finish)


def _dask_cluster():
    """`dask_cluster.py`, loaded on use (the `dask` extra is optional)."""
    try:
        from . import dask_cluster
    except ImportError as exc:
        raise SurestepError("--scheduler needs dask.distributed (pip install "
                            f"'surestep_ocp[dask]'): {exc}") from None
    return dask_cluster
