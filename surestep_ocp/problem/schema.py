"""Strict reading of YAML trees: every error names the file, the key path and what is allowed."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import ProblemError, shown

MAX_MAGNITUDE = 1e9  # any number in a problem file, unless a key states its own range
# any integer (iteration counts, image sizes), unless a key states its own maximum
MAX_INTEGER = 10**7
MAX_VARIANCE = 1e6  # covariance entries [m^2, rad^2, or the observation's units]
# a positive definite covariance's smallest eigenvalue, and a non-zero scalar's
MIN_DEFINITE_EIGENVALUE = 1e-30
MAX_CONDITION = 1e12  # largest / smallest eigenvalue of a positive definite covariance


class Reader:
    """Typed accessors over a parsed YAML tree that raise :class:`ProblemError`."""

    def __init__(self, file: str):
        self.file = file

    def fail(self, key: str, message: str) -> ProblemError:
        return ProblemError(self.file, key, message)

    def mapping(self, node: Any, key: str, allowed: set[str],
                required: set[str] = frozenset()) -> dict:
        """A mapping with only `allowed` keys, all `required` ones present."""
        if not isinstance(node, Mapping):
            raise self.fail(key or "<top>", f"expected a mapping with keys {sorted(allowed)}, "
                                            f"got {_kind(node)}")
        unknown = sorted(set(node) - allowed, key=str)
        missing = sorted(required - set(node))
        if unknown:  # (a misspelt required key is one error, naming the key it stands for)
            lacking = f"; missing here: {', '.join(missing)}" if missing else ""
            raise self.fail(_join(key, str(unknown[0])), "unknown key; allowed keys "
                            f"here: {', '.join(sorted(allowed))}{lacking}")
        if missing:
            raise self.fail(_join(key, missing[0]), "missing required key")
        return dict(node)

    def one_of(self, node: dict, key: str, options: list[str]) -> str:
        """The single key of `options` present in `node`."""
        present = [o for o in options if o in node]
        if len(present) != 1:
            raise self.fail(key, f"give exactly one of {', '.join(options)} (got {len(present)})")
        return present[0]

    def number(self, node: Any, key: str, positive: bool = False, nonneg: bool = False,
               low: float | None = None, high: float | None = None,
               limit: float = MAX_MAGNITUDE) -> float:
        """A finite number; `low`/`high` bound it (inclusive), `limit` its magnitude
        (1e9 unless said)."""
        if isinstance(node, bool) or not isinstance(node, (int, float)):
            raise self.fail(key, f"expected a number, got {_kind(node)}")
        if isinstance(node, int) and abs(node) > 10**30:
            raise self.fail(key, f"a number of magnitude at most {limit:g} is needed, got an "
                                 f"integer of {len(str(abs(node)))} digits")
        value = float(node)
        if not np.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value}")
        if positive and value <= 0:
            raise self.fail(key, f"must be > 0, got {value:g}")
        if nonneg and value < 0:
            raise self.fail(key, f"must be >= 0, got {value:g}")
        if (low is not None and value < low) or (high is not None and value > high):
            lo = "" if low is None else f"{low:g} <= "
            hi = "" if high is None else f" <= {high:g}"
            raise self.fail(key, f"must be in the range {lo}value{hi}, got {value:g}")
        if abs(value) > limit:
            raise self.fail(key, f"magnitude must be at most {limit:g}, got {value:g}")
        return value

    def integer(self, node: Any, key: str, minimum: int | None = None,
                maximum: int | None = MAX_INTEGER) -> int:
        if isinstance(node, bool) or not isinstance(node, int):
            raise self.fail(key, f"expected an integer, got {_kind(node)}")
        if minimum is not None and node < minimum:
            raise self.fail(key, f"must be an integer >= {minimum}, got {_int(node)}")
        if maximum is not None and node > maximum:
            raise self.fail(key, f"must be an integer <= {maximum}, got {_int(node)}")
        return int(node)

    def string(self, node: Any, key: str, choices: tuple[str, ...] | None = None) -> str:
        if not isinstance(node, str):
            raise self.fail(key, f"expected a string, got {_kind(node)}")
        if choices is not None and node not in choices:
            raise self.fail(key, f"'{shown(node)}' is not allowed; choose one "
                                 f"of {', '.join(choices)}")
        return node

    def boolean(self, node: Any, key: str) -> bool:
        if not isinstance(node, bool):
            raise self.fail(key, f"expected true or false, got {_kind(node)}")
        return node

    def vector(self, node: Any, key: str, length: int | None = None, limit: float = MAX_MAGNITUDE,
               max_length: int = 1000) -> np.ndarray:
        """A list of numbers (each of magnitude at most `limit`)."""
        if not isinstance(node, (list, tuple)):
            raise self.fail(key, f"expected a list of {length or 'some'} numbers, "
                                 f"got {_kind(node)}")
        if length is not None and len(node) != length:
            raise self.fail(key, f"expected {length} numbers, got {len(node)}")
        if len(node) > max_length:
            raise self.fail(key, f"expected at most {max_length} numbers, got {len(node)}")
        return np.array([self.number(v, f"{key}[{i}]", limit=limit) for i, v in enumerate(node)],
                        dtype=float)

    def matrix(self, node: Any, key: str, n: int, limit: float = MAX_MAGNITUDE) -> np.ndarray:
        if not isinstance(node, (list, tuple)) or len(node) != n:
            what = f"a list of {len(node)}" if isinstance(node, (list, tuple)) else _kind(node)
            raise self.fail(key, f"expected a {n}x{n} matrix (a list of {n} rows), got {what}")
        return np.array([self.vector(row, f"{key}[{i}]", n, limit=limit)
                         for i, row in enumerate(node)])

    def covariance(self, node: Any, key: str, n: int = 6, definite: bool = False) -> np.ndarray:
        """A scalar (times the identity) or an n x n symmetric positive (semi)definite matrix.

        Entries are at most `MAX_VARIANCE` in magnitude; a positive definite one has every
        eigenvalue >= `MIN_DEFINITE_EIGENVALUE` and a condition number <= `MAX_CONDITION`; a
        semidefinite one has no eigenvalue in (0, `MIN_DEFINITE_EIGENVALUE`) relative to its
        largest (near-singular).
        """
        if isinstance(node, (list, tuple)):
            M = self.matrix(node, key, n, limit=MAX_VARIANCE)
            if not np.allclose(M, M.T, rtol=0, atol=1e-12 * max(1.0, np.abs(M).max())):
                raise self.fail(key, "matrix must be symmetric")
        else:
            s = self.number(node, key, limit=MAX_VARIANCE)
            if s != 0 and abs(s) < MIN_DEFINITE_EIGENVALUE:
                raise self.fail(key, f"must be 0 or of magnitude >= {MIN_DEFINITE_EIGENVALUE:g}, "
                                     f"got {s:g}")
            M = s * np.eye(n)
        eig = np.linalg.eigvalsh(M)
        top = float(np.abs(eig).max())
        if definite and eig.min() <= 0:
            raise self.fail(key, f"must be positive definite (smallest eigenvalue {eig.min():g})")
        if not definite and eig.min() < 0:
            raise self.fail(key, "must be positive semidefinite (smallest "
                                 f"eigenvalue {eig.min():g})")
        if definite and eig.min() < MIN_DEFINITE_EIGENVALUE:
            raise self.fail(key, f"smallest eigenvalue {eig.min():g} is "
                                 f"below {MIN_DEFINITE_EIGENVALUE:g}")
        small = eig[eig > 0].min(initial=np.inf)
        if top > 0 and top / small > MAX_CONDITION:
            raise self.fail(key, f"near-singular: condition number {top / small:.3g} "
                                 f"above {MAX_CONDITION:g} (eigenvalues {small:g} to {top:g}); "
                                 + ("make it better conditioned" if definite else
                                    "make the small eigenvalues exactly 0 or larger"))
        return M


def _join(key: str, sub: str) -> str:
    return f"{key}.{sub}" if key else sub


def _int(value: int) -> str:
    text = str(value)
    return text if len(text) <= 20 else f"an integer of {len(text.lstrip('-'))} digits"


def _kind(node: Any) -> str:
    if node is None:
        return "nothing (null)"
    if isinstance(node, bool):
        return f"the boolean {node}"
    if isinstance(node, str):
        return f"the string '{shown(node)}'"
    if isinstance(node, Mapping):
        return "a mapping"
    if isinstance(node, (list, tuple)):
        return "a list"
    if isinstance(node, int):
        return f"the integer {_int(node)}"
    if isinstance(node, float):
        return f"the number {node:g}"
    return f"{type(node).__name__} {shown(node)}"
