"""The built NLPs and Newton solvers, cached per structure, and the IPOPT options they are built
with.

A built NLP (and its compiled derivatives) is kept per structure: robot, belief model, horizon,
form, smoothness, options, Hessian, codegen and the enforced motion limits (with the step time); a
new start, goal, camera pose or Sigma_0 reuses it. The Newton and interior-point solvers are kept
per thread too: they evaluate in place in buffers of their own (`buffered.py`), which two threads
(e.g. an in-process Dask cluster's workers) must not share.
"""

from __future__ import annotations

import threading

from ..model import limits as limits_module
from ..model.limits import problem_limits
from ..problem.setup import Setup
from ..problem.solver_config import resolve_form
from ..ocp.codegen import available as compiler_available
from ..ocp.codegen import compiled_or_interpreted
from .interior import InteriorNewton
from ..ocp.lifted import LiftedTranscription
from .newton import NewtonSolver
from ..ocp.transcription import Transcription

_CACHE: dict[tuple, Transcription] = {}

# IPOPT options for re-solves started from a previous primal-dual solution.
WARM_OPTIONS = {
    "ipopt.warm_start_init_point": "yes",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
    "ipopt.mu_init": 1e-6,
}


# IPOPT options for the lifted NLP started at the condensed solution (a KKT point up to tol, with
# its multipliers): a small monotone barrier (the adaptive update raised mu and walked away). With
# the structured Hessian the dual infeasibility then falls linearly while the objective stays put:
# an acceptable-level stop like ENFORCED_OPTIONS' (objective change at most 1e-9 over 3 iterations,
# constraints 1e-6, complementarity 1e-6: at 1e-9 it never triggered) ends that tail as
# Solved_To_Acceptable_Level with the same trace (the iterations measured: docs/general_models.md,
# the lifted form and its polish from the condensed solution).
LIFTED_FROM_CONDENSED = {
    "ipopt.mu_init": 1e-9,
    "ipopt.mu_strategy": "monotone",
    "ipopt.warm_start_bound_push": 1e-9,
    "ipopt.warm_start_mult_bound_push": 1e-9,
    "ipopt.acceptable_tol": 1e-3,
    "ipopt.acceptable_iter": 3,
    "ipopt.acceptable_obj_change_tol": 1e-9,
    "ipopt.acceptable_compl_inf_tol": 1e-6,
}


# IPOPT options for the NLP with enforced motion limits (`limits.enforce: true`: thousands of limit
# rows, few of them active at the optimum). MUMPS without its permuting scaling (MC64): the same
# iterations, cheaper linear algebra. Acceptable-level termination for the surrogate Hessian's
# linear tail: the objective (1 at the start) changes by at most 1e-9 in 3 consecutive iterations
# with the complementarity at 1e-9 (the barrier at its end) and the constraints within
# acceptable_constr_viol_tol (1e-6): IPOPT's status is then Solved_To_Acceptable_Level, a success,
# with the same plans. Measured at 33c5856: docs/motion_limits_and_export.md, "The enforced solve's
# speed", and docs/findings.md.
ENFORCED_OPTIONS = {
    "ipopt.mumps_permuting_scaling": 0,
    "ipopt.acceptable_tol": 1e-3,
    "ipopt.acceptable_iter": 3,
    "ipopt.acceptable_obj_change_tol": 1e-9,
    "ipopt.acceptable_compl_inf_tol": 1e-9,
}


def solver_options(setup: Setup, extra: dict | None = None) -> dict:
    prob = setup.ocp
    opts = {
        "ipopt.print_level": prob.solver.print_level,
        "print_time": False,
        "ipopt.sb": "yes",
        "ipopt.tol": prob.solver.tol,
        "ipopt.max_iter": prob.solver.max_iter,
        # The adaptive barrier update needs fewer iterations than the monotone default and avoids
        # its restoration failures (measured with the full form: docs/method.md).
        "ipopt.mu_strategy": "adaptive",
        # The terminal equality is hard: IPOPT's defaults accept a violation of 1e-4, and 1e-2 at
        # its "acceptable" level, whatever `tol` is.
        "ipopt.constr_viol_tol": min(prob.solver.tol, 1e-8),
        "ipopt.acceptable_constr_viol_tol": 1e-6,
    }
    if prob.limits.enforce:
        opts.update(ENFORCED_OPTIONS)
    opts.update({f"ipopt.{k}": v for k, v in prob.solver.options.items()})
    opts.update(extra or {})
    return opts


