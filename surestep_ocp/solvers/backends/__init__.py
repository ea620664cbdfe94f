"""The OCP solver backends, registered by name: the strategy's attempts name one of these.

Adding a solver is one module implementing `base.Backend` and one entry in `BACKENDS`.
"""

from __future__ import annotations

from .base import Backend, Context, Outcome
from .interior_point import InteriorPointBackend
from .ipopt import IpoptBackend
from .projected_newton import NewtonBackend

BACKENDS: dict[str, Backend] = {b.name: b
                                for b in (NewtonBackend(), InteriorPointBackend(), IpoptBackend())}

__all__ = ["BACKENDS", "Backend", "Context", "Outcome"]
