"""A submission's scene pages: its pictured worst scenes and a page per scored scene with the objects that
cost it most (from the per-object file the worker writes), seen as the results are (the key that uploaded
it) for a private submission and by anyone for one its leaderboard shows; the leaderboard links to them."""

from __future__ import annotations

import itertools
import json
import re
import shutil
import subprocess

import httpx
import pytest

# The service end to end (a scored job's scene and object pages): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def scored(tmp_path_factory, scoring_data):
    """A server with a private and a published submission of the same file, both scored."""
    from support.server_harness import Server

    root = tmp_path_factory.mktemp("scene-pages")
    server = Server(root / "data", scoring_data.scenarios, workers=1, scene_pictures=3).start()
    try:
        owner, publisher, stranger = server.key("owner"), server.key("publisher"), server.key("stranger")
        ids = {}
        for name, key, publish in (("private", owner, "false"), ("public", publisher, "true")):
            with server.client(key) as c:
                answer = c.post(
                    "/v1/submissions",
                    params={"method": f"{name}-method", "publish": publish},
                    content=scoring_data.full.read_bytes(),
                )
                assert answer.status_code == 202, answer.text
                ids[name] = answer.json()["id"]
        for name, key in (("private", owner), ("public", publisher)):
            with server.client(key) as c:
                assert server.wait_state(c, ids[name])["state"] == "done"
        yield server, ids, {"owner": owner, "publisher": publisher, "stranger": stranger}
    finally:
        server.stop()


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_the_worker_writes_the_objects_and_their_row_index(scored, scoring_data):
    server, ids, keys = scored
    from wosac_eval.scoring.objects import read_objects

    results = server.data_dir / "results"
    sid = ids["private"]
    objects, index = results / f"{sid}.objects.jsonl", results / f"{sid}.objects.idx"
    with server.client(keys["owner"]) as c:
        summary = c.get(f"/v1/submissions/{sid}/results/summary").json()
        rows = c.get(f"/v1/submissions/{sid}/results").json()["scenarios"]
    # The served result is `wosac-eval score`'s without --per-object: the objects file is the server's own.
    assert "per_object" not in summary and sum(1 for _ in read_objects(objects)) > 0
    offsets = [int.from_bytes(index.read_bytes()[i : i + 8], "little") for i in range(0, index.stat().st_size, 8)]
    assert len(offsets) == len(rows) + 1 and offsets[0] == 0 and offsets[-1] == objects.stat().st_size
    by_scene = {
        sid_: len(list(group))
        for sid_, group in itertools.groupby(read_objects(objects), key=lambda r: r["scenario_id"])
    }
    lines = objects.read_bytes().splitlines(keepends=True)
    starts = list(itertools.accumulate((len(line) for line in lines), initial=0))
    for i, row in enumerate(rows):
        count = by_scene.get(row["scenario_id"], 0)
        first = starts.index(offsets[i])
        assert offsets[i + 1] == starts[first + count]


def test_the_row_index_skips_scenes_without_objects_and_refuses_another_order(tmp_path):
    from wosac_server.scene_objects import scene_records, write_index

    objects, index = tmp_path / "o.objects.jsonl", tmp_path / "o.objects.idx"
    records = [{"scenario_id": sid, "object_id": i} for sid, i in (("a", 1), ("a", 2), ("c", 3))]
    objects.write_text("".join(json.dumps(r) + "\n" for r in records))
    write_index(objects, ["a", "b", "c", "d"], index)
    assert [scene_records(objects, index, row) for row in range(5)] == [records[:2], [], records[2:], [], None]
    with pytest.raises(ValueError, match="out of order"):
        write_index(objects, ["c", "a"], index)
    assert scene_records(tmp_path / "none.jsonl", index, 0) is None  # scored before per-object files


@pytest.mark.slow  # a job scored by the service (the module's `scored`, 40 s on 2 cores): the full run's
def test_scenes_and_worst_objects_in_the_api(scored):
    server, ids, keys = scored
    from wosac_eval.results.worst_objects import scene_worst_objects
    from wosac_eval.scoring.objects import read_objects

    sid = ids["private"]
    objects = server.data_dir / "results" / f"{sid}.objects.jsonl"
    with server.client(keys["owner"]) as c:
        rows = c.get(f"/v1/submissions/{sid}/results").json()["scenarios"]
        listed = c.get(f"/v1/submissions/{sid}/scenes").json()["scenes"]
        assert listed and all(rows[e["row"]]["scenario_id"] == e["scenario_id"] for e in listed)
        worst = listed[0]
        assert worst["worst_objects"] and worst["object_picture"], worst
        assert c.get(worst["object_url"]).content[:8] == PNG
        assert c.get(f"/v1/submissions/{sid}/scenes/{len(listed)}/object.png").status_code == 404
        for row, scenario in enumerate(rows):
            detail = c.get(f"/v1/submissions/{sid}/results/scenarios/{row}").json()
            records = [r for r in read_objects(objects) if r["scenario_id"] == scenario["scenario_id"]]
            assert detail["scenario"] == scenario and detail["objects"] == len(records)
            assert detail["worst_objects"] == json.loads(json.dumps(scene_worst_objects(records, scenario, "2025")))
            pictured = next((e for e in listed if e["row"] == row), None)
            assert detail["picture"] == (
                None if pictured is None else {"rank": pictured["rank"], "object_picture": True}
            )
        assert (
            listed[0]["worst_objects"]
            == c.get(f"/v1/submissions/{sid}/results/scenarios/{worst['row']}").json()["worst_objects"]
        )
        assert c.get(f"/v1/submissions/{sid}/results/scenarios/{len(rows)}").status_code == 404
    # The JSON API stays as the results are: the uploader's key only, published or not.
    with server.client(keys["stranger"]) as c:
        for name in ("private", "public"):
            assert c.get(f"/v1/submissions/{ids[name]}/results/scenarios/0").status_code == 404
            assert c.get(f"/v1/submissions/{ids[name]}/scenes/0/object.png").status_code == 404


