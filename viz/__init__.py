"""Meshcat visualisation of SURESTEP solutions (optional dependency: meshcat).

Importing this package does not import meshcat; the names below load on first use:

    load_solutions(path) -> list[dict]
    build_scene(solutions, repo_root=None, vis=None, animate=None, endoscope=False, ...)
        -> SceneInfo
    write_static_html(solutions, path, repo_root=None, **kwargs) -> SceneInfo
    set_endoscope_view(vis, camera_pose, intrinsics, depth=0.15) -> CameraView
    show(target, open_browser=False, html=None, endoscope_view=False, ...) -> SceneInfo
    show_main(args, solutions=None) -> int ;  add_arguments(parser)
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "load_solutions": "solutions",
    "build_scene": "scene",
    "write_static_html": "scene",
    "SceneInfo": "scene",
    "PathInfo": "paths",
    "set_endoscope_view": "view",
    "set_camera_view": "view",
    "CameraView": "view",
    "RecordingWindow": "recorder",
    "recording_visualizer": "recorder",
    "show": "show",
    "show_main": "show",
    "serve": "show",
    "add_arguments": "show",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    """Import the submodule defining `name` on first access (keeps meshcat optional)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    globals()[name] = value
    return value
