"""A CasADi Function called in place on NumPy arrays, through CasADi's buffer interface: no DM
conversions on the hot paths (the Newton and interior-point iterations, the robot's IK and camera
means, a re-plan's EKF, the lifted form's initial multipliers). At the package's root: the model
and the solvers both use it."""

from __future__ import annotations

import threading

import casadi as ca
import numpy as np


class Buffered:
    """A Function evaluated in place on NumPy arrays (CasADi's buffer interface). Its buffers are
    shared by every call, so one is used by one thread (its owners keep one per thread)."""

    def __init__(self, fn: ca.Function):
        self.fn = fn  # the buffer refers to it
        self.args = [np.zeros(fn.sparsity_in(i).numel()) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.sparsity_out(i).nnz()) for i in range(fn.n_out())]
        self.buf, self.trigger = fn.buffer()
        for i, a in enumerate(self.args):
            self.buf.set_arg(i, memoryview(a))
        for i, r in enumerate(self.res):
            self.buf.set_res(i, memoryview(r))

    def __call__(self, *args) -> list[np.ndarray]:
        for dst, src in zip(self.args, args):
            dst[:] = np.ravel(src, order="F")
        self.trigger()
        return self.res


_PER_THREAD = threading.local()


def thread_buffered(key: tuple, build) -> Buffered:
    """This thread's `Buffered` of the Function `build()` makes, built on its first use here for
    `key`, which must name that Function (e.g. hold the Function it is made from: Functions hash by
    identity, and the key keeps them alive)."""
    cache = _PER_THREAD.__dict__.setdefault("cache", {})
    if key not in cache:
        cache[key] = Buffered(build())
    return cache[key]
