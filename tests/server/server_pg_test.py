"""The whole service on PostgreSQL: a cluster started by the test run, the real
server and workers using it through WOSAC_DB_URL."""

from __future__ import annotations

import pytest

from support.server_harness import canonical

# The service end to end (the service on a real PostgreSQL server): the CI tier's (`pytest --ci`).
pytestmark = pytest.mark.ci


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_service_on_postgresql_scores_and_survives_restart(
    make_server, postgres_server, scoring_data, direct_single_result
):
    url = postgres_server()
    server = make_server(workers=1, db_url=url, scenarios=scoring_data.scenarios)
    assert not (server.data_dir / "wosac.sqlite3").exists()  # the data dir holds files only
    key = server.key("pg-team", max_concurrent=1)
    body = scoring_data.single.read_bytes()
    with server.client(key) as c:
        sid = c.post("/v1/submissions", content=body, params={"allow_partial": "true", "publish": "true"}).json()["id"]
        assert c.post("/v1/submissions", content=body).status_code == 429  # quota counted in PostgreSQL
        status = server.wait_state(c, sid)
        assert status["state"] == "done", status
        served = c.get(f"/v1/submissions/{sid}/results").json()
    assert canonical(served) == canonical(direct_single_result)
    server.stop()
    again = make_server(data_dir=server.data_dir, workers=0, db_url=url, scenarios=scoring_data.scenarios)
    with again.client(key) as c:
        assert c.get(f"/v1/submissions/{sid}").json()["state"] == "done"
        assert c.get("/v1/leaderboard").json()["entries"][0]["submission_id"] == sid


def test_names_and_simultaneous_uploads_on_postgresql(make_server, postgres_server):
    """Look-alike names and the job slots of uploads at once, with the store in PostgreSQL."""
    import threading

    from support.server_harness import as_submission

    server = make_server(workers=0, db_url=postgres_server())
    owner, other = server.key("pg-owner", max_concurrent=2), server.key("pg-other")
    body = as_submission(b"p" * 500)
    with server.client(owner) as a, server.client(other) as b:
        assert a.post("/v1/submissions", content=body, params={"method": "Team Rocket"}).status_code == 202
        assert b.post("/v1/submissions", content=body, params={"method": "team  rocket "}).status_code == 403
        clients = [server.client(owner) for _ in range(10)]
        barrier, codes = threading.Barrier(len(clients)), []

        def upload(c):
            barrier.wait()
            codes.append(c.post("/v1/submissions", content=body).status_code)

        threads = [threading.Thread(target=upload, args=(c,)) for c in clients]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for c in clients:
            c.close()
        assert sorted(codes) == [202] + [429] * 9, codes  # one slot was free of 2
