"""Rendering a report in headless Chromium: the rendered DOM (for tests) and a screenshot (for docs).

Chromium runs with networking features off and a throw-away profile, so a
report that tried to load anything from outside would show it as missing.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--hide-scrollbars",
)


def find_chromium() -> str | None:
    """Path of a Chromium / Chrome executable on PATH, or None."""
    for name in _CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    chromium = find_chromium()
    if chromium is None:
        raise FileNotFoundError("no chromium executable on PATH (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="wosac-chromium-") as profile:
        return subprocess.run(
            [chromium, *_FLAGS, f"--user-data-dir={profile}", *args], capture_output=True, timeout=timeout, check=True
        )


def dump_dom(html_path: str | Path, timeout: float = 60.0) -> str:
    """The DOM Chromium builds for a local HTML file, serialised as HTML."""
    url = Path(html_path).resolve().as_uri()
    return _run(["--dump-dom", url], timeout).stdout.decode("utf-8")


def screenshot(
    html_path: str | Path,
    png_path: str | Path,
    width: int = 1280,
    height: int = 2000,
    timeout: float = 60.0,
    palette_colors: int | None = None,
) -> Path:
    """Writes a PNG screenshot of a local HTML file at the given window size.

    Args:
      palette_colors: when given, re-save the PNG with a palette of this many
        colours (a report is mostly flat colour: this shrinks it several-fold,
        e.g. for a screenshot committed to the docs).
    """
    png_path = Path(png_path).resolve()
    url = Path(html_path).resolve().as_uri()
    _run([f"--screenshot={png_path}", f"--window-size={width},{height}", url], timeout)
    if not png_path.is_file():
        raise RuntimeError(f"chromium did not write {png_path}")
    if palette_colors:
        from PIL import Image  # installed with matplotlib

        with Image.open(png_path) as image:
            quantized = image.convert("RGB").quantize(colors=palette_colors, method=Image.Quantize.MEDIANCUT)
        quantized.save(png_path, optimize=True)
    return png_path
