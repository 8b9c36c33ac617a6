"""`wosac-eval submit` and `wosac_eval.client.submit` against the real service on 127.0.0.1.

The service is `wosac-server serve` in a subprocess (tests/support/server_harness.py), the client
the real command line in a subprocess (or the function in this process): a whole submission
uploaded and followed to the same meta-metric as `wosac-eval score`; an upload interrupted (Ctrl-C,
SIGKILL) and run again, going on from the server's offset; the server stopped and started again
mid-upload; refusals printing the server's reason. Nothing is mocked.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from support.paths import REPO
from support.runs import WOSAC_EVAL, run_cli

pytest.importorskip("wosac_server", reason="the service is not installed (pip install ./server)")
from support.server_harness import GOLDEN_PAIR, SCENARIO_FILES, Server, scoring_data  # noqa: E402

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="the service's harness reads /proc")


def paced(size: int, seconds: float) -> tuple[int, list[str]]:
    """(chunk bytes, the CLI's pacing options) for an upload of `size` bytes taking about `seconds`, in ~32
    chunks: slow enough to be interrupted mid-way, whatever the size of the test's submission."""
    chunk = max(4096, size // 32)
    return chunk, ["--chunk-bytes", str(chunk), "--limit-rate", str(max(1024, int(size / seconds)))]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """The shared golden submissions (demo data when ../shared is absent)."""
    return scoring_data(tmp_path_factory.mktemp("submit-data"))


@pytest.fixture(scope="module")
def scoring_server(tmp_path_factory, data):
    server = Server(tmp_path_factory.mktemp("scoring") / "data", data.scenarios, workers=1)
    yield server.start()
    server.stop()


@pytest.fixture(scope="module")
def api_server(tmp_path_factory, data):
    """No workers: submissions stay queued (the upload tests never score)."""
    server = Server(tmp_path_factory.mktemp("api") / "data", data.scenarios, workers=0)
    yield server.start()
    server.stop()


@pytest.fixture
def big_file(tmp_path, data) -> Path:
    """A real submission of ~2 MB (one golden binproto, or the demo's), copied: its own path and mtime."""
    source = GOLDEN_PAIR[0] if all(p.exists() for p in [*SCENARIO_FILES, *GOLDEN_PAIR]) else data.full
    copy = tmp_path / f"upload{''.join(source.suffixes)}"
    shutil.copyfile(source, copy)
    return copy


def new_key(server: Server, name: str) -> tuple[str, str]:
    """(a new key, its name): the key's own name is a method name no other key may take."""
    return server.key(name), name


def submit_cli(server: Server, key: str, method: str, submission: Path, state: Path, *args: str, timeout: float = 120):
    return run_cli(
        "submit",
        str(submission),
        "--server",
        server.url,
        "--key",
        key,
        "--method",
        method,
        "--state-dir",
        str(state),
        *args,
        timeout=timeout,
    )


def start_cli(server: Server, key: str, method: str, submission: Path, state: Path, *args: str) -> subprocess.Popen:
    """The command line in the background, its key in WOSAC_API_KEY (as a user keeps it out of the history)."""
    return subprocess.Popen(
        [
            *WOSAC_EVAL,
            "submit",
            str(submission),
            "--server",
            server.url,
            "--method",
            method,
            "--state-dir",
            str(state),
            *args,
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**_env(), "WOSAC_API_KEY": key},
    )


def _env() -> dict:
    """This process's environment without WOSAC_API_KEY."""
    return {k: v for k, v in os.environ.items() if k != "WOSAC_API_KEY"}


def the_upload_id(state: Path, proc: subprocess.Popen | None = None, timeout: float = 30) -> str:
    """The upload id a running client wrote to its state dir."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc is None or proc.poll() is None, proc.communicate()
        for path in state.glob("*.json"):
            try:
                return json.loads(path.read_text())["upload_id"]
            except (ValueError, KeyError):
                pass
        time.sleep(0.02)
    raise AssertionError(f"no state file in {state}")


def server_offset(server: Server, key: str, upload_id: str) -> int:
    answer = httpx.head(f"{server.url}/v1/uploads/{upload_id}", headers={"Authorization": f"Bearer {key}"})
    assert answer.status_code == 200, answer
    return int(answer.headers["upload-offset"])


def wait_offset(server: Server, key: str, upload_id: str, at_least: int, proc: subprocess.Popen) -> int:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        offset = server_offset(server, key, upload_id)
        if offset >= at_least:
            return offset
        time.sleep(0.02)
    raise AssertionError(f"upload {upload_id} did not reach {at_least} bytes")


def sent_in_run(stderr: str) -> tuple[int, int]:
    """(bytes sent, PATCH requests) of a run, from its last line about the upload."""
    match = re.search(r"sent ([\d,]+) bytes in (\d+) PATCH request", stderr)
    assert match, stderr
    return int(match.group(1).replace(",", "")), int(match.group(2))


def stored_submission(server: Server, submission_id: str) -> bytes:
    [path] = (server.data_dir / "submissions").glob(f"{submission_id}*")
    return path.read_bytes()


def submission_id_of(stdout: str) -> str:
    match = re.search(r"submission ([0-9a-f]{32}): queued", stdout)
    assert match, stdout
    return match.group(1)


@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
def test_submit_and_wait_gives_the_meta_metric_of_score(tmp_path, scoring_server, data):
    from wosac_eval.client import ArgumentError, FollowOptions, SubmitOptions, follow, submit

    (key, method), state = new_key(scoring_server, "team-wait"), tmp_path / "state"
    done = submit_cli(
        scoring_server,
        key,
        method,
        data.full,
        state,
        "--wait",
        "-o",
        str(tmp_path / "served.json"),
        "--chunk-bytes",
        "256K",
        # --wait includes the server's scoring: on a fresh install the first job compiles the numba kernels
        # (about 40 s of a core, several times that while the other tests load both cores; 120 s ran out twice).
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    scored = run_cli(
        "score",
        "--scenarios",
        *map(str, data.scenarios),
        "--submission",
        str(data.full),
        "-o",
        str(tmp_path / "local.json"),
    )
    assert scored.returncode == 0, scored.stderr
    local = json.loads((tmp_path / "local.json").read_text())["buckets"]
    assert json.loads((tmp_path / "served.json").read_text())["buckets"] == local
    header, row = done.stdout.strip().splitlines()
    figures = dict(zip(header.split(), row.split()))
    assert figures["meta-metric"] == f"{local['realism_meta_metric']:.4f}"
    assert figures["kinematic"] == f"{local['kinematic_metrics']:.4f}"
    assert figures["interactive"] == f"{local['interactive_metrics']:.4f}"
    assert figures["map-based"] == f"{local['map_based_metrics']:.4f}"
    assert figures["minADE"] == f"{local['min_ade']:.3f}"
    assert "submission" in done.stderr and ": done" in done.stderr  # state changes on stderr
    # The key is never written to disk; the same call again (here the function) follows the same
    # submission instead of uploading the file again.
    assert not any(key in p.read_text() for p in state.iterdir())
    lines: list[str] = []
    # The options as one object, a field replaced by name (`submit(path, server=..., ...)` works as well).
    options = SubmitOptions(server=scoring_server.url, key=key, method=method, state_dir=state, log=print)
    status = submit(data.full, options, wait=True, log=lines.append)
    assert status["id"] == figures["submission"] and status["state"] == "done"
    assert status["result"]["buckets"] == local
    assert any("was uploaded before" in line for line in lines) and not any("created" in line for line in lines)
    assert follow(status["id"], server=scoring_server.url, key=key)["result"] == status["result"]
    followed = follow(status["id"], FollowOptions(server=scoring_server.url, key=key))
    assert followed["result"] == status["result"]
    with pytest.raises(ArgumentError, match="SubmitOptions.*'server'"):
        submit(data.full, key=key, method=method, wait=True)
    with pytest.raises(ArgumentError, match="FollowOptions.*'colour'"):
        follow(status["id"], server=scoring_server.url, key=key, colour="red")


def test_a_failed_job_prints_its_error_and_exits_1(tmp_path, scoring_server, data):
    """One scenario of the two, without --partial: the job fails validation."""
    key, method = new_key(scoring_server, "team-fail")
    done = submit_cli(scoring_server, key, method, data.single, tmp_path / "state", "--wait")
    assert done.returncode == 1, done.stdout + done.stderr
    assert re.search(r"wosac-eval submit: submission [0-9a-f]{32} failed: \S", done.stderr), done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["ctrl-c", "kill"])
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_an_interrupted_upload_goes_on_from_the_servers_offset(tmp_path, api_server, big_file, sig):
    (key, method), state, size = (
        new_key(api_server, f"team-{sig.name.lower()}"),
        tmp_path / "state",
        big_file.stat().st_size,
    )
    # 8 s in all: the signal comes at a quarter, with 6 s to spare for a test process slowed by a loaded host
    chunk, pacing = paced(size, 8.0)
    proc = start_cli(api_server, key, method, big_file, state, *pacing)
    try:
        upload_id = the_upload_id(state, proc)
        wait_offset(api_server, key, upload_id, size // 4, proc)
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait()
    if sig == signal.SIGINT:
        assert proc.returncode == 130, stderr
        assert f"upload {upload_id} interrupted at byte" in stderr and "run the same command again" in stderr
    held = server_offset(api_server, key, upload_id)
    assert size // 4 <= held < size
    done = submit_cli(api_server, key, method, big_file, state, "--chunk-bytes", str(chunk))
    assert done.returncode == 0, done.stderr
    resumed = re.search(rf"resuming upload {upload_id} at byte ([\d,]+) of", done.stderr)
    assert resumed, done.stderr
    at = int(resumed.group(1).replace(",", ""))
    assert at >= held  # the server's offset (a killed PATCH's last bytes may land after our look)
    sent, patches = sent_in_run(done.stderr)
    assert size - at <= sent <= size - at + 2 * chunk  # from the offset, never from 0
    assert patches <= -(-(size - at) // chunk) + 2
    assert stored_submission(api_server, submission_id_of(done.stdout)) == big_file.read_bytes()


@pytest.mark.slow  # among the longest outside Ray, browser and JAX (--durations): the full run's
def test_the_upload_survives_a_restart_of_the_server(tmp_path, data, big_file):
    server = Server(tmp_path / "data", data.scenarios, workers=0).start()
    try:
        (key, method), state, size = new_key(server, "team-restart"), tmp_path / "state", big_file.stat().st_size
        chunk, pacing = paced(size, 4.0)
        proc = start_cli(server, key, method, big_file, state, *pacing)
        try:
            upload_id = the_upload_id(state, proc)
            wait_offset(server, key, upload_id, size // 4, proc)
            server.stop()  # SIGTERM; the client meets refused connections until it is back
            time.sleep(0.5)
            server.start()
            stdout, stderr = proc.communicate(timeout=90)
        finally:
            proc.kill()
            proc.wait()
        assert proc.returncode == 0, stderr
        assert "server unreachable" in stderr and "retrying in" in stderr, stderr
        assert the_upload_id(state) == upload_id and "created" not in stderr.split("retrying", 1)[1]
        sent, _ = sent_in_run(stderr)
        assert sent <= size + 2 * chunk  # at most a chunk sent again, never the whole file
        assert stored_submission(server, submission_id_of(stdout)) == big_file.read_bytes()
    finally:
        server.stop()


def test_an_upload_gone_from_the_server_is_started_again(tmp_path, api_server, big_file):
    """Interrupted in this process (Ctrl-C from the progress callback), the upload deleted on the server:
    the next call says so and uploads the file anew."""
    from wosac_eval.client import submit

    (key, method), state, size = new_key(api_server, "team-gone"), tmp_path / "state", big_file.stat().st_size

    def interrupt(stage, done, total):
        if stage == "upload" and done >= size // 2:
            raise KeyboardInterrupt

    lines: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        submit(
            big_file,
            server=api_server.url,
            key=key,
            method=method,
            chunk_bytes=size // 8,
            state_dir=state,
            progress=interrupt,
            log=lines.append,
        )
    upload_id = the_upload_id(state)
    assert any(f"upload {upload_id} interrupted" in line for line in lines)
    # The server may still be taking the PATCH the interrupt cut short: its DELETE answers 409 until then.
    deadline = time.monotonic() + 60
    while True:
        gone = httpx.delete(f"{api_server.url}/v1/uploads/{upload_id}", headers={"Authorization": f"Bearer {key}"})
        if gone.status_code != 409 or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert gone.status_code == 204, gone.text
    lines.clear()
    status = submit(
        big_file,
        server=api_server.url,
        key=key,
        method=method,
        chunk_bytes=size // 8,
        state_dir=state,
        log=lines.append,
    )
    assert status["state"] == "queued" and status["upload_bytes"] == size
    assert any(f"no longer has upload {upload_id}" in line and "starting a new upload" in line for line in lines)
    assert the_upload_id(state) != upload_id


def test_a_409_moves_the_client_to_the_servers_offset(tmp_path, api_server, big_file):
    """Another client appends a chunk behind this one's back (at its first progress report, between its
    create and its first PATCH): that PATCH gets 409 with the server's offset, and it goes on from there."""
    from wosac_eval.client import submit

    (key, method), size, content = new_key(api_server, "team-409"), big_file.stat().st_size, big_file.read_bytes()
    appended: list[int] = []

    def other_client(stage, done, total):
        if stage == "upload" and not appended:
            upload_id = the_upload_id(tmp_path / "state")
            answer = httpx.patch(
                f"{api_server.url}/v1/uploads/{upload_id}",
                content=content[: size // 3],
                headers={
                    "Authorization": f"Bearer {key}",
                    "Upload-Offset": "0",
                    "Content-Type": "application/offset+octet-stream",
                },
            )
            assert answer.status_code == 204, answer.text
            appended.append(int(answer.headers["upload-offset"]))

    lines: list[str] = []
    status = submit(
        big_file,
        server=api_server.url,
        key=key,
        method=method,
        chunk_bytes=size // 8,
        state_dir=tmp_path / "state",
        progress=other_client,
        log=lines.append,
    )
    assert appended == [size // 3]
    assert any(f"the server holds {size // 3:,} bytes" in line and "going on from there" in line for line in lines)
    assert stored_submission(api_server, status["id"]) == content


@pytest.mark.parametrize("case", ["name of another key", "unknown config", "wrong key"])
def test_a_refusal_prints_the_servers_reason_and_exits_1(tmp_path, api_server, big_file, case):
    name = case.replace(" ", "-")
    key = api_server.key(f"team-{name}")
    api_server.key(f"owner-{name}")  # its name is its own
    method = f"owner-{name}" if case == "name of another key" else f"team-{name}"
    args = ("--config", "1999") if case == "unknown config" else ()
    reason = {
        "name of another key": "belongs to another key",
        "unknown config": "unknown config '1999'",
        "wrong key": "unknown or revoked API key",
    }[case]
    used = key + "x" if case == "wrong key" else key
    done = run_cli(
        "submit",
        str(big_file),
        "--server",
        api_server.url,
        "--key",
        used,
        "--method",
        method,
        "--state-dir",
        str(tmp_path / "state"),
        *args,
        timeout=60,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "wosac-eval submit: the server refused it (4" in done.stderr and reason in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""


def test_a_quota_with_a_long_retry_after_is_refused_at_once(tmp_path, api_server, big_file):
    """Retry-After is honoured: a daily quota spent (429, Retry-After about a day, past the retry budget)
    ends the command at once with the server's reason, instead of trying again and again."""
    from wosac_eval.client import submit

    key = api_server.key("team-daily", max_daily=1)
    submit(big_file, server=api_server.url, key=key, method="team-daily", state_dir=tmp_path / "state")
    start = time.monotonic()
    done = submit_cli(api_server, key, "team-daily", big_file, tmp_path / "state", "--new")
    assert done.returncode == 1, done.stderr
    assert "the server refused it (429)" in done.stderr and "its limit is 1 per day" in done.stderr, done.stderr
    assert re.search(r"the server asks to retry in 8\d{4} s", done.stderr), done.stderr
    assert "retrying" not in done.stderr and time.monotonic() - start < 30


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_usage_errors_exit_2_before_any_upload(tmp_path, big_file, data):
    state = tmp_path / "state"
    no_key = run_cli(
        "submit",
        str(big_file),
        "--server",
        "http://127.0.0.1:9",
        "--method",
        "m1",
        "--state-dir",
        str(state),
        env=_env(),
    )
    assert no_key.returncode == 2 and "WOSAC_API_KEY" in no_key.stderr, no_key.stderr
    missing = run_cli(
        "submit",
        str(tmp_path / "nope.tar.gz"),
        "--server",
        "http://127.0.0.1:9",
        "--key",
        "k",
        "--method",
        "m1",
        "--state-dir",
        str(state),
    )
    assert missing.returncode == 2 and "no such file" in missing.stderr, missing.stderr
    closed = Server(tmp_path / "unused", data.scenarios).port  # a free port: nobody listens there
    unreachable = run_cli(
        "submit",
        str(big_file),
        "--server",
        f"http://127.0.0.1:{closed}",
        "--key",
        "k",
        "--method",
        "m1",
        "--state-dir",
        str(state),
        timeout=60,
    )
    assert unreachable.returncode == 2, unreachable.stderr
    assert "cannot reach" in unreachable.stderr and "Traceback" not in unreachable.stderr