@pytest.mark.slow  # a job scored by the service (the module's `scored`, 40 s on 2 cores): the full run's
def test_a_private_submissions_pages_need_its_key(scored):
    server, ids, keys = scored
    sid, url = ids["private"], f"{server.url}/submissions/{ids['private']}"
    with server.client(keys["owner"]) as c:
        listed = c.get(f"/v1/submissions/{sid}/scenes").json()["scenes"]
    # Without a key: the shell that asks for it, saying nothing of the submission; its content and pictures 401.
    shell = httpx.get(url + "/scenes")
    assert shell.status_code == 200 and 'id="need-key"' in shell.text
    assert not any(e["scenario_id"] in shell.text for e in listed)
    unknown = httpx.get(f"{server.url}/submissions/{'0' * 32}/scenes")
    assert unknown.status_code == 200 and 'id="need-key"' in unknown.text  # no existence is confirmed
    for path in ("/scenes?fragment=1", "/scenes/0?fragment=1", "/pictures/0.png", "/pictures/0/object.png"):
        assert httpx.get(url + path).status_code == 401, path
    # With the owner's key: the content (pictures fetched by the shell's script with the key).
    owner = {"Authorization": f"Bearer {keys['owner']}"}
    fragment = httpx.get(url + "/scenes?fragment=1", headers=owner)
    assert fragment.status_code == 200 and "<script" not in fragment.text
    assert [html_id for html_id in re.findall(r'data-scenario="([^"]+)"', fragment.text)] == [
        e["scenario_id"] for e in listed
    ]
    assert f'data-src="/submissions/{sid}/pictures/0.png"' in fragment.text
    assert httpx.get(url + "/pictures/0.png", headers=owner).content[:8] == PNG
    scene = httpx.get(url + f"/scenes/{listed[0]['row']}?fragment=1", headers=owner).text
    assert 'id="worst-objects"' in scene and 'id="pictures"' in scene
    assert f'<td class="num">{listed[0]["worst_objects"][0]["object_id"]}</td>' in scene
    # Another key: as if it did not exist; a wrong key: 401.
    stranger = {"Authorization": f"Bearer {keys['stranger']}"}
    for path in ("/scenes?fragment=1", "/scenes/0?fragment=1", "/pictures/0.png"):
        assert httpx.get(url + path, headers=stranger).status_code == 404, path
    assert httpx.get(url + "/scenes?fragment=1", headers={"Authorization": "Bearer wosac_x_y"}).status_code == 401


@pytest.mark.slow  # a job scored by the service (the module's `scored`, 40 s on 2 cores): the full run's
def test_a_leaderboard_submissions_pages_are_public_and_linked_from_its_row(scored):
    server, ids, keys = scored
    sid, url = ids["public"], f"{server.url}/submissions/{ids['public']}"
    board = httpx.get(server.url + "/?config=2025").text
    assert f'href="/submissions/{sid}/scenes"' in board and ids["private"] not in board
    page = httpx.get(url + "/scenes")
    assert page.status_code == 200 and "need-key" not in page.text and "<script" not in page.text
    rows = [int(r) for r in re.findall(rf'href="/submissions/{sid}/scenes/(\d+)"', page.text)]
    assert rows and f'<img src="/submissions/{sid}/pictures/0.png"' in page.text
    picture = httpx.get(url + "/pictures/0.png")
    assert picture.status_code == 200 and picture.content[:8] == PNG
    assert httpx.get(url + "/pictures/0/object.png").content[:8] == PNG
    scene = httpx.get(url + f"/scenes/{rows[0]}")
    assert scene.status_code == 200 and 'id="worst-objects"' in scene.text
    assert f'<img src="/submissions/{sid}/pictures/0/object.png"' in scene.text
    assert "default-src 'none'" in scene.headers["content-security-policy"]
    # Any key sees it too (the leaderboard shows it); rows past the result are 404.
    stranger = {"Authorization": f"Bearer {keys['stranger']}"}
    assert httpx.get(url + "/scenes?fragment=1", headers=stranger).status_code == 200
    with server.client(keys["publisher"]) as c:
        total = c.get(f"/v1/submissions/{sid}/results/scenarios", params={"limit": 1}).json()["total"]
    for row in (total, -1, 10**30):
        assert httpx.get(url + f"/scenes/{row}").status_code == 404, row
    assert httpx.get(url + "/pictures/7.png").status_code == 404


@pytest.mark.browser
def test_a_private_scene_page_in_chromium(scored, tmp_path):
    """The shell's script fetches the page's content and its pictures with the key (CSP on)."""
    chromium = next(
        (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None
    )
    if chromium is None:
        pytest.skip("no Chromium on PATH (apt-get install -y chromium)")
    server, ids, keys = scored
    sid = ids["private"]
    with server.client(keys["owner"]) as c:
        worst = c.get(f"/v1/submissions/{sid}/scenes").json()["scenes"][0]
    run = subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            f"--user-data-dir={tmp_path / 'profile'}",
            "--virtual-time-budget=8000",
            "--dump-dom",
            f"{server.url}/submissions/{sid}/scenes/{worst['row']}#key={keys['owner']}",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    dom = run.stdout
    assert f'<code id="scenario-id">{worst["scenario_id"]}</code>' in dom
    assert 'id="worst-objects"' in dom and dom.count('src="blob:') == 2, dom[-3000:]
