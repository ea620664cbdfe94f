"""Exception hierarchy.

Every error a user can cause derives from :class:`SurestepError`; the CLI turns
it into a one-line message and exit code 2. Solver failures carry the solver's
status so nothing is hidden.
"""

from __future__ import annotations

import re
from typing import Any

# Longest text echoed back from user input (a string value, a key, a file name) and
# longest whole message.
ECHO_LIMIT = 80
MESSAGE_LIMIT = 1000

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]+")


def one_line(text: Any, limit: int = MESSAGE_LIMIT) -> str:
    """`text` on one line (control characters and line breaks as one space), cut to
    `limit` characters."""
    text = _CONTROL.sub(" ", str(text)).strip()
    return text if len(text) <= limit else text[: limit - 25] + f"... ({len(text)} characters)"


def shown(value: Any, limit: int = ECHO_LIMIT) -> str:
    """A user-given value as echoed in a message: one line, at most `limit` characters."""
    text = (value if isinstance(value, str) else str(value) if isinstance(value, BaseException)
            else repr(value))
    text = text.encode("unicode_escape").decode("ascii") if _CONTROL.search(text) else text
    return text if len(text) <= limit else text[: limit - 3] + "..."


class SurestepError(Exception):
    """Root of all errors raised by surestep_ocp; its text is one line (see `one_line`)."""

    def __str__(self) -> str:
        return one_line(super().__str__())


class ProblemError(SurestepError):
    """A problem file is missing, malformed or describes an impossible set-up.

    The message names the file, the key path and what is allowed.
    """

    def __init__(self, file: str | None, key: str | None, message: str):
        self.file = file
        self.key = key
        where = ": ".join(shown(part, 200) for part in (file, key) if part)
        super().__init__(f"{where}: {message}" if where else message)


class ProblemErrors(ProblemError):
    """Every error found in one problem (each section of a file is read even when
    another has an error).

    `errors` holds them in the order of the file's sections, each a one-line ProblemError; `lines()`
    gives their texts, one per error, as `surestep validate` and the CLI print them. `str()` stays
    one line (the first error, then the others after it), `file` and `key` are the first error's.
    """

    def __init__(self, errors: list[ProblemError]):
        self.errors = list(errors)
        first = self.errors[0]
        more = len(self.errors) - 1
        rest = "; ".join(str(e) for e in self.errors[1:])
        SurestepError.__init__(self, f"{first} (and {more} more "
                                     f"error{'s' if more > 1 else ''}: {rest})")
        self.file, self.key = first.file, first.key

    def lines(self) -> list[str]:
        return [str(e) for e in self.errors]


def error_lines(exc: BaseException) -> list[str]:
    """An error's text as the CLI prints it: one line per error (several for ProblemErrors)."""
    return exc.lines() if isinstance(exc, ProblemErrors) else [str(exc)]


class FrameNotFound(SurestepError):
    """A frame name that the robot model does not have; lists the valid ones."""

    def __init__(self, name: str, available: list[str]):
        self.name = name
        self.available = available
        names = ", ".join(shown(a) for a in available[:40]) + (
            f", ... ({len(available)} in all)" if len(available) > 40 else "")
        super().__init__(f"frame '{shown(name)}' not in the model; available frames: {names}")


class UnsupportedJoint(SurestepError):
    """A joint type the symbolic kinematics cannot express (only 1-DoF joints are)."""


class UnreachablePose(SurestepError):
    """Inverse kinematics found no configuration inside the joint limits."""

    def __init__(self, what: str, residual_m: float, residual_rad: float):
        self.residual_m = residual_m
        self.residual_rad = residual_rad
        super().__init__(
            f"{what} is not reachable within the joint limits "
            f"(best IK residual {residual_m * 1e3:.3f} mm, {residual_rad:.4f} rad)"
        )


class SolverError(SurestepError):
    """A numerical solver failed; carries its return status and statistics."""

    def __init__(self, solver: str, status: str, stats: dict | None = None, message: str = ""):
        self.solver = solver
        self.status = status
        self.stats = stats or {}
        text = f"{solver} failed with status '{status}'"
        super().__init__(f"{text}: {message}" if message else text)
