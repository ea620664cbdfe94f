"""One look per method name (colour, marker, line style), shared by every PNG and the 3D scene.

Each base method (`method_grammar.BASE_METHODS`, `CLOSED_LOOP_METHODS`) and each `surestep replan`
name has a fixed colour and marker. A variant keeps its base's marker: an ablation suffix shades the
colour and hollows the marker, `-expected` / `-predicted` shade it again and change the line style,
so every accepted name looks unlike every other. Names outside the grammar (`ocp-replan-<step>`,
hand-made files) take PALETTE in order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..method_grammar import ABLATIONS, REPLAN_METHODS, split_name


@dataclass(frozen=True)
class MethodStyle:
    """How one method is drawn: `colour` "#rrggbb", a matplotlib `marker` and `linestyle`, line
    `width` and marker `size` [pt] (a method that others often cover is drawn wider, so it
    shows around them)."""

    colour: str
    marker: str
    linestyle: str | tuple = "-"
    filled: bool = True
    width: float = 1.6
    size: float = 5.0

    @property
    def rgb(self) -> tuple[float, float, float]:
        """The colour as RGB in [0, 1] (the form the 3D scene takes)."""
        return rgb_of(self.colour)

    def line(self, **extra) -> dict:
        """Keyword arguments for `Axes.plot` (slightly transparent, so overlapping paths show)."""
        face = self.colour if self.filled else "none"
        return {"color": self.colour, "marker": self.marker, "linestyle": self.linestyle,
                "lw": self.width, "ms": self.size, "markerfacecolor": face,
                "markeredgecolor": self.colour, "alpha": 0.85, **extra}


BASE_STYLES: dict[str, MethodStyle] = {
    "baseline": MethodStyle("#d62728", "s"),  # red
    "gradient": MethodStyle("#ff7f0e", "^"),  # orange
    "gradient-no-pose-loss": MethodStyle("#9467bd", "v"),  # purple
    # blue, wide: ocp-from-gradient often covers it
    "ocp": MethodStyle("#1f77b4", "o", width=3.2, size=8.0),
    # green, dashed, on top
    "ocp-from-gradient": MethodStyle("#2ca02c", "D", "--", width=1.4, size=4.0),
    # the closed loop (its rollouts re-plan at every step), dark teal
    "ocp-mpc": MethodStyle("#006d77", "*", size=7.0),
}
REPLAN_STYLES: dict[str, MethodStyle] = dict(zip(REPLAN_METHODS, (
    MethodStyle("#8c564b", "P"),  # ocp-once, brown: planned once, executed while the camera moves
    MethodStyle("#172b6b", "o"),  # ocp-replanned, navy: the executed re-planned trajectory
)))
PALETTE = ("#17becf", "#bcbd22", "#e377c2", "#006666", "#991a66", "#7f7f7f", "#aec7e8")
FALLBACK_MARKER = "X"
START_COLOUR = "#000000"  # start marker (circle) in the PNGs and the 3D scene
GOAL_COLOUR = "#d91abf"  # goal marker (star in the PNGs, sphere and triad in 3D), magenta

# darker / lighter per ablated component
_SHADES = dict(zip(ABLATIONS.values(), (-0.35, 0.35, 0.6)))
_EXPECTED_SHADE, _PREDICTED_SHADE = -0.25, 0.25
_LINESTYLES = {(True, False): "-.", (False, True): ":", (True, True): (0, (3, 1, 1, 1, 1, 1))}


def rgb_of(colour: str) -> tuple[float, float, float]:
    """RGB in [0, 1] of a "#rrggbb" colour."""
    return tuple(int(colour[i:i + 2], 16) / 255 for i in (1, 3, 5))


def _shade(colour: str, amount: float) -> str:
    """`colour` mixed with black (amount < 0) or white (amount > 0)."""
    mixed = [c * (1 + amount) if amount < 0 else c + (1 - c) * amount for c in rgb_of(colour)]
    return "#" + "".join(f"{round(255 * c):02x}" for c in mixed)


def style_of(method: str, order: Sequence[str] = ()) -> MethodStyle:
    """The style of `method`; a name outside the grammar takes PALETTE by its place among such
    names in `order`."""
    if method in REPLAN_STYLES:
        return REPLAN_STYLES[method]
    try:
        base, ablated, expected, predicted = split_name(method)
    except ValueError:
        others = [m for m in dict.fromkeys([*order, method]) if not known(m)]
        return MethodStyle(PALETTE[others.index(method) % len(PALETTE)], FALLBACK_MARKER)
    s = BASE_STYLES[base]
    colour = s.colour
    for shade, applies in ((_SHADES.get(ablated), ablated), (_EXPECTED_SHADE, expected),
                           (_PREDICTED_SHADE, predicted)):
        colour = _shade(colour, shade) if applies else colour
    return MethodStyle(colour, s.marker, _LINESTYLES.get((expected, predicted), s.linestyle),
                       ablated is None, s.width, s.size)


def known(method: str) -> bool:
    """Whether `method` has a fixed style (a name of the grammar or of `surestep replan`)."""
    if method in REPLAN_STYLES:
        return True
    try:
        split_name(method)
    except ValueError:
        return False
    return True


def styles_of(methods: Sequence[str]) -> dict[str, MethodStyle]:
    """The style of each method of a figure or scene (unknown names numbered in this order)."""
    return {m: style_of(m, methods) for m in methods}