def transcription(setup: Setup, form: str | None = None, extra_options: dict | None = None,
                  horizon: int | None = None, hessian: str = "exact") -> Transcription:
    """The (cached) transcription for this setup's structure (form: default from the problem
    file)."""
    model = setup.model
    form = resolve_form(model, form or setup.ocp.solver.covariance)
    T = setup.ocp.horizon if horizon is None else horizon
    opts = solver_options(setup, extra_options)
    codegen = resolve_codegen(setup, hessian)
    limits = enforced_limits(setup)
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(), model.key(),
           model.scalar, T, form, setup.ocp.smoothness,
           tuple(sorted((k, repr(v)) for k, v in opts.items())), hessian, codegen,
           setup.ocp.solver.codegen is True, limits_key(limits))
    if key not in _CACHE and form == "full" and hessian == "surrogate":
        # the lifted form's structured Hessian
        _CACHE[key] = LiftedTranscription(setup.robot, model, T, setup.ocp.smoothness, opts,
                                          codegen,
                                          codegen_required=setup.ocp.solver.codegen is True)
    elif key not in _CACHE:
        _CACHE[key] = Transcription(setup.robot, model, T, form, setup.ocp.smoothness, opts,
                                    hessian, codegen,
                                    codegen_required=setup.ocp.solver.codegen is True,
                                    limits=limits)
    return _CACHE[key]


def enforced_limits(setup: Setup):
    """(step_s, MotionLimits) when the problem enforces its motion limits (`limits.enforce: true`),
    else None."""
    if not setup.ocp.limits.enforce:
        return None
    return setup.ocp.timing.step_s, problem_limits(setup)


def limits_key(limits) -> tuple | None:
    if limits is None:
        return None
    dt, lim = limits
    return (dt, tuple(lim.joint_names), lim.velocity.tobytes(), lim.acceleration.tobytes(),
            lim.tool_speed, lim.tool_rotation, lim.rcm_min_distance, limits_module.CURVE_ROWS)


def resolve_codegen(setup: Setup, hessian: str) -> bool:
    """Whether the transcription with this Hessian is compiled: `solver.codegen` true, or auto with
    a C compiler."""
    choice = setup.ocp.solver.codegen
    if hessian == "exact":
        return False
    return compiler_available() if choice == "auto" else bool(choice)


_NEWTON: dict[tuple, NewtonSolver] = {}


def newton_solver(setup: Setup, background: bool = False) -> NewtonSolver:
    """The (cached) projected Newton solver of this setup's structure (`solver.name: newton`);
    `background`: a new one's C compiled in a background thread, loaded on first use
    (`NewtonSolver.ready`)."""
    model, prob = setup.model, setup.ocp
    codegen = resolve_codegen(setup, "surrogate")
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(), model.key(),
           model.scalar, prob.horizon, prob.smoothness, codegen, prob.solver.codegen is True,
           threading.get_ident())
    if key not in _NEWTON:
        _NEWTON[key] = NewtonSolver(setup.robot, model, prob.horizon, prob.smoothness, codegen,
                                    codegen_required=prob.solver.codegen is True,
                                    background=background)
    return _NEWTON[key]


_INTERIOR: dict[tuple, InteriorNewton] = {}


def interior_solver(setup: Setup, moving: bool = False) -> InteriorNewton:
    """The (cached) interior-point Newton solver of this setup's structure with its enforced limits;
    `moving`: the plan starts in motion (a re-plan from the executed curve's state)."""
    prob = setup.ocp
    dt, lim = enforced_limits(setup)
    codegen = resolve_codegen(setup, "surrogate")
    key = (str(setup.robot.urdf), setup.robot.frame, setup.robot.offset.tobytes(),
           setup.model.key(), setup.model.scalar, prob.horizon, prob.smoothness, codegen,
           limits_key((dt, lim)), moving, threading.get_ident())
    if key not in _INTERIOR:
        required = prob.solver.codegen is True
        solver = InteriorNewton(newton_solver(setup), setup.robot, dt, lim, moving, codegen,
                                codegen_required=required)
        if codegen:
            # the robot's IK compiled too (once per robot model): the start's search and every
            # re-plan's goal solve IK
            note = setup.robot.compile_ik(lambda fns: compiled_or_interpreted(fns, required))
            solver.codegen_note = solver.codegen_note or note
        _INTERIOR[key] = solver
    return _INTERIOR[key]


def cached_transcriptions() -> list[Transcription]:
    """The transcriptions built so far in this process (e.g. to report their build times)."""
    return list(_CACHE.values())
