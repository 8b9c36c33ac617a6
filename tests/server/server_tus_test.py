"""`/v1/uploads` as tus 1.0.0, against a real server on loopback: discovery, creation with the
submission's parameters in `Upload-Metadata`, chunks with checksums, expiration, termination, the
submission an upload becomes on its last byte, and the service's rules on that path (quotas keep the
bytes, concurrent chunks answer 409, CORS only as configured). The PyPI tus client (`tuspy`) uploads a
submission through a server restart and it is scored."""

from __future__ import annotations

import base64
import email.utils
import hashlib
import threading
import time

import google_crc32c
import pytest
from tusclient import client as tus_client
from tusclient.storage.filestorage import FileStorage

from support.server_harness import as_submission

TUS = {"Tus-Resumable": "1.0.0"}
CHUNK = {**TUS, "Content-Type": "application/offset+octet-stream"}


def metadata(**values: str) -> str:
    return ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in values.items())


def stand_in(size: int = 200_000) -> bytes:
    """A body the upload check takes for a submission (nothing is scored: the server has no worker)."""
    return as_submission(hashlib.sha256(str(size).encode()).digest() * (size // 32))


def create(c, size: int, **meta: str):
    return c.post("/v1/uploads", headers={**TUS, "Upload-Length": str(size), "Upload-Metadata": metadata(**meta)})


def test_options_tell_the_protocol_without_a_key(api_server):
    with api_server.client() as c:
        for path in ("/v1/uploads", "/v1/uploads/" + "0" * 32):
            r = c.options(path)
            assert r.status_code == 204, path
            assert r.headers["tus-resumable"] == r.headers["tus-version"] == "1.0.0"
            assert set(r.headers["tus-extension"].split(",")) == {"creation", "termination", "expiration", "checksum"}
            assert int(r.headers["tus-max-size"]) == 3_000_000
            assert {"sha1", "crc32c"} <= set(r.headers["tus-checksum-algorithm"].split(","))
        assert (
            "access-control-allow-origin" not in c.options("/v1/uploads", headers={"Origin": "https://x.org"}).headers
        )


def test_creation_reads_the_metadata_and_refuses_what_does_not_parse(api_server):
    key = api_server.key("tus-creator")
    with api_server.client(key) as c:
        r = create(c, 1000, method="tus team", challenge="scenario_gen", publish="true", filename="a.tar.gz")
        assert r.status_code == 201, r.text
        assert r.headers["location"] == f"/v1/uploads/{r.json()['upload_id']}"
        assert r.headers["tus-resumable"] == "1.0.0" and r.headers["upload-offset"] == "0"
        expires = email.utils.parsedate_to_datetime(r.headers["upload-expires"]).timestamp()
        assert 6 * 86400 < expires - time.time() <= 7 * 86400
        head = c.head(r.headers["location"], headers=TUS)
        assert head.status_code == 200 and head.headers["upload-length"] == "1000"
        assert head.headers["upload-metadata"] == metadata(
            method="tus team", challenge="scenario_gen", publish="true", filename="a.tar.gz"
        )
        row = api_server.store.fetchone("SELECT * FROM uploads WHERE id = ?", (r.json()["upload_id"],))
        assert (row["method"], row["challenge"], row["config"], row["published"]) == (
            "tus team",
            "scenario_gen",
            "scenario_gen_2025",
            1,
        )
        assert c.delete(r.headers["location"], headers=TUS).status_code == 204
        assert c.head(r.headers["location"], headers=TUS).status_code == 404
        # No length (this server defers none), a version it does not speak, metadata that does not parse.
        assert c.post("/v1/uploads", headers=TUS).status_code == 400
        r = c.post("/v1/uploads", headers={"Tus-Resumable": "0.2.2", "Upload-Length": "10"})
        assert r.status_code == 412 and r.headers["tus-version"] == "1.0.0"
        bad = {**TUS, "Upload-Length": "10"}
        assert c.post("/v1/uploads", headers={**bad, "Upload-Metadata": "method !!!"}).status_code == 400
        assert create(c, 10, challenge="chess").status_code == 422
        assert create(c, 10, publish="maybe").status_code == 422
        assert create(c, 10, method="../etc").status_code == 422
        assert create(c, 10**9).status_code == 413  # past WOSAC_MAX_UPLOAD_BYTES, at once
        assert (
            api_server.store.fetchone("SELECT COUNT(*) AS n FROM uploads WHERE key_id = ?", (key.split("_")[1],))["n"]
            == 0
        )


def test_chunks_with_checksums_and_the_last_one_makes_the_submission(api_server):
    key = api_server.key("tus-chunks")
    body = stand_in()
    with api_server.client(key) as c:
        url = create(c, len(body), method="tus chunks").headers["location"]
        first = body[:65536]
        sha1 = base64.b64encode(hashlib.sha1(first).digest()).decode()
        r = c.patch(url, content=first, headers={**CHUNK, "Upload-Offset": "0", "Upload-Checksum": f"sha1 {sha1}"})
        assert r.status_code == 204 and r.headers["upload-offset"] == "65536" and "submission-id" not in r.headers
        # A checksum that does not match: 460, the chunk's bytes dropped, the earlier ones kept.
        second = body[65536:131072]
        wrong = base64.b64encode(hashlib.sha1(b"other").digest()).decode()
        r = c.patch(
            url, content=second, headers={**CHUNK, "Upload-Offset": "65536", "Upload-Checksum": f"sha1 {wrong}"}
        )
        assert r.status_code == 460 and r.headers["upload-offset"] == "65536", r.text
        assert c.head(url, headers=TUS).headers["upload-offset"] == "65536"
        assert c.patch(url, content=second, headers={**CHUNK, "Upload-Offset": "65536", "Upload-Checksum": "md4 AAAA"})
        crc = base64.b64encode(google_crc32c.Checksum(second).digest()).decode()
        r = c.patch(
            url, content=second, headers={**CHUNK, "Upload-Offset": "65536", "Upload-Checksum": f"crc32c {crc}"}
        )
        assert r.status_code == 204 and r.headers["upload-offset"] == "131072"
        # tus's PATCH carries its own content type; a stale offset gets 409 with the server's.
        assert c.patch(url, content=b"x", headers={**TUS, "Upload-Offset": "131072"}).status_code == 415
        r = c.patch(url, content=b"x", headers={**CHUNK, "Upload-Offset": "0"})
        assert r.status_code == 409 and r.headers["upload-offset"] == "131072"
        # The last chunk: the upload is a queued submission, its id in the answer.
        r = c.patch(url, content=body[131072:], headers={**CHUNK, "Upload-Offset": "131072"})
        assert r.status_code == 204 and r.headers["upload-offset"] == str(len(body)), r.text
        sid = r.headers["submission-id"]
        assert c.head(url, headers=TUS).headers["submission-id"] == sid
        assert c.get(url).json()["submission_id"] == sid
        status = c.get(f"/v1/submissions/{sid}").json()
        assert status["state"] == "queued" and status["method"] == "tus chunks" and status["upload_bytes"] == len(body)
        stored = next(api_server.data_dir.glob(f"submissions/{sid}.*")).read_bytes()
        assert stored == body
        assert c.delete(url, headers=TUS).status_code == 409  # a submission now


def test_a_quota_at_the_last_byte_keeps_the_bytes_and_head_completes_later(api_server):
    key = api_server.key("tus-quota", max_concurrent=1)
    body = stand_in(100_000)
    with api_server.client(key) as c:
        url = create(c, len(body), method="tus quota").headers["location"]
        first = c.post("/v1/submissions", content=body).json()["id"]  # then the key's only job slot is taken
        r = c.patch(url, content=body, headers={**CHUNK, "Upload-Offset": "0"})
        assert r.status_code == 429 and "retry-after" in r.headers, r.text
        head = c.head(url, headers=TUS)
        assert head.status_code == 429 and "submission-id" not in head.headers
        # The slot frees (the first job ends): the next HEAD makes the submission from the bytes kept.
        api_server.store.execute("UPDATE submissions SET state = 'failed' WHERE id = ?", (first,))
        head = c.head(url, headers=TUS)
        assert head.status_code == 200 and head.headers["upload-offset"] == str(len(body)), head.text
        sid = head.headers["submission-id"]
        assert c.get(f"/v1/submissions/{sid}").json()["upload_bytes"] == len(body)


def test_concurrent_chunks_of_one_upload_answer_409(api_server):
    key = api_server.key("tus-race")
    body = stand_in(1_000_000)
    with api_server.client(key) as c:
        url = create(c, len(body), method="tus race").headers["location"]
    answers: list[int] = []

    def send() -> None:
        with api_server.client(key) as k:
            answers.append(k.patch(url, content=body[:500_000], headers={**CHUNK, "Upload-Offset": "0"}).status_code)

    threads = [threading.Thread(target=send) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers.count(204) == 1 and set(answers) == {204, 409}, answers
    with api_server.client(key) as c:
        assert c.head(url, headers=TUS).headers["upload-offset"] == "500000"


def test_cors_only_for_the_origins_configured_and_never_with_credentials(make_server):
    server = make_server(workers=0, cors_origins="https://challenge.example.org")
    preflight = {
        "Access-Control-Request-Method": "PATCH",
        "Access-Control-Request-Headers": "authorization,upload-offset",
    }
    with server.client() as c:
        r = c.options("/v1/uploads", headers={"Origin": "https://challenge.example.org", **preflight})
        assert r.status_code == 200 and r.headers["access-control-allow-origin"] == "https://challenge.example.org"
        assert "access-control-allow-credentials" not in r.headers
        assert "upload-offset" in r.headers["access-control-allow-headers"].lower()
        r = c.options("/v1/uploads", headers={"Origin": "https://evil.example.org", **preflight})
        assert "access-control-allow-origin" not in r.headers
        r = c.options("/v1/uploads", headers={"Origin": "https://challenge.example.org"})  # tus discovery, cross-origin
        assert r.headers["tus-version"] == "1.0.0"
        assert "upload-offset" in r.headers["access-control-expose-headers"].lower()


@pytest.mark.slow
def test_tuspy_uploads_a_submission_through_a_server_restart(make_server, scoring_data, tmp_path):
    """The PyPI tus client: half the file, the server stopped and started again, a new client from the
    same URL storage resumes at the server's offset; the last chunk makes the submission, which is scored."""
    server = make_server(workers=1, scenarios=scoring_data.scenarios)
    key = server.key("tuspy")
    path = scoring_data.full
    size = path.stat().st_size
    chunk = max(1024, size // 8)
    storage = FileStorage(str(tmp_path / "tus-urls.json"))
    meta = {"method": "tuspy client", "publish": "true", "filename": path.name}

    def uploader():
        tus = tus_client.TusClient(server.url + "/v1/uploads", headers={"Authorization": f"Bearer {key}"})
        return tus.uploader(
            str(path), chunk_size=chunk, metadata=meta, store_url=True, url_storage=storage, upload_checksum=True
        )

    first = uploader()
    first.upload(stop_at=chunk * 3)  # interrupted here: this client is gone
    assert first.offset == chunk * 3
    server.stop()
    server.start()
    second = uploader()
    assert second.url == first.url and second.offset == chunk * 3  # resumed from the server's offset (HEAD)
    second.upload()
    sid = second.request.response_headers["submission-id"]
    with server.client(key) as c:
        status = server.wait_state(c, sid)
    assert status["state"] == "done" and status["method"] == "tuspy client" and status["published"], status
    assert next(server.data_dir.glob(f"submissions/{sid}.*")).read_bytes() == path.read_bytes()
