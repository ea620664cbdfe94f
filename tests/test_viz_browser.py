"""Browser test: headless Chromium renders the static HTML (WebGL via SwiftShader).

Skipped when no Chromium is installed (`make browser` installs it). Uses the same
`viz.screenshot.screenshot_html` as `surestep show --screenshot` (the docs/
images). Checks the screenshot for pixels of every path colour and of the arm's
colour, that two different solution sets give different pictures, and that the
screenshot function refuses a blank page.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("meshcat")
pytest.importorskip("pinocchio")
mpimg = pytest.importorskip("matplotlib.image")

from test_viz import ARM_URDF, make_solution  # noqa: E402  (tests/ is on sys.path under pytest)

from surestep_ocp.errors import SurestepError  # noqa: E402
from surestep_ocp.viz import write_static_html  # noqa: E402
from surestep_ocp.viz.screenshot import (  # noqa: E402
    ScreenshotError, find_chromium, screenshot_html)
from surestep_ocp.viz.style import METHOD_COLORS  # noqa: E402

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (make browser, or apt-get install chromium)")


def screenshot(html: Path, png: Path) -> np.ndarray:
    """Render `html` headless (1024x768) with the shared `screenshot_html` (the one
    `surestep show --screenshot` uses) and return the image as int RGB (H, W, 3) in 0-255."""
    try:
        screenshot_html(html, png, size=(1024, 768), timeout_s=300)
    except ScreenshotError as exc:
        if exc.no_webgl:
            pytest.skip("this Chromium has no WebGL (SwiftShader) support")
        raise
    img = mpimg.imread(str(png))[..., :3]
    return np.round(img * 255).astype(int)


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
    img_a = screenshot(scenes["a"], tmp_path / "a.png")
    assert img_a.shape == (768, 1024, 3)
    assert img_a.std() > 5, "blank screenshot: the scene did not render"
    for method in ("baseline", "gradient", "ocp"):
        n = count_color(img_a, METHOD_COLORS[method])
        assert n >= 40, f"{method} path colour: only {n} pixels"
    assert count_green(img_a) >= 500, "robot colour missing"

    img_b = screenshot(scenes["b"], tmp_path / "b.png")
    assert count_color(img_b, METHOD_COLORS["gradient"]) < 10  # no gradient path in b
    changed = (np.abs(img_a - img_b).max(axis=-1) > 30).mean()
    assert changed > 0.002, f"pictures barely differ ({changed:.4%} of pixels)"


def test_endoscope_view_screenshot(tmp_path: Path, scenes: dict[str, Path]):
    img = screenshot(scenes["endo"], tmp_path / "endo.png")
    for method in ("baseline", "ocp"):
        assert count_color(img, METHOD_COLORS[method]) >= 40, method


def test_blank_page_is_an_error(tmp_path: Path):
    """A page that draws nothing gives a uniform image: a SurestepError, and no PNG."""
    page = tmp_path / "blank.html"
    page.write_text("<!DOCTYPE html><html><body style='background:#fff'></body></html>")
    png = tmp_path / "blank.png"
    with pytest.raises(SurestepError, match="blank"):
        screenshot_html(page, png, size=(320, 200), budget_ms=200)
    assert not png.exists()
    assert not list(tmp_path.glob(".blank.png.*"))  # no temporary file left behind


def test_missing_chromium_is_an_error(tmp_path: Path, monkeypatch):
    page = tmp_path / "p.html"
    page.write_text("<html></html>")
    monkeypatch.setattr("surestep_ocp.viz.screenshot.find_chromium", lambda: None)
    with pytest.raises(SurestepError, match="no Chromium found"):
        screenshot_html(page, tmp_path / "p.png")
    with pytest.raises(SurestepError, match="cannot run"):
        screenshot_html(page, tmp_path / "p.png", chromium=str(tmp_path / "no-such-browser"))
