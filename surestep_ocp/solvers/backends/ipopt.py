"""IPOPT (through CasADi) on the multiple-shooting NLP: the condensed, gain-lifted and diagonal
transcriptions (`transcription.py`) and the lifted vech(Sigma) form with the structured Hessian
(`lifted.py`)."""

from __future__ import annotations

from ...problem.solver_config import SolverName
from ...ocp.iterate import InitialGuess, Iterate
from ..nlp_cache import LIFTED_FROM_CONDENSED, WARM_OPTIONS, transcription
from .base import Backend, Context, Handles, Outcome, Warm


class IpoptBackend(Backend):
    """Any model, form and Hessian; the motion limits as constraint rows; warm starts from a
    primal-dual point.

    Options: `max_iter`; `barrier_update` ("monotone": IPOPT's `mu_strategy`); `near_start` (the
    start is a KKT point with multipliers, e.g. the lifted NLP from the condensed solution:
    `LIFTED_FROM_CONDENSED`'s small monotone barrier)."""

    name = SolverName.IPOPT
    label = "ipopt"
    handles = Handles(limits=True, any_model=True, warm=Warm.PRIMAL_DUAL,
                      options=frozenset({"max_iter", "barrier_update", "near_start"}))

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        dual = warm.dual if warm is not None else None
        options = ipopt_options(options)
        extra = {**options, **WARM_OPTIONS} if dual is not None else dict(options)
        nlp = transcription(ctx.setup, ctx.resolved.form, {**ctx.options, **extra}, hessian=hessian)
        sol, reached = nlp.solve(ctx.setup, start, ctx.method, warm=dual)
        return Outcome(sol, Iterate(sol.joints, reached),
                       lambda init: nlp.start_solution(ctx.setup, init, ctx.method))


def ipopt_options(options: dict) -> dict:
    """An attempt's options (`IpoptBackend`'s) in IPOPT's words; a ValueError for any other (the
    caller's raw IPOPT options go in `Context.options`)."""
    unknown = set(options) - IpoptBackend.handles.options
    if unknown:
        raise ValueError(f"IPOPT attempt options {sorted(unknown)}: it takes "
                         f"{sorted(IpoptBackend.handles.options)}")
    out = dict(LIFTED_FROM_CONDENSED) if options.get("near_start") else {}
    if "max_iter" in options:
        out["ipopt.max_iter"] = options["max_iter"]
    if options.get("barrier_update"):
        out["ipopt.mu_strategy"] = options["barrier_update"]
    return out
