"""The typed record of one solver attempt, as a Solution lists them (`Solution.attempts`).

Written to the solution file as a mapping under `attempts` (docs/solution_file.md); files written
before the records were typed (the attempt's label under `hessian`, no `solver` key) are read too.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class AttemptRecord:
    """One attempt of the solve strategy: which backend ran, with which Hessian, how it ended."""

    # the strategy's name for it, e.g. "surrogate, monotone barrier", "newton, warm start"
    label: str
    solver: str  # the backend: newton | ipopt | none (the kept initial guess)
    hessian: str | None  # exact | surrogate | gauss-newton; None for Newton and the kept guess
    status: str
    iterations: int
    solve_time_s: float
    objective: float
    kept: bool  # the plan returned is this attempt's
    compiled: bool  # its derivatives were compiled to C

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> AttemptRecord:
        """A record from a solution file, this format or the untyped one before it."""
        if "label" in d:
            return cls(**{k: d[k] for k in cls.__dataclass_fields__})
        label = str(d["hessian"])  # the untyped format: the label under "hessian"
        solver = ("none" if label.startswith("none") else "newton" if label.startswith("newton")
                  else "ipopt")
        first = label.split(",")[0].split(" ")[0]
        hessian = first if first in ("exact", "surrogate", "gauss-newton") else None
        return cls(label, solver, hessian, str(d["status"]), int(d["iterations"]),
                   float(d["solve_time_s"]),
                   float(d["objective"]), bool(d["kept"]), bool(d.get("compiled", False)))
