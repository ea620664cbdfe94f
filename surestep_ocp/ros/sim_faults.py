"""Faults `surestep sim-robot --fault KIND@T[+D]` injects: from T s after the first servo_jp,
for D s (default: to the end). `tracker-silent`: no estimates; `nan`: estimates with NaN;
`stuck`: the arm stops following servo_jp."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ..errors import SurestepError, shown

KINDS = ("tracker-silent", "nan", "stuck")
_SPEC = re.compile(r"([a-z-]+)@([0-9.]+)(?:\+([0-9.]+))?\Z")


@dataclass(frozen=True)
class Fault:
    kind: str
    at: float
    duration: float = math.inf

    def active(self, kind: str, t: float | None) -> bool:
        return t is not None and kind == self.kind and self.at <= t < self.at + self.duration


def parse_faults(specs: list[str]) -> list[Fault]:
    out = []
    for s in specs:
        mt = _SPEC.match(s.strip())
        try:
            ok = mt is not None and mt.group(1) in KINDS
            f = Fault(mt.group(1), float(mt.group(2)),
                      float(mt.group(3)) if mt.group(3) else math.inf) if ok else None
        except ValueError:
            f = None
        if f is None:
            raise SurestepError(f"--fault: '{shown(s)}' is not KIND@T[+D] with KIND one of "
                                f"{', '.join(KINDS)} and T, D seconds")
        out.append(f)
    return out


def active(faults: list[Fault], kind: str, t: float | None) -> bool:
    return any(f.active(kind, t) for f in faults)
