"""The legend of the static Meshcat page: an HTML box over the viewer (Meshcat has none of its own).

One entry per drawn method in its colour (`data-method` names it, for tests), then the start, the
goal, the ellipsoids and the camera. Built from the SceneInfo, so it lists exactly what was drawn.
"""

from __future__ import annotations

from html import escape

from . import style

_BOX = ("position:absolute;top:8px;left:8px;z-index:10;background:rgba(255,255,255,0.85);"
        "padding:6px 10px;border-radius:4px;font:12px/1.45 sans-serif;color:#222;max-width:300px;"
        "pointer-events:none")


def _hex(rgb) -> str:
    return f"#{style.rgb_int(rgb):06x}"


def _entry(mark: str, text: str, method: str | None = None) -> str:
    attr = (f' class="surestep-legend-method" data-method="{escape(method)}"' if method is not None
            else "")
    return f'<div{attr}>{mark} {text}</div>'


def _bar(rgb) -> str:
    return (f'<span style="display:inline-block;width:22px;height:5px;vertical-align:middle;'
            f'background:{_hex(rgb)}"></span>')


def _dot(rgb) -> str:
    return ('<span style="display:inline-block;width:9px;height:9px;margin:0 6px;'
            f'border-radius:50%;vertical-align:middle;background:{_hex(rgb)}"></span>')


def legend_html(info) -> str:
    """The legend box for a built scene (`scene.SceneInfo`)."""
    rows = [_entry(_bar(p.color),
                   escape(m) + (" (the arm follows it)" if m == info.animated else ""), m)
            for m, p in info.paths.items()]
    if info.start is not None:
        rows.append(_entry(_dot(style.START_COLOR), "start"))
    if info.goal is not None:
        rows.append(_entry(_dot(style.GOAL_COLOR), "goal (sphere and axes)"))
    rows.append(_entry("", f"spheres: {style.N_SIGMA:g}-sigma position ellipsoids of Sigma_t|t, in "
                           "the path's colour (the followed path at every step, the others "
                           f"at {style.OTHER_ELLIPSOIDS} steps, fainter; any wider than the image "
                           "starts hidden: Open Controls, Scene)"))
    rows.append(_entry("", "black lines: the endoscope's view frustum; grey rectangle: its image "
                           "at the ideal depth d*"))
    return f'<div id="surestep-legend" style="{_BOX}"><b>SURESTEP</b>{"".join(rows)}</div>'
