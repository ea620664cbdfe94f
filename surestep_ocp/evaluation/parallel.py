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
import uuid
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
    "10s"), or a `distributed.Client` passed in."""
    try:
        from distributed import Client  # optional: the `dask` extra
    except ImportError as exc:
        raise SurestepError("--scheduler needs dask.distributed (pip install "
                            f"'surestep_ocp[dask]'): {exc}") from None
    if not isinstance(scheduler, str):
        return scheduler, False
    _check_scheduler_address(scheduler)
    try:
        return Client(scheduler, timeout=timeout, set_as_default=False), True
    except (OSError, TimeoutError, ValueError) as exc:
        raise SurestepError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler "
                            f"({type(exc).__name__}: {exc})") from None


def _check_scheduler_address(scheduler: str) -> None:
    """Refuse an address dask.distributed cannot parse before a `Client` is made of it.

    A `Client` whose address fails to parse is left half-started: its `__del__` then waits 20 s
    and prints a traceback. The checks are distributed's own parsers (scheme, then host:port).
    """
    from distributed.comm import registry
    from distributed.comm.addressing import parse_address

    allowed = "an address like tcp://host:8786 (or tls://, ws://, wss://, inproc://)"
    scheme, loc = parse_address(scheduler)
    try:
        backend = registry.get_backend(scheme)
    except ValueError:
        raise SurestepError(f"--scheduler {scheduler!r}: unknown scheme {scheme!r}; "
                            f"expected {allowed}") from None
    try:
        try:
            host, port = backend.get_address_host_port(loc)
        except NotImplementedError:  # not an IP transport (inproc): its own form and checks
            backend.get_address_host(loc)
            return
    except (ValueError, TypeError) as exc:
        raise SurestepError(f"--scheduler {scheduler!r}: not a {scheme}:// address ({exc}); "
                            f"expected {allowed}") from None
    if not host or not 0 < port < 65536:
        raise SurestepError(f"--scheduler {scheduler!r}: needs a host and a port in 1..65535; "
                            f"expected {allowed}")


def run_dask(todo, args, rest, client, finish) -> None:
    """The configurations as Dask futures on the client's cluster; records handed to `finish` as
    they complete."""
    from distributed import as_completed  # optional (the `dask` extra), loaded on use

    futures = []
    tag = uuid.uuid4().hex[:8]
    try:
        # pure=False: every configuration is its own task; retries=1 rescues a worker lost mid-task
        futures = [client.submit(evaluate_configuration, *args, i, *rest,
                                 key=f"surestep-config-{i}-{tag}", pure=False,
                                 retries=1) for i in todo]
        with client.as_current():
            for fut in as_completed(futures):
                finish(fut.result())
    except BaseException:
        client.cancel(futures)
        raise
