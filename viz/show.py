"""`surestep show`: write the scene as static HTML, or serve it live with Meshcat."""

from __future__ import annotations

import argparse
import signal
import tempfile
import threading
import time
import webbrowser
from pathlib import Path
from typing import Sequence, Union

from .scene import build_scene, write_static_html
from .solutions import Solution, load_solutions

Target = Union[Path, str, Solution, Sequence[Solution]]


def as_solutions(target: Target) -> list[Solution]:
    """Solutions from a solution file, a directory of them, one dict or a list of dicts."""
    if isinstance(target, dict):
        return [target]
    if isinstance(target, (str, Path)):
        return load_solutions(Path(target))
    return list(target)


def serve(
    solutions: Sequence[Solution],
    open_browser: bool = False,
    endoscope_view: bool = False,
    repo_root: Path | None = None,
    animate: str | None = None,
    zmq_url: str | None = None,
):
    """Start (or connect to) a Meshcat server on loopback and draw the scene into it.

    Returns `(vis, info)`; the server subprocess lives as long as this process
    (meshcat registers its cleanup with `atexit`). `zmq_url` connects to an already
    running `meshcat-server` instead of starting one.
    """
    import meshcat

    vis = meshcat.Visualizer(zmq_url=zmq_url)
    info = build_scene(solutions, repo_root=repo_root, vis=vis, animate=animate,
                       endoscope=endoscope_view)
    if open_browser:
        webbrowser.open(vis.url(), new=2)
    return vis, info


def show(
    target: Target,
    open_browser: bool = False,
    html: Path | str | None = None,
    endoscope_view: bool = False,
    repo_root: Path | None = None,
    animate: str | None = None,
    block: bool = True,
    solutions: Sequence[Solution] | None = None,
    screenshot: Path | str | None = None,
    screenshot_size: Sequence[int] = (1280, 800),
) -> int:
    """Show solutions: static HTML if `html` is given, a PNG if `screenshot` is, else a
    live Meshcat server; return 0.

    Args:
        target: solution JSON file, directory of them (comparison.json ignored), or
            solution dict(s) (e.g. a baseline the CLI just solved from a problem YAML).
        open_browser: open the page (the HTML file or the server URL) in a browser.
        html: output file for the standalone page; no server is started then.
        endoscope_view: start from the endoscope's point of view.
        repo_root: folder the solutions' `urdf` paths are relative to.
        animate: method the arm follows (default "ocp", else "ocp-replanned", else the
            first).
        block: in server mode, keep serving until Ctrl-C (False returns at once; the
            server lives until this process exits).
        solutions: solution dicts to show instead of loading `target` (e.g. when the
            target is a problem YAML the caller solved first).
        screenshot: PNG to write: the static page (`html`, or a temporary file)
            rendered by headless Chromium (see `screenshot.screenshot_html`); no
            server is started. Raises `SurestepError` if Chromium fails.
        screenshot_size: (width, height) of the PNG [px].
    """
    sols = list(solutions) if solutions is not None else as_solutions(target)
    if screenshot is not None:
        return _screenshot(sols, Path(screenshot), html, screenshot_size, open_browser,
                           repo_root=repo_root, animate=animate, endoscope=endoscope_view)
    if html is not None:
        out = Path(html)
        info = write_static_html(sols, out, repo_root=repo_root, animate=animate,
                                 endoscope=endoscope_view)
        print(f"wrote {out} ({', '.join(info.paths)})")
        if open_browser:
            webbrowser.open(out.resolve().as_uri(), new=2)
        return 0
    vis, info = serve(sols, open_browser, endoscope_view, repo_root, animate)
    print(f"Meshcat scene ({', '.join(info.paths)}) at {vis.url()}")
    if block:
        print("Serving; press Ctrl-C to stop.")
        _stop_on_sigterm()
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            print("stopped")
    return 0


def _screenshot(sols: Sequence[Solution], png: Path, html: Path | str | None,
                size: Sequence[int], open_browser: bool, **scene_kwargs) -> int:
    """Write the static page (to `html`, or a temporary file) and screenshot it to `png`."""
    from .screenshot import screenshot_html

    with tempfile.TemporaryDirectory(prefix="surestep-show-") as tmp:
        page = Path(html) if html is not None else Path(tmp) / "scene.html"
        info = write_static_html(sols, page, **scene_kwargs)
        if html is not None:
            print(f"wrote {page} ({', '.join(info.paths)})")
        screenshot_html(page, png, size=size)
    print(f"wrote {png} ({', '.join(info.paths)})")
    if open_browser:
        webbrowser.open(png.resolve().as_uri(), new=2)
    return 0


def _stop_on_sigterm() -> None:
    """Turn SIGTERM into KeyboardInterrupt so meshcat's atexit cleanup stops its server."""
    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the `show` options (target, --open, --html, --screenshot, --endoscope-view,
    --animate)."""
    parser.add_argument("target", type=Path, help="solution JSON or directory of them")
    parser.add_argument("--open", dest="open_browser", action="store_true",
                        help="open a browser")
    parser.add_argument("--html", type=Path, default=None,
                        help="write a standalone HTML file instead of serving")
    parser.add_argument("--screenshot", type=Path, default=None, metavar="PNG",
                        help="render the static page with headless Chromium to a PNG")
    parser.add_argument("--endoscope-view", action="store_true",
                        help="start from the endoscope's view")
    parser.add_argument("--animate", default=None,
                        help="method the arm follows (default ocp, else ocp-replanned)")


def show_main(args: argparse.Namespace, solutions: Sequence[Solution] | None = None) -> int:
    """Run `show` from parsed CLI arguments (see `add_arguments`); return an exit code.

    `solutions`, when given, replaces loading `args.target` (e.g. the CLI solved a
    problem YAML first).
    """
    html = getattr(args, "html", None)
    png = getattr(args, "screenshot", None)
    return show(
        args.target,
        open_browser=bool(getattr(args, "open_browser", getattr(args, "open", False))),
        html=Path(html) if html else None,
        endoscope_view=bool(getattr(args, "endoscope_view", False)),
        animate=getattr(args, "animate", None),
        solutions=solutions,
        screenshot=Path(png) if png else None,
    )
