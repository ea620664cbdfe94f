"""The method names `surestep` accepts: a base method, then optional suffixes (the one registry).

`methods.run_method` dispatches on these names, `plot_styles` gives every one of them a look and the
CLI's help lists them from here, so a new method or suffix is added in one place. Kept free of the
solvers so that the plots and the 3D scene can read it cheaply.
"""

from __future__ import annotations

from itertools import product

from .model.belief import COMPONENTS

BASE_METHODS = ("baseline", "gradient", "gradient-no-pose-loss", "ocp", "ocp-from-gradient")
# closed-loop methods: a policy, not a plan; the rollouts re-plan at every step from each rollout's
# own belief within the motion limits (evaluation/closed_loop.py); as a plan, the first one
CLOSED_LOOP_METHODS = ("ocp-mpc",)
# the bases the OCP solver flags (--solver, --hessian, ...) act on
OCP_METHODS = ("ocp", "ocp-from-gradient", *CLOSED_LOOP_METHODS)
# that observation component left out while planning
ABLATIONS = {f"-no-{c}": c for c in COMPONENTS}
EXPECTED = "-expected"  # plan with the observation noise expected under the belief
PREDICTED = "-predicted"  # minimise Tr(Sigma_T|T-1)
# written by `surestep replan`, with ocp-replan-<step>
REPLAN_METHODS = ("ocp-once", "ocp-replanned")


def split_name(name: str) -> tuple[str, str | None, bool, bool]:
    """(base, ablated component or None, -expected?, -predicted?) of a method name;
    ValueError if unknown."""
    rest = name
    predicted = rest.endswith(PREDICTED)
    rest = rest[: -len(PREDICTED)] if predicted else rest
    expected = rest.endswith(EXPECTED)
    rest = rest[: -len(EXPECTED)] if expected else rest
    bases = (*BASE_METHODS, *CLOSED_LOOP_METHODS)
    for suffix, comp in ABLATIONS.items():
        if rest.endswith(suffix) and rest[: -len(suffix)] in bases:
            return rest[: -len(suffix)], comp, expected, predicted
    if rest in bases:
        return rest, None, expected, predicted
    raise ValueError(f"unknown method '{name}'; allowed: {grammar()}")


def grammar() -> str:
    """The accepted names in one line (for help texts and error messages)."""
    return (f"{' | '.join((*BASE_METHODS, *CLOSED_LOOP_METHODS))}, optionally followed by "
            f"{' | '.join(ABLATIONS)}, "
            f"then {EXPECTED}, then {PREDICTED}")


def all_names() -> list[str]:
    """Every name `split_name` accepts, grouped by base method."""
    return [b + a + e + p for b, a, e, p
            in product((*BASE_METHODS, *CLOSED_LOOP_METHODS), ("", *ABLATIONS), ("", EXPECTED),
                       ("", PREDICTED))]


def is_closed_loop(name: str) -> bool:
    """Whether the method name is a closed-loop method (`CLOSED_LOOP_METHODS` and its variants)."""
    return split_name(name)[0] in CLOSED_LOOP_METHODS
