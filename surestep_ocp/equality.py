"""Value equality for the frozen dataclasses that hold NumPy arrays (a problem's specs, the noise
constants).

The `==` a dataclass generates compares its fields as tuples, which asks an array for a truth value
and raises ValueError; `ArrayEquality` compares (and hashes) a canonical form instead.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np


def canonical(value: Any) -> Any:
    """A hashable value equal for equal specs: dataclasses field by field (those compared), NumPy
    arrays by shape and values, lists and tuples elementwise, mappings by their items, paths as
    text."""
    if is_dataclass(value) and not isinstance(value, type):
        return (type(value).__name__,
                *((f.name, canonical(getattr(value, f.name))) for f in fields(value) if f.compare))
    if isinstance(value, np.ndarray):
        return ("array", value.shape, tuple(value.ravel().tolist()))
    if isinstance(value, (list, tuple)):
        return tuple(canonical(v) for v in value)
    if isinstance(value, dict):
        items = ((str(k), canonical(v)) for k, v in value.items())
        return ("dict", tuple(sorted(items, key=lambda kv: kv[0])))
    if isinstance(value, Path):
        return str(value)
    return value.item() if isinstance(value, np.generic) else value


class ArrayEquality:
    """`==` and `hash` for frozen dataclasses holding NumPy arrays (the generated ones raise on an
    array's truth value): equal when every compared field is, arrays by shape and values
    (`canonical`)."""

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return canonical(self) == canonical(other)

    def __hash__(self) -> int:
        return hash(canonical(self))
