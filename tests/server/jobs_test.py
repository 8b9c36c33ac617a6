"""The job store on both engines (a real SQLite file, a real PostgreSQL server):
atomic claims, leases, the reaper, keys, the leaderboard."""

from __future__ import annotations

import json
import threading
import time

import pytest

from wosac_server import auth, jobs


def add_job(store, key_id="k", method="m", config="2025", published=False, created=None, challenge="sim_agents") -> str:
    sid = jobs.new_id()
    params = jobs.SubmissionParams(challenge=challenge, config=config, method=method, publish=published)
    jobs.insert_submission(store, sid, key_id, params, file_name=sid + ".binproto", upload_bytes=10)
    if created is not None:
        store.execute("UPDATE submissions SET created_at = ? WHERE id = ?", (created, sid))
    return sid


def test_each_job_is_claimed_exactly_once_under_contention(store):
    ids = {add_job(store) for _ in range(40)}
    claimed: list[tuple[str, str]] = []
    lock = threading.Lock()

    def worker(owner: str) -> None:
        while (job := jobs.claim_next(store, owner, lease_s=60)) is not None:
            with lock:
                claimed.append((job["id"], owner))
        store.close()

    threads = [threading.Thread(target=worker, args=(f"w{i}",)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(sid for sid, _ in claimed) == sorted(ids)  # every job once, none twice
    for sid, owner in claimed:
        row = jobs.get_submission(store, sid)
        assert (row["state"], row["lease_owner"], row["attempts"]) == ("validating", owner, 1)


def test_claims_follow_upload_order(store):
    late = add_job(store, created=2000.0)
    early = add_job(store, created=1000.0)
    assert jobs.claim_next(store, "w", 60)["id"] == early
    assert jobs.claim_next(store, "w", 60)["id"] == late
    assert jobs.claim_next(store, "w", 60) is None


def test_reaper_requeues_stale_leases_then_gives_up(store):
    sid = add_job(store)
    for attempt in (1, 2, 3):
        job = jobs.claim_next(store, f"worker-{attempt}", lease_s=0.05)
        assert job["id"] == sid and job["attempts"] == attempt
        assert jobs.record_progress(store, sid, f"worker-{attempt}", 1, 5)
        assert jobs.reap_expired(store, max_attempts=3, now=time.time()) == (0, 0)  # lease still fresh
        time.sleep(0.06)
        requeued, failed = jobs.reap_expired(store, max_attempts=3)
        assert (requeued, failed) == ((1, 0) if attempt < 3 else (0, 1))
        # The dead worker's late writes are refused: the job is not its any more.
        assert not jobs.renew_lease(store, sid, f"worker-{attempt}", 60)
        assert not jobs.finish_done(store, sid, f"worker-{attempt}", {"buckets": {}, "scenarios": []})
    row = jobs.get_submission(store, sid)
    assert row["state"] == "failed" and "interrupted 3 times" in row["error"]
    assert row["lease_owner"] is None and row["finished_at"] is not None


def test_heartbeat_keeps_the_lease_and_finish_records_the_score(store):
    sid = add_job(store, method="good", published=True)
    jobs.claim_next(store, "w", lease_s=0.2)
    for _ in range(3):
        time.sleep(0.1)
        assert jobs.renew_lease(store, sid, "w", lease_s=0.2)
        assert jobs.reap_expired(store, max_attempts=3) == (0, 0)
    result = {
        "scenarios": [{"scenario_id": "a"}, {"scenario_id": "b"}],
        "buckets": {"realism_meta_metric": 0.75, "min_ade": 1.5},
    }
    assert jobs.finish_done(store, sid, "w", result)
    row = jobs.get_submission(store, sid)
    assert (row["state"], row["scenarios_done"], row["scenarios_total"]) == ("done", 2, 2)
    assert row["realism_meta_metric"] == 0.75 and json.loads(row["buckets"])["min_ade"] == 1.5
    assert not jobs.finish_failed(store, sid, "w", "too late")  # a finished job stays finished


def test_release_on_shutdown_does_not_count_an_attempt(store):
    sid = add_job(store)
    jobs.claim_next(store, "w", 60)
    assert jobs.release(store, sid, "w")
    row = jobs.get_submission(store, sid)
    assert (row["state"], row["attempts"], row["lease_owner"]) == ("queued", 0, None)


def test_leaderboard_keeps_the_best_published_result_per_method(store):
    def scored(method, meta, published=True, config="2025", challenge="sim_agents", coverage=1.0):
        sid = add_job(store, method=method, published=published, config=config, challenge=challenge)
        job = jobs.claim_next(store, "w", 60)
        assert job["id"] == sid
        jobs.finish_done(
            store,
            sid,
            "w",
            {"scenarios": [{}], "buckets": {"realism_meta_metric": meta}, "coverage": {"fraction": coverage}},
        )
        return sid

    scored("alpha", 0.50)
    best_alpha = scored("alpha", 0.60)
    scored("alpha", 0.55)
    best_beta = scored("beta", 0.58)
    scored("gamma", 0.99, published=False)
    scored("delta", 0.99, config="2024")
    board = jobs.leaderboard(store, "2025")
    assert [(e["rank"], e["method"], e["submission_id"], e["realism_meta_metric"]) for e in board] == [
        (1, "alpha", best_alpha, 0.60),
        (2, "beta", best_beta, 0.58),
    ]
    assert [e["method"] for e in jobs.leaderboard(store, "2024")] == ["delta"]
    # One leaderboard per challenge; a partial result carries its coverage.
    generated = scored("epsilon", 0.3, config="scenario_gen_2025", challenge="scenario_gen", coverage=0.5)
    assert jobs.leaderboard(store, "scenario_gen_2025", "sim_agents") == []
    board = jobs.leaderboard(store, "scenario_gen_2025", "scenario_gen")
    assert [(e["method"], e["submission_id"], e["coverage"]) for e in board] == [("epsilon", generated, 0.5)]
    assert all(e["coverage"] == 1.0 for e in jobs.leaderboard(store, "2025"))


def test_a_version_1_database_is_migrated(tmp_path):
    """A data dir written before challenges existed keeps its jobs, as sim agents jobs."""
    import sqlite3

    from wosac_server.db import SCHEMA, SCHEMA_VERSION, Store

    path = tmp_path / "old.sqlite3"
    with sqlite3.connect(path) as conn:
        for stmt in SCHEMA:
            conn.execute(stmt)
        conn.execute("INSERT INTO schema_version (version) VALUES (1)")
        conn.execute(
            "INSERT INTO submissions (id, key_id, method, config, allow_partial, published, state, file_name,"
            " upload_bytes, created_at, updated_at, scenarios_done, attempts) VALUES"
            " ('a', 'k', 'm', '2025', 0, 0, 'queued', 'a.binproto', 1, 0, 0, 0, 0)"
        )
    store = Store(f"sqlite:///{path}")
    store.migrate()
    store.migrate()  # idempotent
    assert store.fetchone("SELECT version FROM schema_version")["version"] == SCHEMA_VERSION == 5
    row = jobs.get_submission(store, "a")
    assert (row["challenge"], row["coverage"], row["state"]) == ("sim_agents", None, "queued")
    assert (row["peak_rss_bytes"], row["cpu_s"]) == (None, None)
    assert store.fetchall("SELECT * FROM method_names") == []
    store.close()


def test_names_compare_by_their_normal_form():
    from wosac_server.names import display_name, name_key

    same = [
        "Team Rocket",
        "Team  Rocket",
        "Team Rocket ",
        " team ROCKET",
        "Team\tRocket",
        "Ｔｅａｍ Ｒｏｃｋｅｔ",
        "Team\u00a0Rocket",
        "Team \u200bRocket",
        "Team\u200b Rocket",
        "Team Rocket\u200d\ufeff",
        "Team\u3000Rocket",
    ]
    assert {name_key(n) for n in same} == {"team rocket"}
    assert name_key("Team\u200bRocket") == name_key("TeamRocket") == "teamrocket"  # zero-width is nothing
    assert name_key("Team Rocket2") != name_key("Team Rocket") != name_key("Team-Rocket")
    assert [display_name(n) for n in ("Team  Rocket ", "Team\u00a0 Rocket", "x")] == ["Team Rocket", "Team Rocket", "x"]


def test_look_alike_claims_are_one_name_and_the_board_shows_the_owner_only(store):
    assert jobs.claim_method(store, "sim_agents", "Team Rocket", "owner")
    assert not jobs.claim_method(store, "sim_agents", "team  ROCKET ", "imitator")
    assert jobs.claim_method(store, "sim_agents", "TEAM ROCKET", "owner")  # the owner, any spelling
    assert jobs.claim_method(store, "scenario_gen", "team rocket", "imitator")  # per challenge
    assert jobs.method_owner(store, "sim_agents", "Team\u00a0Rocket") == "owner"
    assert [(m["challenge"], m["method"]) for m in jobs.list_methods(store)] == [
        ("scenario_gen", "team rocket"),
        ("sim_agents", "Team Rocket"),
    ]

    def scored(key_id, method, meta):
        sid = add_job(store, key_id=key_id, method=method, published=True)
        assert jobs.claim_next(store, "w", 60)["id"] == sid
        jobs.finish_done(
            store,
            sid,
            "w",
            {"scenarios": [{}], "buckets": {"realism_meta_metric": meta}, "coverage": {"fraction": 1.0}},
        )
        return sid

    # Rows as an older server stored them: an imitator's look-alike, the owner's own spellings.
    scored("imitator", "Team  Rocket", 0.9)
    best = scored("owner", "Team Rocket ", 0.7)
    scored("owner", "Team Rocket", 0.6)
    free = scored("anyone", "Unclaimed  Name", 0.5)
    board = jobs.leaderboard(store, "2025")
    assert [(e["method"], e["submission_id"]) for e in board] == [("Team Rocket", best), ("Unclaimed Name", free)]
    jobs.assign_method(store, "sim_agents", "team rocket", "imitator")  # the operator's override
    assert jobs.method_owner(store, "sim_agents", "Team Rocket") == "imitator"
    assert [e["realism_meta_metric"] for e in jobs.leaderboard(store, "2025")] == [0.9, 0.5]


def test_key_names_are_unique_by_their_normal_form(store):
    auth.create_key(store, "Team  Rocket ", max_concurrent=1, max_daily=1, max_daily_bytes=1)
    assert [k["name"] for k in auth.list_keys(store)] == ["Team Rocket"]
    for look_alike in ("team rocket", "TEAM  ROCKET"):
        with pytest.raises(ValueError, match="'Team Rocket' already exists"):
            auth.create_key(store, look_alike, max_concurrent=1, max_daily=1, max_daily_bytes=1)


@pytest.mark.parametrize("engine", ["sqlite", "postgresql"])
def test_a_version_3_database_gets_normal_forms_and_look_alike_claims_resolved(engine, tmp_path, request):
    """Claims and keys of a version 3 database get their normal form; of look-alike claims made before,
    the first keeps the name."""
    from wosac_server.db import MIGRATIONS, SCHEMA, SCHEMA_VERSION, Store

    url = f"sqlite:///{tmp_path / 'v3.sqlite3'}" if engine == "sqlite" else request.getfixturevalue("postgres_server")()
    store = Store(url)
    with store.transaction():
        for stmt in [*SCHEMA, *MIGRATIONS[2], *MIGRATIONS[3]]:
            store.execute(stmt)
        store.execute("INSERT INTO schema_version (version) VALUES (3)")
        for i, (challenge, method, key_id) in enumerate(
            [
                ("sim_agents", "Team Rocket", "first"),
                ("sim_agents", "Team  Rocket", "second"),
                ("sim_agents", "team rocket ", "third"),
                ("scenario_gen", "TEAM ROCKET", "second"),
                ("sim_agents", "Other", "second"),
            ]
        ):
            store.execute(
                "INSERT INTO method_names (challenge, method, key_id, claimed_at) VALUES (?, ?, ?, ?)",
                (challenge, method, key_id, 100.0 + i),
            )
        store.execute(
            "INSERT INTO api_keys (id, name, salt, key_hash, created_at, max_concurrent, max_daily,"
            " max_daily_bytes) VALUES ('kid', 'Old  Key', '00', 'x', 0, 1, 1, 1)"
        )
    store.migrate()
    store.migrate()  # idempotent
    assert store.fetchone("SELECT version FROM schema_version")["version"] == SCHEMA_VERSION
    claims = store.fetchall("SELECT challenge, method, name_key, key_id FROM method_names ORDER BY challenge, method")
    assert [tuple(c.values()) for c in claims] == [
        ("scenario_gen", "TEAM ROCKET", "team rocket", "second"),
        ("sim_agents", "Other", "other", "second"),
        ("sim_agents", "Team Rocket", "team rocket", "first"),
    ]
    assert not jobs.claim_method(store, "sim_agents", "Team  Rocket", "second")
    assert store.fetchone("SELECT name_key FROM api_keys WHERE id = 'kid'")["name_key"] == "old key"
    with pytest.raises(ValueError, match="'Old  Key' already exists"):
        auth.create_key(store, "old key", max_concurrent=1, max_daily=1, max_daily_bytes=1)
    store.close()


def test_keys_are_hashed_and_verified(store):
    key = auth.create_key(store, "team", max_concurrent=1, max_daily=2, max_daily_bytes=3)
    found = auth.verify_key(store, key)
    assert (found.name, found.max_concurrent, found.max_daily, found.max_daily_bytes) == ("team", 1, 2, 3)
    secret = key.split("_", 2)[2]
    row = store.fetchone("SELECT * FROM api_keys WHERE name = 'team'")
    assert secret not in json.dumps(row)
    assert auth.verify_key(store, key[:-1] + ("x" if key[-1] != "x" else "y")) is None
    with pytest.raises(ValueError, match="already exists"):
        auth.create_key(store, "team", max_concurrent=1, max_daily=1, max_daily_bytes=1)
    assert auth.revoke_key(store, "team")
    assert auth.verify_key(store, key) is None


def test_quotas_count_unfinished_jobs_and_the_last_day(store):
    key = auth.verify_key(store, auth.create_key(store, "q", max_concurrent=2, max_daily=3, max_daily_bytes=25))
    add_job(store, key_id=key.id)
    auth.check_submission_quota(store, key, 10)
    add_job(store, key_id=key.id)
    with pytest.raises(auth.QuotaExceeded) as exc:
        auth.check_submission_quota(store, key, 1)
    assert exc.value.status == 429 and "at a time" in exc.value.message
    store.execute("UPDATE submissions SET state = 'done' WHERE key_id = ?", (key.id,))
    with pytest.raises(auth.QuotaExceeded) as exc:
        auth.check_submission_quota(store, key, 6)  # 20 bytes used of 25
    assert exc.value.status == 413
    add_job(store, key_id=key.id)
    with pytest.raises(auth.QuotaExceeded) as exc:
        auth.check_submission_quota(store, key, 1)
    assert exc.value.status == 429 and "per day" in exc.value.message
    store.execute("UPDATE submissions SET created_at = created_at - 90000 WHERE key_id = ?", (key.id,))
    auth.check_submission_quota(store, key, 25)  # a day later, all of it is available again


def test_store_reconnects_after_postgresql_drops_the_connection(postgres_server):
    import psycopg

    from wosac_server.db import Store

    url = postgres_server()
    store = Store(url)
    store.migrate()
    sid = add_job(store)
    backend = store.fetchone("SELECT pg_backend_pid() AS pid")["pid"]
    with psycopg.connect(url, autocommit=True) as admin:
        admin.execute("SELECT pg_terminate_backend(%s)", (backend,))
    assert jobs.get_submission(store, sid)["state"] == "queued"  # served on a new connection
    assert store.fetchone("SELECT pg_backend_pid() AS pid")["pid"] != backend
    store.close()
