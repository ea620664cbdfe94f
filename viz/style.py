"""Colours and sizes of the visualisation (one place, so tests and legend agree)."""

from __future__ import annotations

from typing import Sequence

# Fixed colour per method (RGB in [0, 1]); unknown methods take the palette in order.
METHOD_COLORS: dict[str, tuple[float, float, float]] = {
    "baseline": (0.839, 0.153, 0.157),  # red
    "gradient": (1.000, 0.498, 0.055),  # orange
    "ocp": (0.122, 0.467, 0.706),  # blue
    "ocp-replanned": (0.090, 0.170, 0.420),  # navy (`surestep replan`'s executed plan)
}
PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.580, 0.404, 0.741),  # purple
    (0.549, 0.337, 0.294),  # brown
    (0.090, 0.745, 0.812),  # cyan
    (0.737, 0.741, 0.133),  # olive
    (0.890, 0.467, 0.761),  # pink
    (0.000, 0.400, 0.400),  # dark teal
    (0.600, 0.100, 0.400),  # plum
)
GOAL_COLOR: tuple[float, float, float] = (0.85, 0.10, 0.75)  # magenta
CAMERA_COLOR: tuple[float, float, float] = (0.25, 0.25, 0.25)  # frustum lines
FOOTPRINT_COLOR: tuple[float, float, float] = (0.35, 0.35, 0.40)  # image rectangle at d*
NEEDLE_COLOR: tuple[float, float, float] = (0.50, 0.52, 0.57)  # steel (silver, darkened)
BACKGROUND_TOP: tuple[float, float, float] = (0.97, 0.97, 0.98)
BACKGROUND_BOTTOM: tuple[float, float, float] = (0.86, 0.87, 0.90)

TUBE_RADIUS = 0.0008  # [m] radius of the drawn path tubes
ANIMATED_TUBE_SCALE = 1.25  # the animated method's tube is this much thicker (on top)
NODE_RADIUS = 0.0012  # [m] radius of the small spheres at path nodes
GOAL_RADIUS = 0.0025  # [m] radius of the goal sphere
TRIAD_SCALE = 0.012  # [m] axis length of the goal and camera triads
ELLIPSOID_OPACITY = 0.3  # opacity of the 3-sigma ellipsoids up to ELLIPSOID_REF_RADIUS
ELLIPSOID_REF_RADIUS = 0.006  # [m] larger ellipsoids get fainter (opacity ~ 1 / radius)
ELLIPSOID_MIN_OPACITY = 0.04
NEEDLE_TUBE_RADIUS = 0.00025  # [m] the needle is drawn 0.5 mm thick
NEEDLE_SWEEP_DEG = 270.0  # the needle is drawn as a 3/4 circle
CAMERA_HISTORY_OPACITY = (0.12, 0.35)  # frusta of earlier camera poses: first .. last
N_SIGMA = 3.0  # ellipsoid radii are N_SIGMA * sqrt(eigenvalue)


def method_colors(methods: Sequence[str]) -> dict[str, tuple[float, float, float]]:
    """Colour of each method: the fixed ones by name, others from PALETTE in order."""
    out: dict[str, tuple[float, float, float]] = {}
    k = 0
    for m in methods:
        if m in METHOD_COLORS:
            out[m] = METHOD_COLORS[m]
        else:
            out[m] = PALETTE[k % len(PALETTE)]
            k += 1
    return out


def rgb_int(rgb: Sequence[float]) -> int:
    """0xRRGGBB integer of an RGB triple in [0, 1] (the form meshcat materials take)."""
    r, g, b = (max(0, min(255, int(round(255 * float(c))))) for c in rgb[:3])
    return (r << 16) | (g << 8) | b
