"""Fixtures for the service tests: the real server (uvicorn in a subprocess on
127.0.0.1, a real SQLite file under tmp_path), real keys, real submissions."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from wosac_server.db import Store
from support.server_harness import (  # noqa: F401  (re-exported to the test modules)
    GOLDEN_PAIR,
    SCENARIO_FILES,
    SHARED,
    ScoringData,
    Server,
    canonical,
    files_under,
    free_port,
    tar_bytes,
)
from support.server_harness import scoring_data as harness_scoring_data


def scorer_available() -> bool:
    try:
        from wosac_eval.scoring.submission import score_submission  # noqa: F401
    except ImportError:
        return False
    return True


def need_scorer():
    if not scorer_available():
        pytest.skip("wosac_eval.scoring.submission.score_submission is not available yet")


@pytest.fixture(scope="session")
def scoring_data(tmp_path_factory) -> ScoringData:
    """The golden submissions of ../shared, or demo data from `wosac_eval.sim` when absent."""
    need_scorer()
    return harness_scoring_data(tmp_path_factory.mktemp("scoring-data"))


@pytest.fixture(scope="session")
def direct_single_result(scoring_data) -> dict:
    """`score_submission` called directly on the one-scenario submission (partial)."""
    from wosac_eval.scoring.submission import score_submission

    return json.loads(
        canonical(score_submission(scoring_data.scenarios, scoring_data.single, "2025", allow_partial=True))
    )


@pytest.fixture(scope="session")
def direct_full_result(scoring_data) -> dict:
    """`score_submission` called directly on the submission covering every scenario."""
    from wosac_eval.scoring.submission import score_submission

    return json.loads(canonical(score_submission(scoring_data.scenarios, scoring_data.full, "2025")))


@pytest.fixture(scope="session")
def replicated_job(tmp_path_factory) -> tuple[Path, Path, str]:
    """(scenario shard, a .tar.gz submission of 16 scenarios in 4 shards, its result as `canonical` text):
    a small multi-scenario job (copies of a golden case), scored directly once."""
    need_scorer()
    from support.submissions import replicated_submission
    from wosac_eval.scoring.submission import score_submission

    scenarios, submission = replicated_submission(tmp_path_factory.mktemp("replicated"), 16, per_shard=4)
    return scenarios, submission, canonical(score_submission([scenarios], submission, "2025"))


def default_scenarios(tmp: Path) -> list[Path]:
    """Scenario shards for servers whose tests never score (workers=0): the shared ones
    when present, else a placeholder file, since `serve` insists on at least one shard."""
    if all(p.exists() for p in SCENARIO_FILES):
        return SCENARIO_FILES
    placeholder = tmp / "placeholder.tfrecord"
    placeholder.write_bytes(b"")
    return [placeholder]


def _server_factory(root: Path):
    started: list[Server] = []

    def make(*, data_dir: Path | None = None, scenarios: list[Path] | None = None, **env) -> Server:
        server = Server(data_dir or root / "data", scenarios or default_scenarios(root), **env)
        started.append(server)
        return server.start()

    return make, started


@pytest.fixture
def make_server(tmp_path):
    make, started = _server_factory(tmp_path)
    yield make
    for server in started:
        server.stop()


@pytest.fixture(scope="session")
def api_server(tmp_path_factory):
    """A server with no workers (jobs stay queued), a 3 MB upload limit; shared by the
    tests that never score (each uses its own key, so they cannot see each other)."""
    root = tmp_path_factory.mktemp("api")
    make, started = _server_factory(root)
    yield make(workers=0, max_upload_bytes=3_000_000)
    for server in started:
        server.stop()


# -- PostgreSQL: a throwaway cluster started by the test run --------------------------------
def _pg_bindir() -> Path | None:
    for candidate in sorted(Path("/usr/lib/postgresql").glob("*/bin"), reverse=True):
        if (candidate / "initdb").exists() and (candidate / "pg_ctl").exists():
            return candidate
    return None


@pytest.fixture(scope="session")
def postgres_server():
    """A PostgreSQL cluster in a temp dir on a free 127.0.0.1 port; yields a URL factory.

    Run as the `postgres` system user when the tests run as root (initdb refuses root).
    Skips, with the reason, when the server binaries are missing.
    """
    import shutil
    import tempfile

    bindir = _pg_bindir()
    if bindir is None:
        pytest.skip(
            "PostgreSQL server binaries not found under /usr/lib/postgresql/*/bin (apt-get install -y postgresql)"
        )
    pytest.importorskip("psycopg", reason="psycopg 3 is not installed (pip install 'psycopg[binary]')")
    root = Path(tempfile.mkdtemp(prefix="wosac-pg-"))
    data, port = root / "data", free_port()
    prefix: list[str] = []
    if os.geteuid() == 0:
        # util-linux puts it in /usr/sbin, which a non-login root shell's PATH may lack.
        runuser = shutil.which("runuser") or shutil.which("runuser", path="/usr/sbin:/sbin")
        import pwd

        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run the cluster as")
        if runuser is None:
            pytest.skip("running as root and runuser is missing (not on PATH, /usr/sbin or /sbin)")
        shutil.chown(root, "postgres")
        os.chmod(root, 0o700)
        prefix = [runuser, "-u", "postgres", "--"]

    def pg(*args: str) -> None:
        subprocess.run([*prefix, *args], check=True, capture_output=True, timeout=120, cwd=root)

    pg(str(bindir / "initdb"), "-D", str(data), "-U", "wosac", "--auth=trust", "-E", "UTF8", "--no-sync")
    pg(
        str(bindir / "pg_ctl"),
        "-D",
        str(data),
        "-l",
        str(root / "log"),
        "-w",
        "-t",
        "60",
        "start",
        "-o",
        f"-c listen_addresses=127.0.0.1 -p {port} -k {root} -c fsync=off",
    )
    base = f"postgresql://wosac@127.0.0.1:{port}"
    created = iter(range(10**6))

    def new_database() -> str:
        import psycopg

        name = f"wosac_{next(created)}"
        with psycopg.connect(f"{base}/postgres", autocommit=True) as conn:
            conn.execute(f"CREATE DATABASE {name}")
        return f"{base}/{name}"

    try:
        yield new_database
    finally:
        subprocess.run(
            [*prefix, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
            capture_output=True,
            timeout=60,
            cwd=root,
        )
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def store(request, tmp_path):
    """A migrated job store on each engine: a SQLite file, a fresh PostgreSQL database."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.sqlite3'}"
    else:
        url = request.getfixturevalue("postgres_server")()
    s = Store(url)
    s.migrate()
    yield s
    s.close()
