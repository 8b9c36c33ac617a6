"""Headless Chromium: a report's rendered DOM (for tests) and a screenshot (for docs), and a browser driven
over its DevTools pipe (the service's pages, in tests and benchmarks).

Chromium runs with networking features off and a throw-away profile, so a
report that tried to load anything from outside would show it as missing.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import tempfile
import time
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


class DevToolsBrowser:
    """Headless Chromium driven over `--remote-debugging-pipe` (DevTools protocol:
    JSON messages separated by NUL; Chromium reads fd 3 and writes fd 4)."""

    def __init__(self, executable: str, profile, flags: list[str]):
        cmd_read, self._cmd = os.pipe()
        self._replies, reply_write = os.pipe()

        def wire_fds():  # in the child: its fd 3 and 4 become our pipes
            a, b = os.dup(cmd_read), os.dup(reply_write)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [executable, *flags, f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"],
            pass_fds=(3, 4),
            preexec_fn=wire_fds,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(cmd_read)
        os.close(reply_write)
        self._buffer, self._last_id, self.session = b"", 0, None

    def send(self, method: str, **params):
        self._last_id += 1
        message = {"id": self._last_id, "method": method, "params": params}
        if self.session and not method.startswith(("Target.", "Browser.")):
            message["sessionId"] = self.session
        os.write(self._cmd, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + 30
        while True:
            while b"\0" in self._buffer:
                raw, self._buffer = self._buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._last_id:
                    assert "error" not in reply, f"{method}: {reply['error']}"
                    return reply["result"]
            ready, _, _ = select.select([self._replies], [], [], max(0.0, deadline - time.monotonic()))
            assert ready, f"Chromium did not answer {method}"
            chunk = os.read(self._replies, 1 << 16)
            assert chunk, "Chromium closed the DevTools pipe"
            self._buffer += chunk

    def open(self, url: str) -> None:
        target = self.send("Target.createTarget", url=url)["targetId"]
        self.session = self.send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        # The new tab starts on about:blank, itself "complete": wait for our page.
        self.wait_for(f"location.href === {json.dumps(url)} && document.readyState === 'complete'")

    def js(self, expression: str):
        result = self.send("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 60.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.js(expression)
            if value:
                return value
            time.sleep(0.1)
        raise AssertionError(f"still false after {timeout} s: {expression}")

    def choose_file(self, selector: str, path) -> None:
        root = self.send("DOM.getDocument")["root"]["nodeId"]
        node = self.send("DOM.querySelector", nodeId=root, selector=selector)["nodeId"]
        self.send("DOM.setFileInputFiles", files=[str(path)], nodeId=node)

    def close(self) -> None:
        try:
            self.send("Browser.close")
            self.proc.wait(10)
        except (AssertionError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        os.close(self._cmd)
        os.close(self._replies)
