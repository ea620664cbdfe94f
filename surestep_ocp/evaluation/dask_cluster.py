"""The evaluation on a Dask cluster (`surestep evaluate --scheduler`): the client, the scheduler
address checked by distributed's own parsers, the configurations as futures. The one module that
imports `distributed` (the optional `dask` extra): `parallel.py` loads it when a scheduler is given.
"""

from __future__ import annotations

import uuid

from distributed import Client, as_completed
from distributed.comm import registry
from distributed.comm.addressing import parse_address

from ..errors import SurestepError
from .configuration_record import evaluate_configuration


def client(scheduler, timeout: str):
    """(client, whether we opened it) for a scheduler address (connecting within `timeout`, e.g.
    "10s"), or a `distributed.Client` passed in."""
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


def run(todo, args, rest, client, finish) -> None:
    """The configurations as Dask futures on the client's cluster; records handed to `finish` as
    they complete."""
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
