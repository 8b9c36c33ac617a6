"""The web page in a real headless Chromium: a file uploaded through the form is
scored, the status page's script follows it to `done`, the leaderboard is
server-rendered. The browser is driven over the DevTools protocol on a pipe."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import time

import httpx
import pytest

from support.browser import DevToolsBrowser


CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("no Chromium on PATH (apt-get install -y chromium)")


def Browser(profile) -> DevToolsBrowser:  # noqa: N802 - reads as the class it makes
    """Headless Chromium driven over its DevTools pipe (tests/support/browser.py); skipped without one."""
    return DevToolsBrowser(chromium(), profile, CHROMIUM_FLAGS)


def rendered_dom(url: str, profile) -> str:
    """The DOM after the page's scripts ran (virtual time lets pending fetches finish)."""
    run = subprocess.run(
        [chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=8000", "--dump-dom", url],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def field(dom: str, element_id: str) -> str:
    match = re.search(rf'id="{element_id}"[^>]*>([^<]*)<', dom)
    assert match, f"no #{element_id} in the page"
    return html.unescape(match.group(1))


def test_leaderboard_cells_are_escaped():
    from wosac_server.web import leaderboard_table

    table = leaderboard_table(
        [{"rank": 1, "method": "<script>x</script>", "realism_meta_metric": 0.5, "buckets": {"min_ade": 1.25}}]
    )
    assert "<script>" not in table and "&lt;script&gt;x&lt;/script&gt;" in table
    assert '<td class="num">1.2500</td>' in table


def test_page_uses_no_external_resources(api_server):
    server = api_server
    page = httpx.get(server.url + "/").text
    assert '<form id="upload-form">' in page and "No published results yet" in page
    assert not re.search(r'(src|href)="(https?:)?//', page)  # nothing from a CDN
    assert httpx.get(server.url + "/static/style.css").headers["content-type"].startswith("text/css")
    assert httpx.get(server.url + "/docs").status_code == 404  # the CDN-backed docs page is off


def test_pages_send_a_strict_content_security_policy(api_server):
    """Only the page's own inline scripts run (by hash; no 'unsafe-inline'), nothing frames it, no sniffing.

    The Chromium test below runs the pages' scripts under this policy."""
    import base64
    import hashlib

    for path in ("/", "/submissions/" + "0" * 32):
        response = httpx.get(api_server.url + path)
        policy = response.headers["content-security-policy"]
        scripts = re.findall(r"<script>(.*?)</script>", response.text, re.S)
        assert scripts, path
        for body in scripts:
            digest = base64.b64encode(hashlib.sha256(body.encode()).digest()).decode()
            assert f"'sha256-{digest}'" in policy, path
        assert "unsafe-inline" not in policy and "default-src 'none'" in policy and "frame-ancestors 'none'" in policy
        assert response.headers["x-frame-options"] == "DENY"
        assert response.headers["x-content-type-options"] == "nosniff"
    assert httpx.get(api_server.url + "/static/style.css").headers["x-content-type-options"] == "nosniff"


def submit_upload_form(browser: DevToolsBrowser, url: str, file, key: str, method: str, partial: bool = False) -> str:
    """Fill the page's upload form (published, partial when asked) and send it; the status page's path."""
    browser.open(url + "/")
    browser.choose_file("#upload-form input[type=file]", file)
    browser.js(f"""(() => {{ const f = document.getElementById("upload-form");
        f.key.value = {json.dumps(key)}; f.method.value = {json.dumps(method)}; f.publish.checked = true;
        f.partial.checked = {json.dumps(partial)}; f.requestSubmit(); }})()""")
    # The page uploads through tus, then follows the submission on the same page; its link opens the status page.
    browser.wait_for("document.getElementById('result-id').textContent.length === 32")
    browser.js("document.getElementById('result-link').click()")
    return browser.wait_for("location.pathname.startsWith('/submissions/') && location.pathname")


@pytest.mark.browser
def test_upload_form_status_page_and_leaderboard_in_chromium(make_server, scoring_data, tmp_path):
    server = make_server(workers=1, scenarios=scoring_data.scenarios, scene_pictures=3)
    key = server.key("browser")
    browser = Browser(tmp_path / "profile")
    try:
        # The form's script uploads, then goes to the status page, which polls until done.
        path = submit_upload_form(browser, server.url, scoring_data.full, key, "log-replay 1.0")
        browser.wait_for("document.readyState === 'complete'")
        state = browser.wait_for(
            "['done', 'failed'].includes(document.getElementById('state').textContent)"
            " && document.getElementById('state').textContent",
            timeout=90,
        )
        shown = browser.js("""(() => Object.fromEntries(['progress', 'method', 'meta'].map(
            id => [id, document.getElementById(id).textContent])))()""")
        links_visible = browser.js("!document.getElementById('links').hidden")
        # The worst scenes' pictures, fetched with the key and shown once the job is done.
        pictures = min(3, len(scoring_data.scenarios))
        browser.wait_for(
            f"[...document.querySelectorAll('#scene-list img')].filter("
            f"i => i.complete && i.naturalWidth > 600).length === {pictures}"
        )
        shown_scenes = browser.js("[...document.querySelectorAll('#scene-list figure')].map(f => f.dataset.scenario)")
    finally:
        browser.close()
    sid = path.rsplit("/", 1)[1]
    with server.client(key) as c:
        status = c.get(f"/v1/submissions/{sid}").json()
    assert state == status["state"] == "done", status
    assert status["upload_bytes"] == scoring_data.full.stat().st_size and status["published"]
    n = len(scoring_data.scenarios)
    assert shown == {
        "progress": f"{n} / {n} scenarios",
        "method": "log-replay 1.0",
        "meta": str(status["realism_meta_metric"]),
    }
    assert links_visible
    with server.client(key) as c:
        result = c.get(f"/v1/submissions/{sid}/results").json()
        listed = c.get(f"/v1/submissions/{sid}/scenes").json()["scenes"]
        assert c.get(f"/v1/submissions/{sid}/scenes/{len(listed)}.png").status_code == 404
        picture = c.get(listed[0]["url"])
    worst_first = [s["scenario_id"] for s in sorted(result["scenarios"], key=lambda s: s["metametric"])]
    assert shown_scenes == [e["scenario_id"] for e in listed] == worst_first[:pictures]
    assert picture.headers["content-type"] == "image/png" and picture.content[:8] == b"\x89PNG\r\n\x1a\n"
    with server.client(server.key("stranger")) as c:
        assert c.get(f"/v1/submissions/{sid}/scenes").status_code == 404

    board = rendered_dom(server.url + "/?config=2025", tmp_path / "profile-a")
    row = re.search(r'<td class="method">([^<]*)</td><td class="num meta">([^<]*)</td>', board)
    assert row, board[-3000:]
    assert row.group(1) == "log-replay 1.0"
    assert float(row.group(2)) == pytest.approx(status["realism_meta_metric"], abs=5e-5)

    other = server.key("someone-else")
    page = rendered_dom(f"{server.url}/submissions/{sid}#key={other}", tmp_path / "profile-b")
    assert field(page, "state").startswith("error 404")


@pytest.mark.browser
def test_upload_form_asks_for_partial_scoring_and_the_board_marks_it(make_server, scoring_data, tmp_path):
    """The form's partial box sends allow_partial; the published partial row says "partial" on the page
    and `partial: true` in the API."""
    server = make_server(workers=1, scenarios=scoring_data.scenarios, metadata_checks="warn")
    key = server.key("partial-browser")
    browser = Browser(tmp_path / "profile")
    try:
        path = submit_upload_form(browser, server.url, scoring_data.single, key, "half", partial=True)
    finally:
        browser.close()
    sid = path.rsplit("/", 1)[1]
    with server.client(key) as c:
        status = server.wait_state(c, sid)
        assert status["state"] == "done" and status["allow_partial"] and status["partial"], status
        entry = next(
            e
            for e in c.get("/v1/leaderboard", params={"config": "2025"}).json()["entries"]
            if e["submission_id"] == sid
        )
    assert entry["partial"] and entry["coverage"] < 1
    board = rendered_dom(server.url + "/?config=2025", tmp_path / "profile-a")
    assert re.search(r'<span class="partial"[^>]*>[0-9.]+% partial</span>', board), board[-3000:]


def padded_submission(data, path, pad_bytes: int):
    """One binproto of every rollout of `data.full` (a .tar.gz of shards, or one binproto), its description
    `pad_bytes` long: a valid submission of a few hundred MB that scores in seconds."""
    import tarfile

    from wosac_eval.protos import sim_agents_submission_pb2 as pb

    if data.full.name.endswith((".tar.gz", ".tar")):
        with tarfile.open(data.full) as tar:
            shards = [tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()]
    else:
        shards = [data.full.read_bytes()]
    merged = pb.SimAgentsChallengeSubmission.FromString(shards[0])
    for shard in shards[1:]:
        merged.scenario_rollouts.extend(pb.SimAgentsChallengeSubmission.FromString(shard).scenario_rollouts)
    merged.description = "x" * pad_bytes
    path.write_bytes(merged.SerializeToString())
    return path


# The page's tus client as the server sees it, recorded in the page (the browser's own requests, not mocked):
# the Upload-Offset of every PATCH it sends (`sentOffsets`) and of every HEAD's answer (`headOffsets`).
RECORD_OFFSETS = """(() => { window.sentOffsets = []; window.headOffsets = [];
    const set = XMLHttpRequest.prototype.setRequestHeader, open = XMLHttpRequest.prototype.open;
    XMLHttpRequest.prototype.setRequestHeader = function (name, value) {
        if (name.toLowerCase() === 'upload-offset') { window.sentOffsets.push(Number(value)); }
        return set.call(this, name, value); };
    XMLHttpRequest.prototype.open = function (method, ...rest) {
        if (String(method).toUpperCase() === 'HEAD') { this.addEventListener('load', () => {
            if (this.status === 200) { window.headOffsets.push(Number(this.getResponseHeader('Upload-Offset'))); }
        }); }
        return open.call(this, method, ...rest); }; })()"""


def start_page_upload(browser: DevToolsBrowser, url: str, file, key: str | None) -> None:
    """Choose the file and send the form: on a new tab with `key`, else on this tab reloaded (its key from
    the tab's sessionStorage)."""
    if key:
        browser.open(url + "/")
    else:
        browser.js("window.beforeReload = true; location.reload()")
        browser.wait_for("window.beforeReload === undefined && document.readyState === 'complete'")
    browser.js(RECORD_OFFSETS)
    browser.choose_file("#upload-form input[type=file]", file)
    fill = f"f.key.value = {json.dumps(key)}; f.method.value = 'resumed'; f.publish.checked = true;" if key else ""
    browser.js(f"""(() => {{ const f = document.getElementById("upload-form"); {fill} f.requestSubmit(); }})()""")


@pytest.mark.browser
@pytest.mark.slow
def test_a_large_upload_survives_a_killed_server_and_a_reload(make_server, scoring_data, tmp_path):
    """A 320 MB submission through the page: the server killed (SIGKILL) and started again mid-way, the page
    reloaded and the file chosen again; the upload goes on from the server's offset (same upload, no byte
    sent twice but the chunk cut short), is scored, the result shown; the bytes on disk are the file's."""
    big = padded_submission(scoring_data, tmp_path / "big.binproto", 320 * 2**20)
    size = big.stat().st_size
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    key = server.key("resumer")
    browser = Browser(tmp_path / "profile")
    try:
        start_page_upload(browser, server.url, big, key)
        deadline = time.monotonic() + 120
        while True:  # until the server holds at least two of the page's 64 MiB chunks
            held = server.store.fetchone("SELECT id, received_bytes FROM uploads")
            if held and held["received_bytes"] >= 2 * 64 * 2**20:
                break
            assert time.monotonic() < deadline, browser.js("document.getElementById('upload-status').textContent")
            time.sleep(0.05)
        upload_id = held["id"]
        server.proc.kill()  # SIGKILL: no shutdown, a PATCH cut off mid-body
        server.proc.wait()
        server.start()
        at_restart = server.store.fetchone("SELECT received_bytes FROM uploads WHERE id = ?", (upload_id,))
        start_page_upload(browser, server.url, big, None)  # reloaded; the key from the tab's sessionStorage
        state = browser.wait_for(
            "['done', 'failed'].includes(document.getElementById('result-state').textContent)"
            " && document.getElementById('result-state').textContent",
            timeout=240,
        )
        shown = browser.js(
            "[document.getElementById('result-id').textContent, document.getElementById('result-meta').textContent]"
        )
        resumed_offsets, head_offsets = browser.js("[window.sentOffsets, window.headOffsets]")
    finally:
        browser.close()
    sid, meta = shown
    assert state == "done", state
    rows = server.store.fetchall("SELECT id, submission_id FROM uploads")
    assert rows == [{"id": upload_id, "submission_id": sid}]  # the same upload, resumed, never a new one
    # The reloaded page goes on from the offset the server answers to its HEAD: the bytes held at the restart,
    # or more where the old tab's retry got part of a chunk in before the reload cut it short (a tus server keeps
    # the bytes of a PATCH cut off: `ClientBody`).
    assert head_offsets and resumed_offsets[0] == head_offsets[0] >= at_restart["received_bytes"] > 0
    assert resumed_offsets == sorted(resumed_offsets)
    with server.client(key) as c:
        status = c.get(f"/v1/submissions/{sid}").json()
    assert status["upload_bytes"] == size and meta == str(status["realism_meta_metric"])
    stored = next(server.data_dir.glob(f"submissions/{sid}.*"))
    assert stored.stat().st_size == size and stored.read_bytes() == big.read_bytes()
