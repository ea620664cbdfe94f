"""`surestep show`: write the scene as static HTML, or serve it live with Meshcat."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import signal
import sys
import tempfile
import threading
import time
import warnings
import webbrowser
from pathlib import Path
from typing import Sequence, Union

import meshcat

from surestep_ocp.errors import SurestepError, shown
from surestep_ocp.output.files import check_output_file
from surestep_ocp.quiet import quiet_fd

from . import server
from .scene import build_scene, write_static_html
from .screenshot import screenshot_html
from .solutions import Solution, load_solutions

Target = Union[Path, str, Solution, Sequence[Solution]]


def as_solutions(target: Target) -> list[Solution]:
    """Solutions from a solution file, a directory of them, one dict or a list of dicts."""
    if isinstance(target, dict):
        return [target]
    if isinstance(target, (str, Path)):
        path = Path(target)
        name = shown(str(path), 200)
        try:
            sols = load_solutions(path)
        except FileNotFoundError as exc:
            raise SurestepError(f"{name}: {shown(exc.strerror or str(exc), 200)}") from None
        except UnicodeDecodeError as exc:
            raise SurestepError(f"{name}: not a solution file (not UTF-8 text: invalid byte at "
                                f"offset {exc.start})") from None
        except json.JSONDecodeError as exc:
            what = ("empty" if not exc.doc.strip()
                    else f"not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}")
            raise SurestepError(f"{name}: not a solution file ({what})") from None
        except (ValueError, RecursionError) as exc:
            raise SurestepError(f"{name}: not a solution file ({shown(str(exc), 200)})") from None
        except OSError as exc:
            raise SurestepError(f"{name}: cannot read it ({exc.strerror or exc})") from None
        if not sols:
            raise SurestepError(f"{name}: holds no solution (a JSON object with 'poses')")
        for sol in sols:
            check_solution(sol)
        return sols
    return list(target)


# The problem reader's ranges (surestep_ocp/problem/parse.py, problems/README.md "Limits"), kept
# here so that the viz package does not import the problem reader (and CasADi with it).
MAX_POSITION = 100.0  # [m] any position (poses, points, translations)
MAX_ANGLE = 1000.0  # [rad] any angle, axis-angle or joint value [rad or m]
MAX_FOCAL = 1e6  # [px]
MAX_IMAGE = 100_000  # [px] image width and height
MAX_VARIANCE = 1e6  # covariance entries
MAX_WAYPOINTS = 10_000  # poses, q, sigma, camera_poses
RIGID_TOL = 1e-6  # a rotation block's distance from orthonormal


def _numbers(value, shape: tuple[int, ...], limit: float = math.inf) -> bool:
    """Whether `value` is a nested list of finite numbers of exactly this shape, each within
    +-`limit`."""
    if not shape:
        return (isinstance(value, (int, float)) and not isinstance(value, bool)
                and math.isfinite(value) and abs(value) <= limit)
    return (isinstance(value, list) and len(value) == shape[0]
            and all(_numbers(v, shape[1:], limit) for v in value))


def _pose6(value) -> bool:
    """[px, py, pz, rx, ry, rz]: a position within MAX_POSITION, an axis-angle within MAX_ANGLE."""
    return (_numbers(value, (6,)) and all(abs(v) <= MAX_POSITION for v in value[:3])
            and all(abs(v) <= MAX_ANGLE for v in value[3:]))


def _rigid(value) -> bool:
    """A 4x4 rigid transform: orthonormal rotation (det +1), last row 0 0 0 1, translation within
    MAX_POSITION."""
    if not _numbers(value, (4, 4), 1e12):
        return False
    T = [[float(x) for x in row] for row in value]
    R = [row[:3] for row in T[:3]]
    for i in range(3):
        for j in range(3):
            dot = sum(R[k][i] * R[k][j] for k in range(3))
            if abs(dot - (1.0 if i == j else 0.0)) > RIGID_TOL:
                return False
    det = (R[0][0] * (R[1][1] * R[2][2] - R[1][2] * R[2][1])
           - R[0][1] * (R[1][0] * R[2][2] - R[1][2] * R[2][0])
           + R[0][2] * (R[1][0] * R[2][1] - R[1][1] * R[2][0]))
    return (det > 0 and all(abs(a - b) <= RIGID_TOL for a, b in zip(T[3], (0, 0, 0, 1)))
            and all(abs(T[i][3]) <= MAX_POSITION for i in range(3)))


RIGID_TEXT = ("must be a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1, "
              f"translation within {MAX_POSITION:g} m)")


def check_solution(sol: Solution) -> None:
    """Raise a one-line SurestepError unless `sol` has what the scene reads, of the right shapes,
    every number finite and within the problem reader's ranges (positions within 100 m, focal
    lengths in [1, 1e6] px, rigid poses)."""
    src = shown(str(sol.get("_source", "a solution")), 200)

    def bad(key: str, what: str):
        return SurestepError(f"{src}: not a usable solution file: '{key}' {what}")

    poses = sol.get("poses")
    if not isinstance(poses, list) or not poses:
        raise bad("poses", "must be a non-empty list of [px, py, pz, rx, ry, rz] (or null)")
    if len(poses) > MAX_WAYPOINTS:
        raise bad("poses", f"lists {len(poses)} waypoints; at most {MAX_WAYPOINTS} are shown")
    for t, p in enumerate(poses):
        if p is not None and not _pose6(p):
            raise bad(f"poses[{t}]", "must be 6 finite numbers "
                                     f"(a position within {MAX_POSITION:g} m, an "
                                     f"axis-angle within {MAX_ANGLE:g} rad) or null")
    if "camera_pose" not in sol:
        raise bad("camera_pose", "is missing")
    if not _rigid(sol["camera_pose"]):
        raise bad("camera_pose", RIGID_TEXT)
    if "goal" not in sol:
        raise bad("goal", "is missing")
    if not _pose6(sol["goal"]):
        raise bad("goal", f"must be 6 finite numbers (a position within {MAX_POSITION:g} m, "
                          f"an axis-angle within {MAX_ANGLE:g} rad)")
    cam = sol.get("camera")
    if not isinstance(cam, dict) or not all(_numbers(cam.get(k), ())
                                            for k in ("fx", "fy", "cx", "cy", "width", "height")):
        raise bad("camera", "must hold the finite numbers fx, fy, cx, cy, width, height")
    if not (1 <= cam["fx"] <= MAX_FOCAL and 1 <= cam["fy"] <= MAX_FOCAL
            and 1 <= cam["width"] <= MAX_IMAGE and 1 <= cam["height"] <= MAX_IMAGE
            and abs(cam["cx"]) <= MAX_FOCAL and abs(cam["cy"]) <= MAX_FOCAL):
        raise bad("camera", f"needs fx, fy in [1, {MAX_FOCAL:g}] px, cx, cy within {MAX_FOCAL:g} "
                            f"and width, height in [1, {MAX_IMAGE}]")
    if not isinstance(sol.get("method", ""), str):
        raise bad("method", "must be a string")
    for key, shape, limit, ok in (("sigma", (6, 6), MAX_VARIANCE, None),
                                  ("camera_poses", (4, 4), None, _rigid)):
        seq = sol.get(key)
        if seq is None:
            continue
        if not isinstance(seq, list) or len(seq) > MAX_WAYPOINTS:
            raise bad(key, f"must be a list of at most {MAX_WAYPOINTS} "
                           f"{'x'.join(map(str, shape))} matrices")
        for t, v in enumerate(seq):
            if v is not None and not (ok(v) if ok else _numbers(v, shape, limit)):
                raise bad(f"{key}[{t}]",
                          RIGID_TEXT if ok else f"must be {'x'.join(map(str, shape))} finite "
                                                f"numbers within {limit:g} (or null)")
    if sol.get("camera_poses") is not None and len(sol["camera_poses"]) not in (0, len(poses)):
        raise bad("camera_poses", f"must hold one pose per waypoint ({len(poses)})")
    q = sol.get("q")
    if q is not None and (not isinstance(q, list) or len(q) > MAX_WAYPOINTS):
        raise bad("q", f"must be a list of at most {MAX_WAYPOINTS} joint vectors (or null)")
    for t, v in enumerate(q or []):
        if v is not None and not (isinstance(v, list)
                                  and all(_numbers(x, (), MAX_ANGLE) for x in v)):
            raise bad(f"q[{t}]",
                      f"must be a list of finite joint values within {MAX_ANGLE:g} (or null)")
    names = sol.get("joint_names")
    if names is not None and (not isinstance(names, list)
                              or not all(isinstance(n, str) for n in names)):
        raise bad("joint_names", "must be a list of strings")
    noise = sol.get("noise")
    if noise is not None and (not isinstance(noise, dict) or (
            "depth_star" in noise and not (_numbers(noise["depth_star"], (), MAX_POSITION)
                                           and noise["depth_star"] > 0))):
        raise bad("noise.depth_star",
                  f"must be a positive number of metres, at most {MAX_POSITION:g}")
    for key in ("robot", "ecm"):
        if sol.get(key) is not None:
            _check_arm(sol[key], key, bad)
    arms = sol.get("other_arms")
    if arms is not None and (not isinstance(arms, list)
                             or not all(isinstance(a, dict) for a in arms)):
        raise bad("other_arms", "must be a list of mappings")
    if arms is not None and len(arms) > 16:
        raise bad("other_arms", f"lists {len(arms)} arms; at most 16 are drawn")
    for k, arm in enumerate(arms or []):
        _check_arm(arm, f"other_arms[{k}]", bad)


def _check_arm(arm, key: str, bad) -> None:
    """An arm entry (`robot`, `ecm`, `other_arms[k]`): urdf, frame, base_pose, q (and joint_names),
    needle."""
    if not isinstance(arm, dict) or not isinstance(arm.get("urdf", ""), str) or not isinstance(
            arm.get("frame", ""), str):
        raise bad(key, "must be a mapping with the strings urdf and frame")
    if "base_pose" in arm and not _rigid(arm["base_pose"]):
        raise bad(f"{key}.base_pose", RIGID_TEXT)
    q = arm.get("q")
    values = list(q.values()) if isinstance(q, dict) else q
    if q is not None and (not isinstance(values, list) or len(values) > 64
                          or not all(_numbers(v, (), MAX_ANGLE) for v in values)):
        raise bad(f"{key}.q", "must be a list (or a joint: value mapping) of finite joint values "
                              f"within {MAX_ANGLE:g}")
    names = arm.get("joint_names")
    if names is not None and (not isinstance(names, list)
                              or not all(isinstance(n, str) for n in names)):
        raise bad(f"{key}.joint_names", "must be a list of strings")
    needle = arm.get("needle")
    if needle:
        if not isinstance(needle, dict) or not (_numbers(needle.get("radius"), (), 1.0)
                                                and needle["radius"] > 0):
            raise bad(f"{key}.needle", "must be a mapping with a radius in (0, 1] m "
                                       "(and optionally a grasp pose)")
        if "grasp" in needle and not _rigid(needle["grasp"]):
            raise bad(f"{key}.needle.grasp", RIGID_TEXT)


def _checked_outputs(sols: Sequence[Solution], *outputs) -> None:
    """Output files checked before any work (never one of the solution files read)."""
    inputs = [s.get("_source") for s in sols if isinstance(s, dict)]
    for out in outputs:
        if out is not None:
            check_output_file(out, inputs, "the page" if str(out).endswith((".html", ".htm"))
                              else "the output")


def _scene_errors(sols: Sequence[Solution]):
    """A solution file that passes `check_solution` but still breaks the scene: one line, not a
    traceback."""
    @contextlib.contextmanager
    def guard():
        try:
            # C libraries (urdfdom) print parse errors on stderr: silenced; Python warnings (a robot
            # that cannot be drawn) are collected and said on one line each afterwards
            with warnings.catch_warnings(record=True) as caught, quiet_fd(2):
                warnings.simplefilter("always")
                yield
        except (KeyError, TypeError, ValueError, IndexError, AttributeError,
                ZeroDivisionError) as exc:
            srcs = ", ".join(shown(str(s.get("_source", "?")), 100) for s in sols[:3]
                             if isinstance(s, dict))
            raise SurestepError(f"{srcs or 'the solutions'}: not a usable solution file "
                                f"({type(exc).__name__}: {shown(str(exc), 200)})") from None
        finally:
            for w in caught if "caught" in locals() else []:
                print(f"warning: {shown(str(w.message), 300)}", file=sys.stderr)

    return guard()


def serve(
    solutions: Sequence[Solution],
    open_browser: bool = False,
    endoscope_view: bool = False,
    repo_root: Path | None = None,
    animate: str | None = None,
    zmq_url: str | None = None,
):
    """Start (or connect to) a Meshcat server on loopback and draw the scene into it.

    Returns `(vis, info)`; the server subprocess ends with this process, however it ends
    (see `server`). `zmq_url` connects to an already running `meshcat-server` instead of
    starting one.
    """
    vis = meshcat.Visualizer(zmq_url=zmq_url) if zmq_url is not None else server.visualizer()
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
    for sol in sols:  # solution dicts given directly: the same promises as a file's
        if isinstance(sol, dict) and (solutions is not None or not isinstance(target, (str, Path))):
            check_solution(sol)
    _checked_outputs(sols, html, screenshot)
    if screenshot is not None:
        with _scene_errors(sols):
            return _screenshot(sols, Path(screenshot), html, screenshot_size, open_browser,
                               repo_root=repo_root, animate=animate, endoscope=endoscope_view)
    if html is not None:
        out = Path(html)
        with _scene_errors(sols):
            info = write_static_html(sols, out, repo_root=repo_root, animate=animate,
                                     endoscope=endoscope_view)
        print(f"wrote {out} ({', '.join(info.paths)})")
        if open_browser:
            webbrowser.open(out.resolve().as_uri(), new=2)
        return 0
    with _scene_errors(sols):
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
    """Turn SIGTERM into KeyboardInterrupt so the atexit cleanup stops the server at once."""
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
    for flag, value in (("--html", html), ("--screenshot", png)):
        if value is not None and str(value) in ("", "."):
            raise SurestepError(f"{flag} '{shown(str(value))}': must name a file to write "
                                f"(leave {flag} out to serve the scene live)")
    return show(
        args.target,
        open_browser=bool(getattr(args, "open_browser", getattr(args, "open", False))),
        html=Path(html) if html is not None else None,
        endoscope_view=bool(getattr(args, "endoscope_view", False)),
        animate=getattr(args, "animate", None),
        solutions=solutions,
        screenshot=Path(png) if png is not None else None,
    )
