"""Schemathesis fuzzes every operation of the live server's OpenAPI schema (and, through
the schema's links, sequences of them: create an upload, patch it, complete it...); no
input may produce a 5xx answer."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("schemathesis", reason="schemathesis is not installed (pip install schemathesis)")


def schemathesis_cli() -> list[str]:
    exe = Path(sys.executable).with_name("schemathesis")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("schemathesis")
    if found is None:
        pytest.skip("the schemathesis command is not on PATH")
    return [found]


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_fuzzed_requests_never_get_a_server_error(api_server, tmp_path):
    server = api_server
    key = server.key("fuzzer", max_concurrent=10**6, max_daily=10**6)
    run = subprocess.run(
        [
            *schemathesis_cli(),
            "run",
            f"{server.url}/openapi.json",
            "--checks",
            "not_a_server_error",
            "--max-examples",
            "15",
            "--seed",
            "20251121",
            "--workers",
            "1",
            "--no-color",
            "--generation-database",
            "none",
            # The check is for 5xx answers, not for speed: once in CI a 623 kB POST /v1/submissions went past
            # 20 s (no error in the server's log), the two cores busy with step 1's workers and the
            # interpreter matrix's installs beside them, and the client's timeout failed the run.
            "--request-timeout",
            "120",
            "--phases",
            "examples,coverage,fuzzing,stateful",
            "--header",
            f"Authorization: Bearer {key}",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    assert "No issues found" in run.stdout or "passed" in run.stdout, run.stdout[-3000:]
    assert "Traceback" not in server.log.read_text()  # no exception escaped a handler either
