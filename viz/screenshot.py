"""Screenshot a static Meshcat HTML page with headless Chromium (WebGL via SwiftShader).

Used by `surestep show --screenshot PNG` and by the browser test, so the docs/
images come from the same code the test checks.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path
from typing import Sequence

from surestep_ocp.errors import SurestepError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

# Flags that give headless Chromium a software WebGL context (SwiftShader through
# ANGLE) and keep it from touching the network or the user's profile.
CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu",
    "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    "--disable-background-networking", "--disable-quic", "--no-first-run",
    "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
    "--hide-scrollbars", "--enable-logging=stderr", "--v=0",
)

NO_WEBGL = "Error creating WebGL context"

# Hides meshcat's "Open Controls" bar (dat.GUI) in the picture; the page is unchanged.
HIDE_CONTROLS_CSS = "<style>.dg.main { display: none !important; }</style>"


class ScreenshotError(SurestepError):
    """Chromium is missing or did not produce a (non-blank) image.

    `no_webgl` is True when Chromium reported that it has no WebGL context (the
    browser test skips then instead of failing).
    """

    def __init__(self, message: str, no_webgl: bool = False):
        self.no_webgl = no_webgl
        super().__init__(message)


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable on PATH (or /usr/bin/chromium), else None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return "/usr/bin/chromium" if os.access("/usr/bin/chromium", os.X_OK) else None


def _read_png(path: Path):
    """The PNG as a float array (H, W, C) in [0, 1] (matplotlib is a dependency of the package)."""
    import matplotlib.image as mpimg  # loaded on use: keeps `surestep show` start-up light

    return mpimg.imread(str(path))


def _is_uniform(img) -> bool:
    """True if every pixel has (nearly) the same RGB colour, e.g. a white or empty page."""
    rgb = img[..., :3]
    return float((rgb.max(axis=(0, 1)) - rgb.min(axis=(0, 1))).max()) < 2.0 / 255.0


def _run(args: list[str], timeout_s: float) -> str | None:
    """Run Chromium in its own process group; its stderr, or None on timeout.

    On timeout the whole group (browser, GPU and renderer processes) is killed.
    """
    try:
        proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, errors="replace",
                                start_new_session=True)
    except OSError as exc:
        raise ScreenshotError(f"cannot run {args[0]}: {exc}") from None
    try:
        _, err = proc.communicate(timeout=timeout_s)
        return err or ""
    except BaseException as exc:  # timeout or Ctrl-C: kill the group before the leader is reaped
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        proc.communicate()
        if isinstance(exc, subprocess.TimeoutExpired):
            return None
        raise


def _page_copy(html: Path, folder: Path) -> Path:
    """Copy of a (self-contained) page in `folder` with HIDE_CONTROLS_CSS in its head."""
    text = html.read_text(encoding="utf-8")
    head = text.find("</head>")
    text = ((text[:head] + HIDE_CONTROLS_CSS + text[head:]) if head >= 0
            else HIDE_CONTROLS_CSS + text)
    page = folder / "page.html"
    page.write_text(text, encoding="utf-8")
    return page


def screenshot_html(
    html: Path | str,
    png: Path | str,
    size: Sequence[int] = (1280, 800),
    timeout_s: float = 120,
    budget_ms: int = 3000,
    chromium: str | None = None,
    hide_controls: bool = True,
) -> Path:
    """Render `html` in headless Chromium and write a `size` = (width, height) PNG to `png`.

    Each attempt uses a fresh temporary profile (`--user-data-dir`) and lets the
    page run for `budget_ms` of virtual time so the scene is drawn (the arm's
    animation also runs on that clock: 3 s shows it part-way, deterministically;
    every virtual frame is rendered in software, so longer budgets are slower).
    An attempt is retried once if Chromium writes no image, a uniform (blank)
    one, or reports no WebGL. The PNG is written atomically (temporary file in
    the same folder, then `os.replace`). `hide_controls` renders a copy of the
    page without meshcat's "Open Controls" bar.

    Returns the path of the PNG. Raises `ScreenshotError` (a `SurestepError`) if
    Chromium is missing, times out on both attempts, or gives no non-blank image.
    """
    html, png = Path(html), Path(png)
    if not html.is_file():
        raise ScreenshotError(f"{html}: no such HTML file")
    exe = chromium or find_chromium()
    if exe is None:
        raise ScreenshotError(
            "no Chromium found (looked for " + ", ".join(CHROMIUM_NAMES)
            + " on PATH); install it, e.g. `make browser` or `apt-get install chromium`")
    width, height = (int(v) for v in size)
    png.parent.mkdir(parents=True, exist_ok=True)
    problems: list[str] = []
    no_webgl = False
    for attempt in range(2):
        fd, tmp = tempfile.mkstemp(prefix=f".{png.name}.", suffix=".png", dir=png.parent)
        os.close(fd)
        tmp_png = Path(tmp)
        tmp_png.unlink()  # Chromium must create it: an existing empty file would hide a failure
        try:
            with tempfile.TemporaryDirectory(prefix="surestep-chromium-",
                                             ignore_cleanup_errors=True) as work:
                page = _page_copy(html, Path(work)) if hide_controls else html.resolve()
                args = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={Path(work) / 'profile'}",
                        f"--window-size={width},{height}",
                        f"--virtual-time-budget={int(budget_ms)}",
                        f"--screenshot={tmp_png}", page.as_uri()]
                stderr = _run(args, timeout_s)
            if stderr is None:
                problems.append(f"attempt {attempt + 1}: Chromium timed out after {timeout_s} s")
                continue
            if NO_WEBGL in stderr:  # the page's HTML controls would still give pixels
                no_webgl = True
                problems.append(f"attempt {attempt + 1}: Chromium has no WebGL context "
                                "(needs SwiftShader: --use-angle=swiftshader)")
                continue
            if not tmp_png.exists() or tmp_png.stat().st_size == 0:
                problems.append(f"attempt {attempt + 1}: no image:\n{stderr[-2000:]}")
                continue
            try:
                img = _read_png(tmp_png)
            except Exception as exc:  # truncated / not a PNG
                problems.append(f"attempt {attempt + 1}: unreadable image: {exc}")
                continue
            if _is_uniform(img):
                problems.append(f"attempt {attempt + 1}: blank (uniform) image")
                continue
            os.chmod(tmp_png, 0o644)
            os.replace(tmp_png, png)
            return png
        finally:
            tmp_png.unlink(missing_ok=True)
    raise ScreenshotError(f"Chromium ({exe}) gave no screenshot of {html}:\n" + "\n".join(problems),
                          no_webgl=no_webgl)
