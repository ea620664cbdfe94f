"""Browser test: headless Chromium renders the static HTML (WebGL via SwiftShader).

Skipped when no Chromium is installed (`make browser` installs it). Checks the
screenshot for pixels of every path colour and of the arm's colour, and that two
different solution sets give different pictures.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("meshcat")
pytest.importorskip("pinocchio")
mpimg = pytest.importorskip("matplotlib.image")

from test_viz import ARM_URDF, make_solution  # noqa: E402  (tests/ is on sys.path under pytest)

from surestep_ocp.viz import write_static_html  # noqa: E402
from surestep_ocp.viz.style import METHOD_COLORS  # noqa: E402


def find_chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None


CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (make browser, or apt-get install chromium)")


def screenshot(html: Path, png: Path, tmp: Path, budget_ms: int = 8000) -> np.ndarray:
    """Render `html` headless (1024x768) and return the screenshot as uint8 RGB (H, W, 3).

    One retry with a fresh profile if Chromium exits without writing the file.
    """
    err = ""
    for attempt in range(2):
        args = [
            CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
            "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--disable-background-networking", "--disable-quic", "--no-first-run",
            "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
            f"--user-data-dir={tmp / f'profile-{png.stem}-{attempt}'}", "--window-size=1024,768",
            f"--virtual-time-budget={budget_ms}", "--enable-logging=stderr", "--v=0",
            f"--screenshot={png}", html.resolve().as_uri(),
        ]
        out = subprocess.run(args, capture_output=True, text=True, timeout=300)
        if "Error creating WebGL context" in out.stderr:
            pytest.skip("this Chromium has no WebGL (SwiftShader) support")
        if png.exists():
            img = mpimg.imread(str(png))[..., :3]
            return np.round(img * 255).astype(int)
        err = f"rc={out.returncode}:\n{out.stderr[-3000:]}"
    raise AssertionError(f"no screenshot of {html}: {err}")


def count_color(img: np.ndarray, rgb, tol: int = 10) -> int:
    """Pixels within `tol` (per channel, 0-255) of an RGB colour in [0, 1]."""
    target = np.round(np.asarray(rgb) * 255).astype(int)
    return int((np.abs(img - target).max(axis=-1) <= tol).sum())


def count_green(img: np.ndarray) -> int:
    """Pixels whose green clearly dominates (the fixture arm; no path colour is green)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((g > r + 60) & (g > b + 40)).sum())


@pytest.fixture()
def scenes(tmp_path: Path) -> dict[str, Path]:
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM_URDF)
    a = [make_solution(urdf, "baseline", 0.0, 1), make_solution(urdf, "gradient", 0.08, 3),
         make_solution(urdf, "ocp", 0.15, 2)]
    b = [make_solution(urdf, "baseline", 0.0, 1), make_solution(urdf, "ocp", -0.25, 4)]
    out = {"a": tmp_path / "a.html", "b": tmp_path / "b.html", "endo": tmp_path / "endo.html"}
    write_static_html(a, out["a"])
    write_static_html(b, out["b"])
    write_static_html(a, out["endo"], endoscope=True)
    return out


def test_screenshot_shows_paths_robot_and_changes(tmp_path: Path, scenes: dict[str, Path]):
    img_a = screenshot(scenes["a"], tmp_path / "a.png", tmp_path)
    assert img_a.shape == (768, 1024, 3)
    assert img_a.std() > 5, "blank screenshot: the scene did not render"
    for method in ("baseline", "gradient", "ocp"):
        n = count_color(img_a, METHOD_COLORS[method])
        assert n >= 40, f"{method} path colour: only {n} pixels"
    assert count_green(img_a) >= 500, "robot colour missing"

    img_b = screenshot(scenes["b"], tmp_path / "b.png", tmp_path)
    assert count_color(img_b, METHOD_COLORS["gradient"]) < 10  # no gradient path in b
    changed = (np.abs(img_a - img_b).max(axis=-1) > 30).mean()
    assert changed > 0.002, f"pictures barely differ ({changed:.4%} of pixels)"


def test_endoscope_view_screenshot(tmp_path: Path, scenes: dict[str, Path]):
    img = screenshot(scenes["endo"], tmp_path / "endo.png", tmp_path)
    for method in ("baseline", "ocp"):
        assert count_color(img, METHOD_COLORS[method]) >= 40, method
