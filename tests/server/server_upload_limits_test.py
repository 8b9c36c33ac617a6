"""Upload size limits, on the real server: a whole validation-set submission (20-30 GB) fits the defaults
through resumable uploads (64 GiB), and a single-request body has its own, smaller limit whose 413 says to
use `wosac-eval submit`."""

from __future__ import annotations

import os

import pytest

from wosac_server.settings import GiB, load_settings

MiB = 2**20


def test_default_limits_take_a_whole_validation_set():
    settings = load_settings({"WOSAC_SCENARIOS": "x"})
    assert settings.max_upload_bytes == 64 * GiB and settings.max_single_upload_bytes == 16 * GiB


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_a_single_request_past_its_limit_is_413_naming_the_resumable_client(make_server):
    server = make_server(workers=0, max_single_upload_bytes=MiB, max_upload_bytes=4 * MiB)
    body = os.urandom(2 * MiB)
    with server.client(server.key("limits")) as c:
        declared = c.post("/v1/submissions", content=body)  # refused on its Content-Length
        streamed = c.post("/v1/submissions", content=iter([body[:MiB], body[MiB:]]))  # refused while read
        for r in (declared, streamed):
            detail = r.json()["detail"]
            assert r.status_code == 413 and "`wosac-eval submit`" in detail, detail
            assert "WOSAC_MAX_SINGLE_UPLOAD_BYTES" in detail and "\n" not in detail
        # The same bytes go through /v1/uploads, up to WOSAC_MAX_UPLOAD_BYTES.
        up = c.post("/v1/uploads", headers={"Upload-Length": str(len(body))})
        assert up.status_code == 201, up.text
        r = c.patch(f"/v1/uploads/{up.json()['upload_id']}", content=body, headers={"Upload-Offset": "0"})
        assert r.status_code == 204, r.text
        r = c.post("/v1/uploads", headers={"Upload-Length": str(4 * MiB + 1)})
        assert r.status_code == 413 and "WOSAC_MAX_UPLOAD_BYTES" in r.json()["detail"]
    assert list((server.data_dir / "uploads").glob("*.body")) == []
