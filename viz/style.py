"""Colours and sizes of the 3D scene (one place, so tests and legend agree); method
colours are the PNGs'."""

from __future__ import annotations

from collections.abc import Sequence

from surestep_ocp.output.plot_styles import (
    BASE_STYLES,
    GOAL_COLOUR,
    REPLAN_STYLES,
    START_COLOUR,
    rgb_of,
    style_of,
    styles_of,
)

# Method colours come from surestep_ocp.output.plot_styles (the PNGs use the same table);
# RGB in [0, 1].
METHOD_COLORS: dict[str, tuple[float, float, float]] = {
    m: style_of(m).rgb for m in (*BASE_STYLES, *REPLAN_STYLES)}
GOAL_COLOR: tuple[float, float, float] = rgb_of(GOAL_COLOUR)  # magenta, as in the PNGs
START_COLOR: tuple[float, float, float] = rgb_of(START_COLOUR)
CAMERA_COLOR: tuple[float, float, float] = (0.25, 0.25, 0.25)  # frustum lines
FOOTPRINT_COLOR: tuple[float, float, float] = (0.35, 0.35, 0.40)  # image rectangle at d*
NEEDLE_COLOR: tuple[float, float, float] = (0.50, 0.52, 0.57)  # steel (silver, darkened)
BACKGROUND_TOP: tuple[float, float, float] = (0.97, 0.97, 0.98)
BACKGROUND_BOTTOM: tuple[float, float, float] = (0.86, 0.87, 0.90)

TUBE_RADIUS = 0.0008  # [m] radius of the drawn path tubes
ANIMATED_TUBE_SCALE = 1.25  # the animated method's tube is this much thicker (on top)
NODE_RADIUS = 0.0012  # [m] radius of the small spheres at path nodes
GOAL_RADIUS = 0.0025  # [m] radius of the goal sphere
START_RADIUS = 0.0018  # [m] radius of the start sphere
TRIAD_SCALE = 0.012  # [m] axis length of the goal and camera triads
ELLIPSOID_OPACITY = 0.3  # opacity of the 3-sigma ellipsoids up to ELLIPSOID_REF_RADIUS
ELLIPSOID_REF_RADIUS = 0.006  # [m] larger ellipsoids get fainter (opacity ~ 1 / radius)
ELLIPSOID_MIN_OPACITY = 0.04
# paths the arm does not follow show at most this many ellipsoids (the last among them) ...
OTHER_ELLIPSOIDS = 4
# ... at this fraction of the opacity, so they do not hide the other paths
OTHER_ELLIPSOID_OPACITY = 0.5
NEEDLE_TUBE_RADIUS = 0.00025  # [m] the needle is drawn 0.5 mm thick
NEEDLE_SWEEP_DEG = 270.0  # the needle is drawn as a 3/4 circle
CAMERA_HISTORY_OPACITY = (0.12, 0.35)  # frusta of earlier camera poses: first .. last
N_SIGMA = 3.0  # ellipsoid radii are N_SIGMA * sqrt(eigenvalue)


def method_colors(methods: Sequence[str]) -> dict[str, tuple[float, float, float]]:
    """Colour of each method (`surestep_ocp.output.plot_styles`: fixed by name, others from its
    palette in order)."""
    return {m: st.rgb for m, st in styles_of(methods).items()}


def rgb_int(rgb: Sequence[float]) -> int:
    """0xRRGGBB integer of an RGB triple in [0, 1] (the form meshcat materials take)."""
    r, g, b = (max(0, min(255, int(round(255 * float(c))))) for c in rgb[:3])
    return (r << 16) | (g << 8) | b
