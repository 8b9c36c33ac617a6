"""Regenerates the screenshot of the service's upload page (docs/service-upload.png); needs Chromium.

    python scripts/upload_page_screenshot.py [--png docs/service-upload.png]

Starts a service on loopback (no worker), uploads a 300 MB submission through the page in headless
Chromium, pauses it part-way and takes the upload section as the page shows it then.
"""

from __future__ import annotations

import argparse
import base64
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "benchmarks"))

from support.browser import DevToolsBrowser, find_chromium  # noqa: E402
from support.server_harness import Server, scoring_data  # noqa: E402
from upload_speed import FLAGS, make_submission  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", type=Path, default=REPO / "docs" / "service-upload.png")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="wosac-upload-page-"))
    data = scoring_data(work / "data")
    big = make_submission(work / "my-method.tar", 300 * 2**20, data)
    server = Server(work / "server", data.scenarios, workers=0, min_free_fraction=0).start()
    browser = DevToolsBrowser(find_chromium(), work / "profile", FLAGS)
    try:
        key = server.key("my-team")
        browser.open(server.url + "/")
        browser.send("Emulation.setDeviceMetricsOverride", width=1100, height=900, deviceScaleFactor=1, mobile=False)
        browser.choose_file("#upload-form input[type=file]", big)
        browser.js(
            f"""(() => {{ const f = document.getElementById("upload-form"); f.key.value = {json.dumps(key)};
            f.method.value = "my-method"; f.publish.checked = true; f.requestSubmit(); }})()"""
        )
        browser.wait_for(
            "document.getElementById('upload-bar').value > 0.35 * document.getElementById('upload-bar').max"
        )
        browser.js("document.getElementById('upload-pause').click()")
        time.sleep(0.5)
        browser.js("document.getElementById('upload').scrollIntoView()")
        shot = browser.send("Page.captureScreenshot", format="png")["data"]
        args.png.write_bytes(base64.b64decode(shot))
    finally:
        browser.close()
        server.stop()
    from PIL import Image  # installed with matplotlib

    with Image.open(args.png) as image:
        image.convert("RGB").quantize(colors=64, method=Image.Quantize.MEDIANCUT).save(args.png, optimize=True)
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
