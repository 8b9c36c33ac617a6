"""The web page in a real headless Chromium: the leaderboard is server-rendered,
the status page's script fetches the submission with the user's key."""
from __future__ import annotations

import html
import re
import shutil
import subprocess

import httpx
import pytest


CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("no Chromium on PATH (apt-get install -y chromium)")


def rendered_dom(url: str, profile) -> str:
    """The DOM after the page's scripts ran (virtual time lets pending fetches finish)."""
    run = subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                          "--virtual-time-budget=8000", "--dump-dom", url],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    return run.stdout


def field(dom: str, element_id: str) -> str:
    match = re.search(rf'id="{element_id}"[^>]*>([^<]*)<', dom)
    assert match, f"no #{element_id} in the page"
    return html.unescape(match.group(1))


def test_leaderboard_cells_are_escaped():
    from wosac_eval.fronts.server.web import leaderboard_table

    table = leaderboard_table([{"rank": 1, "method": "<script>x</script>", "realism_meta_metric": 0.5,
                                "buckets": {"min_ade": 1.25}}])
    assert "<script>" not in table and "&lt;script&gt;x&lt;/script&gt;" in table
    assert '<td class="num">1.2500</td>' in table


def test_page_uses_no_external_resources(api_server):
    server = api_server
    page = httpx.get(server.url + "/").text
    assert "<form id=\"upload-form\">" in page and "No published results yet" in page
    assert not re.search(r'(src|href)="(https?:)?//', page)  # nothing from a CDN
    assert httpx.get(server.url + "/static/style.css").headers["content-type"].startswith("text/css")
    assert httpx.get(server.url + "/docs").status_code == 404  # the CDN-backed docs page is off


def test_leaderboard_and_status_page_in_chromium(make_server, scoring_data, tmp_path):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    key = server.key("browser")
    with server.client(key) as c:
        sid = c.post("/v1/submissions", content=scoring_data.single.read_bytes(),
                     params={"allow_partial": "true", "publish": "true", "method": "log-replay 1.0"}).json()["id"]
        status = server.wait_state(c, sid)
    assert status["state"] == "done", status

    board = rendered_dom(server.url + "/?config=2025", tmp_path / "profile-a")
    row = re.search(r'<td class="method">([^<]*)</td><td class="num meta">([^<]*)</td>', board)
    assert row, board[-3000:]
    assert row.group(1) == "log-replay 1.0"
    assert float(row.group(2)) == pytest.approx(status["realism_meta_metric"], abs=5e-5)

    page = rendered_dom(f"{server.url}/submissions/{sid}#key={key}", tmp_path / "profile-b")
    assert field(page, "state") == "done"
    assert field(page, "progress") == "1 / 1 scenarios"
    assert float(field(page, "meta")) == status["realism_meta_metric"]
    assert 'id="links" hidden' not in page  # result links shown once done

    other = server.key("someone-else")
    page = rendered_dom(f"{server.url}/submissions/{sid}#key={other}", tmp_path / "profile-c")
    assert field(page, "state").startswith("error 404")
