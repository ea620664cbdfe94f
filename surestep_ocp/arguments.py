"""Numeric arguments of the public API checked as the problem reader checks its keys.

A bad value is a SurestepError naming the argument and what is allowed (the CLI's exit 2), never a
raw ValueError / OverflowError from `int()` and never silently clamped.
"""

from __future__ import annotations

import math
import numbers

from .errors import SurestepError, shown


def whole_number(value, name: str, minimum: int = 0, maximum: int | None = None) -> int:
    """`value` as an int: a whole number (int, or a float with no fraction) within
    [minimum, maximum]; a bool, a string, NaN, an infinity or a fraction is an error naming
    `name`."""
    allowed = (f"a whole number >= {minimum}" if maximum is None
               else f"a whole number from {minimum} to {maximum}")
    ok = (isinstance(value, numbers.Real) and not isinstance(value, bool)
          and math.isfinite(value) and value == int(value)
          and value >= minimum and (maximum is None or value <= maximum))
    if not ok:
        kind = "" if isinstance(value, numbers.Real) else f" ({type(value).__name__})"
        raise SurestepError(f"{name} must be {allowed}, got {shown(value)}{kind}")
    return int(value)


def real_number(value, name: str) -> float:
    """`value` as a float: a real number (an int or a float; not a bool, a string or None), which
    the callee's own range check then bounds; else an error naming `name`."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        raise SurestepError(f"{name} must be a number, got {shown(value)} "
                            f"({type(value).__name__})")
    return float(value)
