"""Results served from a real server on loopback, streamed: the whole JSON document (the bytes
`json.dump` writes of it), its CSV (the text the in-memory CSV builder gives), its summary and pages of
its rows, for a stored result of 5,000 rows, a result stored by an earlier service (one `<id>.json`),
and a job scored end to end. A stored result is written as the worker writes it
(`wosac_server.results.write_result`) for a job marked done."""

from __future__ import annotations

import csv
import io
import json

import pytest

from support.results import synthetic_result
from support.server_harness import as_submission, canonical, wait_gone
from wosac_server import jobs, results

# The service end to end (scored jobs' results stored, streamed and served): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci

ROWS = 5_000


def _done_job(server, client) -> str:
    """A job of the client's key, marked done (no worker scores it)."""
    sid = client.post("/v1/submissions", content=as_submission(b"r" * 64)).json()["id"]
    server.store.execute("UPDATE submissions SET state = 'done' WHERE id = ?", (sid,))
    return sid


def _without_rows(doc: dict) -> dict:
    return {k: v for k, v in doc.items() if k != "scenarios"}


def _all_pages(client, sid: str, limit: int) -> list[dict]:
    rows, offset = [], 0
    while True:
        page = client.get(f"/v1/submissions/{sid}/results/scenarios", params={"offset": offset, "limit": limit})
        assert page.status_code == 200, page.text
        body = page.json()
        rows += body["scenarios"]
        offset += len(body["scenarios"])
        if not body["scenarios"]:
            assert offset == body["total"]
            return rows


