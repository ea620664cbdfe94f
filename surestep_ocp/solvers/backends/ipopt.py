"""IPOPT (through CasADi) on the multiple-shooting NLP: the condensed, gain-lifted and diagonal
transcriptions (`transcription.py`) and the lifted vech(Sigma) form with the structured Hessian
(`lifted.py`)."""

from __future__ import annotations

from ...problem.solver_config import SolverName
from ...ocp.iterate import InitialGuess, Iterate
from ..nlp_cache import WARM_OPTIONS, transcription
from .base import Context, Outcome


class IpoptBackend:
    """Any model, form and Hessian; the motion limits as constraint rows; warm starts from a
    primal-dual point."""

    name = SolverName.IPOPT

    def applies(self, ctx: Context) -> str | None:
        return None

    def solve(self, ctx: Context, start: InitialGuess, warm: Iterate | None, hessian: str | None,
              options: dict) -> Outcome:
        dual = warm.dual if warm is not None else None
        extra = {**options, **WARM_OPTIONS} if dual is not None else dict(options)
        nlp = transcription(ctx.setup, ctx.resolved.form, {**ctx.options, **extra}, hessian=hessian)
        sol, reached = nlp.solve(ctx.setup, start, ctx.method, warm=dual)
        return Outcome(sol, Iterate(sol.joints, reached),
                       lambda init: nlp.start_solution(ctx.setup, init, ctx.method))
