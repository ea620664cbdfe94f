"""The `solver:` choices as enums and every rule on how they combine, in one place.

A problem's solver section names a solver, a covariance form, a Hessian and whether derivatives are
compiled; which combinations work depends on the belief model (its maps and noise form) and on the
robot (how many joints move the tracked frame). `resolve` turns the choices into what runs
(`ResolvedSolver`) or raises a `ProblemError` naming the key: the loader calls it when a problem is
read and set up, `solve` once more for a method's variant of the model (`-expected`, `-predicted`),
never in the middle of a solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from ..errors import ProblemError
from ..model.belief import NX, BeliefModel


class SolverName(str, Enum):
    """`solver.name`: which solver runs first."""

    # Newton where it applies (projected; interior-point with enforced limits), else IPOPT
    AUTO = "auto"
    IPOPT = "ipopt"
    NEWTON = "newton"
    # the interior-point Newton method (enforced limits only), IPOPT its fallback
    INTERIOR = "interior"


class Form(str, Enum):
    """`solver.covariance`: how the covariance enters the NLP (docs/method.md)."""

    AUTO = "auto"
    FULL = "full"
    DIAGONAL = "diagonal"
    CONDENSED = "condensed"


class Hessian(str, Enum):
    """`solver.hessian`: the Hessian of the Lagrangian IPOPT uses (auto: by the model)."""

    AUTO = "auto"
    EXACT = "exact"
    SURROGATE = "surrogate"
    GAUSS_NEWTON = "gauss-newton"


FORMS = tuple(f.value for f in Form)
HESSIANS = tuple(h.value for h in Hessian if h is not Hessian.AUTO)  # what an NLP is built with
SOLVER_NAMES = tuple(s.value for s in SolverName)

CODEGEN_EXACT = ("solver.codegen: true compiles the stage-wise derivatives of the surrogate and "
                 "Gauss-Newton Hessians only (the exact condensed Hessian did not compile within "
                 "10 minutes); use solver.hessian: auto, surrogate or gauss-newton, or codegen: "
                 "auto or false")


@dataclass(frozen=True)
class ResolvedSolver:
    """The solver choices resolved for one model and robot: what the strategy runs."""

    name: SolverName
    form: str  # condensed | full | diagonal
    hessian: str  # exact | surrogate | gauss-newton
    forced: bool  # the Hessian was named (surrogate or gauss-newton): no exact-Hessian attempts
    newton_fits: bool  # the projected Newton solver's reformulation is exact here


def resolve_form(model: BeliefModel, form: str, file: str | None = None) -> str:
    """`solver.covariance` for this model: auto is condensed for a structured or scalar
    model, else full."""
    if form not in FORMS:
        raise ProblemError(file, "solver.covariance", f"unknown covariance form '{form}'; "
                           f"allowed: {', '.join(FORMS)}")
    if form == Form.AUTO:
        return Form.CONDENSED.value if model.scalar or model.structured else Form.FULL.value
    if form == Form.DIAGONAL and not model.diagonal:
        raise ProblemError(file, "solver.covariance", "the diagonal form is exact only with "
                           "identity motion/observation maps and diagonal base covariances; use "
                           "full, condensed or auto")
    return form


def resolve_hessian(model: BeliefModel, form: str, choice: str, file: str | None = None) -> str:
    """`solver.hessian` for this model and form: the surrogate where the model is structured
    (the condensed form, or the lifted form's structured Hessian for Tr(Sigma_T|T)), the exact
    Hessian elsewhere."""
    possible = form == Form.CONDENSED and model.structured
    if (form == Form.FULL and model.structured and model.noise.objective == "posterior"
            and choice in ("auto", "surrogate")):
        return Hessian.SURROGATE.value  # the lifted form's structured Hessian (lifted.py)
    if choice in (Hessian.SURROGATE, Hessian.GAUSS_NEWTON) and not possible:
        raise ProblemError(file, "solver.hessian", f"{choice} needs a model with constant "
                           "motion/observation maps and noise.observation_noise: mean "
                           "(gauss-newton: the condensed form); use exact or auto")
    if choice == Hessian.AUTO:
        return Hessian.SURROGATE.value if possible else Hessian.EXACT.value
    return choice


def resolve(spec, model: BeliefModel, moving_joints: int | None, form: str | None = None,
            file: str | None = None, limited: bool = True) -> ResolvedSolver:
    """Every rule on the solver choices `spec` (a SolverSpec) for a model and a robot with
    `moving_joints` joints moving the tracked frame (None: no robot yet, as when a file is read: the
    robot's rule is checked when the problem is set up); `form` overrides `spec.covariance`;
    `limited`: the problem enforces its motion limits. Raises ProblemError naming the key."""
    if spec.name not in SOLVER_NAMES:
        raise ProblemError(file, "solver.name", f"unknown solver '{spec.name}'; "
                                                f"allowed: {', '.join(SOLVER_NAMES)}")
    if spec.hessian not in (Hessian.AUTO, *HESSIANS):
        raise ProblemError(file, "solver.hessian", f"unknown Hessian '{spec.hessian}'; allowed: "
                           f"auto, {', '.join(HESSIANS)}")
    if spec.codegen not in (True, False, "auto") or not isinstance(spec.codegen, (bool, str)):
        raise ProblemError(file, "solver.codegen", "expected true, false or auto, "
                           f"got {spec.codegen!r}")
    if (model.noise.objective == "predicted"
            and (form or spec.covariance) not in (Form.AUTO, Form.CONDENSED)):
        raise ProblemError(file, "objective.covariance", "predicted needs solver.covariance: "
                           "condensed (or auto)")
    form = resolve_form(model, form or spec.covariance, file)
    if model.noise.objective == "predicted" and form != Form.CONDENSED:
        raise ProblemError(file, "objective.covariance", "predicted needs solver.covariance: "
                           "condensed (or auto)")
    hessian = resolve_hessian(model, form, spec.hessian, file)
    if form == Form.FULL and hessian == Hessian.SURROGATE and model.joint_noise:
        raise ProblemError(file, "noise.joint_motion_sigma", "the lifted form's structured Hessian "
                           "takes its noise coefficients from the means alone; use "
                           "solver.covariance: condensed (or auto)")
    if spec.codegen is True and hessian == Hessian.EXACT:
        raise ProblemError(file, "solver.codegen", CODEGEN_EXACT.split(": ", 1)[1])
    forced = spec.hessian in (Hessian.SURROGATE, Hessian.GAUSS_NEWTON)
    # exact when the terminal pose fixes the last node's joints (six joints move the tracked
    # frame): the surrogate model's condensed scalar recursion with the mean noise; a
    # redundant arm keeps IPOPT
    fits = (form == Form.CONDENSED and hessian != Hessian.EXACT and not forced
            and moving_joints in (NX, None))
    if spec.name == SolverName.INTERIOR and not (fits and limited):
        raise ProblemError(file, "solver.name", "interior needs limits.enforce: true and what "
                           "newton needs: the condensed form of a model with constant motion and "
                           "observation maps, noise.observation_noise: mean, solver.hessian: auto "
                           "and six joints moving the tracked frame; use solver.name: auto or "
                           "ipopt")
    if spec.name == SolverName.NEWTON and not fits:
        raise ProblemError(file, "solver.name", "newton needs the condensed form of a model with "
                           "constant motion and observation maps, noise.observation_noise: mean, "
                           "solver.hessian: auto and exactly six joints moving the tracked frame "
                           "(the goal pose then fixes the last joints); use solver.name: auto or "
                           "ipopt")
    return ResolvedSolver(SolverName(spec.name), form, hessian, forced, fits)