def _check_served(client, sid: str, doc: dict) -> None:
    """Every form of the result the service serves, against the document itself."""
    whole = json.dumps(doc, allow_nan=True).encode()  # what the service's json.dump wrote of it
    served = client.get(f"/v1/submissions/{sid}/results")
    assert served.status_code == 200 and served.headers["content-type"] == "application/json"
    assert served.content == whole and int(served.headers["content-length"]) == len(whole)
    assert canonical(served.json()) == canonical(doc)

    table = client.get(f"/v1/submissions/{sid}/results", params={"format": "csv"})
    assert table.status_code == 200 and table.headers["content-type"] == "text/csv; charset=utf-8"
    assert table.text == results.result_csv(doc)
    assert [r["scenario_id"] for r in csv.DictReader(io.StringIO(table.text))] == [
        s["scenario_id"] for s in doc["scenarios"]
    ]

    summary = client.get(f"/v1/submissions/{sid}/results/summary")
    assert summary.status_code == 200 and summary.headers["content-type"] == "application/json"
    assert list(summary.json()) == list(_without_rows(doc))  # the document's keys, in order, but the rows
    assert canonical(summary.json()) == canonical(_without_rows(doc))


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_result_of_many_rows_is_streamed_paged_and_summarised(api_server):
    doc = synthetic_result(ROWS)
    rows = [json.loads(json.dumps(r, allow_nan=True)) for r in doc["scenarios"]]
    with api_server.client(api_server.key("many-rows")) as c, api_server.client(api_server.key("other")) as o:
        sid = _done_job(api_server, c)
        results.write_result(api_server.data_dir / "results", sid, doc)
        assert sorted(p.name for p in (api_server.data_dir / "results").glob(f"{sid}*")) == [
            f"{sid}.rows.jsonl",
            f"{sid}.summary.json",
        ]
        _check_served(c, sid, doc)

        # Pages: their boundaries, the last one short, past the end empty, the limit capped.
        base = f"/v1/submissions/{sid}/results/scenarios"
        for offset, limit in [
            (0, 1000),
            (0, 1),
            (999, 2),
            (1000, 1000),
            (1999, 3),
            (4990, 1000),
            (ROWS - 1, 5),
            (ROWS, 10),
            (10**9, 1),
        ]:
            page = c.get(base, params={"offset": offset, "limit": limit})
            assert page.status_code == 200, page.text
            assert canonical(page.json()) == canonical(
                {"total": ROWS, "offset": offset, "scenarios": rows[offset : offset + limit]}
            ), (offset, limit)
        assert len(c.get(base).json()["scenarios"]) == results.MAX_PAGE  # the default: a whole page
        for bad in ({"limit": results.MAX_PAGE + 1}, {"limit": 0}, {"offset": -1}, {"offset": "x"}):
            assert c.get(base, params=bad).status_code == 422, bad
        assert canonical(_all_pages(c, sid, 777)) == canonical(rows)
        assert "NaN" in c.get(base, params={"offset": 3, "limit": 1}).text  # stored NaN, served as the document has it

        # Same key rules as the other results: another key's id is 404, a job not done 409.
        forms = ["/results", "/results?format=csv", "/results/summary", "/results/scenarios"]
        for form in forms:
            r = o.get(f"/v1/submissions/{sid}{form}")
            assert r.status_code == 404 and sid in r.json()["detail"], form
            assert c.get(f"/v1/submissions/{'0' * 32}{form}").status_code == 404
        queued = c.post("/v1/submissions", content=as_submission(b"q" * 64)).json()["id"]
        for form in forms:
            r = c.get(f"/v1/submissions/{queued}{form}")
            assert r.status_code == 409 and "queued" in r.json()["detail"], form

        # A rows file gone or cut short: 410 with the reason, never a document missing rows.
        rows_file = results.rows_path(api_server.data_dir / "results", sid)
        rows_file.write_bytes(rows_file.read_bytes()[:-100])
        for form in forms:
            r = c.get(f"/v1/submissions/{sid}{form}")
            assert r.status_code == 410 and "damaged on the server" in r.json()["detail"], (form, r.text)
        rows_file.unlink()
        assert "rows file is missing" in c.get(f"/v1/submissions/{sid}/results").json()["detail"]


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_result_stored_by_an_earlier_service_is_still_served(api_server):
    """A service upgraded in place keeps its results of the single-file format (`<id>.json`, the whole
    document, as `jobs.write_json_atomically` wrote it)."""
    doc = synthetic_result(2_500, seed=1)
    with api_server.client(api_server.key("old-format")) as c:
        sid = _done_job(api_server, c)
        old = api_server.data_dir / "results" / f"{sid}.json"
        jobs.write_json_atomically(old, doc)
        _check_served(c, sid, doc)
        assert c.get(f"/v1/submissions/{sid}/results").content == old.read_bytes()
        base = f"/v1/submissions/{sid}/results/scenarios"
        rows = json.loads(old.read_text())["scenarios"]
        for offset, limit in [(0, 1000), (999, 2), (2499, 10), (2500, 1)]:
            assert canonical(c.get(base, params={"offset": offset, "limit": limit}).json()) == canonical(
                {"total": 2500, "offset": offset, "scenarios": rows[offset : offset + limit]}
            )
        assert canonical(_all_pages(c, sid, 1000)) == canonical(rows)

        old.write_bytes(old.read_bytes()[: len(old.read_bytes()) // 2])  # cut short: the CSV finds it first
        r = c.get(f"/v1/submissions/{sid}/results", params={"format": "csv"})
        assert r.status_code == 410 and "damaged on the server" in r.json()["detail"]
        old.unlink()
        for form in ("/results", "/results/summary", "/results/scenarios"):
            r = c.get(f"/v1/submissions/{sid}{form}")
            assert r.status_code == 410 and "missing on the server" in r.json()["detail"], form


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_a_scored_job_is_stored_apart_and_served_whole(make_server, scoring_data):
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    with server.client(server.key("scored")) as c:
        sid = c.post("/v1/submissions", content=scoring_data.full.read_bytes()).json()["id"]
        status = server.wait_state(c, sid)
        assert status["state"] == "done", status
        # The journal goes once the job's end is recorded (state first: a crash between the two never
        # scores a finished job again), so it may outlive "done" by a moment.
        wait_gone(server.data_dir / "results" / f"{sid}.journal", timeout=30)
        stored = sorted(p.name for p in (server.data_dir / "results").iterdir() if p.is_file())
        # (and the per-object values behind its scene pages, with their row index: server_scene_pages_test.py)
        assert stored == [f"{sid}.objects.idx", f"{sid}.objects.jsonl", f"{sid}.rows.jsonl", f"{sid}.summary.json"]
        doc = c.get(f"/v1/submissions/{sid}/results").json()
        assert len(doc["scenarios"]) == doc["num_scenarios"] == len(scoring_data.scenarios)
        _check_served(c, sid, doc)
        assert canonical(_all_pages(c, sid, 1)) == canonical(doc["scenarios"])
        assert (
            c.get(f"/v1/submissions/{sid}/results/summary").json()["buckets"]["realism_meta_metric"]
            == status["realism_meta_metric"]
        )


def _peak_rss_bytes(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM in /proc status")


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_ten_clients_fetching_a_result_at_once_do_not_grow_the_api(make_server):
    """The whole JSON of a 1 MB result, to ten clients at once that read it slowly: streamed from the stored
    files, the API process's peak RSS grows by a few MB at most (not by the result times its readers)."""
    import threading
    import time

    server = make_server(workers=0)
    key = server.key("ten-readers")
    doc = synthetic_result(330)  # about 1 MB of JSON
    whole = json.dumps(doc, allow_nan=True).encode()
    assert 0.9e6 < len(whole) < 1.4e6
    with server.client(key) as c:
        sid = _done_job(server, c)
        results.write_result(server.data_dir / "results", sid, doc)
        assert c.get(f"/v1/submissions/{sid}/results").content == whole  # every code path warm
    baseline = _peak_rss_bytes(server.proc.pid)
    got: list[bytes] = []

    def read_slowly() -> None:
        with server.client(key) as c, c.stream("GET", f"/v1/submissions/{sid}/results") as answer:
            parts = []
            for part in answer.iter_raw(65536):
                parts.append(part)
                time.sleep(0.02)
            got.append(b"".join(parts))

    readers = [threading.Thread(target=read_slowly) for _ in range(10)]
    for reader in readers:
        reader.start()
    for reader in readers:
        reader.join()
    growth = _peak_rss_bytes(server.proc.pid) - baseline
    assert got == [whole] * 10
    # 10.8 MiB when each reader's stream went in pieces of 256 KiB
    assert growth < 5 * 2**20, f"the API grew by {growth / 2**20:.1f} MiB serving a {len(whole) / 1e6:.1f} MB result"
