"""Strict reading of YAML trees: every error names the file, the key path and what is allowed."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import ProblemError


class Reader:
    """Typed accessors over a parsed YAML tree that raise :class:`ProblemError`."""

    def __init__(self, file: str):
        self.file = file

    def fail(self, key: str, message: str) -> ProblemError:
        return ProblemError(self.file, key, message)

    def mapping(self, node: Any, key: str, allowed: set[str], required: set[str] = frozenset()) -> dict:
        """A mapping with only `allowed` keys, all `required` ones present."""
        if not isinstance(node, Mapping):
            raise self.fail(key or "<top>", f"expected a mapping with keys {sorted(allowed)}, got {_kind(node)}")
        unknown = sorted(set(node) - allowed, key=str)
        if unknown:
            raise self.fail(_join(key, str(unknown[0])), f"unknown key; allowed keys here: {', '.join(sorted(allowed))}")
        missing = sorted(required - set(node))
        if missing:
            raise self.fail(_join(key, missing[0]), "missing required key")
        return dict(node)

    def one_of(self, node: dict, key: str, options: list[str]) -> str:
        """The single key of `options` present in `node`."""
        present = [o for o in options if o in node]
        if len(present) != 1:
            raise self.fail(key, f"give exactly one of {', '.join(options)} (got {len(present)})")
        return present[0]

    def number(self, node: Any, key: str, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(node, bool) or not isinstance(node, (int, float)):
            raise self.fail(key, f"expected a number, got {_kind(node)}")
        value = float(node)
        if not np.isfinite(value):
            raise self.fail(key, "expected a finite number")
        if positive and value <= 0:
            raise self.fail(key, f"must be > 0, got {value:g}")
        if nonneg and value < 0:
            raise self.fail(key, f"must be >= 0, got {value:g}")
        return value

    def integer(self, node: Any, key: str, minimum: int | None = None) -> int:
        if isinstance(node, bool) or not isinstance(node, int):
            raise self.fail(key, f"expected an integer, got {_kind(node)}")
        if minimum is not None and node < minimum:
            raise self.fail(key, f"must be an integer >= {minimum}, got {node}")
        return int(node)

    def string(self, node: Any, key: str, choices: tuple[str, ...] | None = None) -> str:
        if not isinstance(node, str):
            raise self.fail(key, f"expected a string, got {_kind(node)}")
        if choices is not None and node not in choices:
            raise self.fail(key, f"'{node}' is not allowed; choose one of {', '.join(choices)}")
        return node

    def boolean(self, node: Any, key: str) -> bool:
        if not isinstance(node, bool):
            raise self.fail(key, f"expected true or false, got {_kind(node)}")
        return node

    def vector(self, node: Any, key: str, length: int | None = None) -> np.ndarray:
        if not isinstance(node, (list, tuple)):
            raise self.fail(key, f"expected a list of {length or 'some'} numbers, got {_kind(node)}")
        if length is not None and len(node) != length:
            raise self.fail(key, f"expected {length} numbers, got {len(node)}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(node)])

    def matrix(self, node: Any, key: str, n: int) -> np.ndarray:
        if not isinstance(node, (list, tuple)) or len(node) != n:
            raise self.fail(key, f"expected a {n}x{n} matrix (a list of {n} rows), got {_kind(node)}")
        return np.array([self.vector(row, f"{key}[{i}]", n) for i, row in enumerate(node)])

    def covariance(self, node: Any, key: str, n: int = 6, definite: bool = False) -> np.ndarray:
        """A scalar (times the identity) or an n x n symmetric positive (semi)definite matrix."""
        if isinstance(node, (list, tuple)):
            M = self.matrix(node, key, n)
            if not np.allclose(M, M.T, rtol=0, atol=1e-12 * max(1.0, np.abs(M).max())):
                raise self.fail(key, "matrix must be symmetric")
        else:
            M = self.number(node, key) * np.eye(n)
        eig = np.linalg.eigvalsh(M)
        if definite and eig.min() <= 0:
            raise self.fail(key, f"must be positive definite (smallest eigenvalue {eig.min():g})")
        if not definite and eig.min() < 0:
            raise self.fail(key, f"must be positive semidefinite (smallest eigenvalue {eig.min():g})")
        return M


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def _kind(node: Any) -> str:
    if node is None:
        return "nothing (null)"
    return {dict: "a mapping", list: "a list", str: f"the string '{node}'", bool: f"the boolean {node}"}.get(
        type(node), f"{type(node).__name__} {node!r}"
    )
