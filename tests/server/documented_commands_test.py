"""Every `wosac-server` command line that README.md, server/README.md and docs/*.md show runs as written.

The lines are read from the documents themselves (code blocks and inline code), in document order,
and run in one scratch folder with an empty HOME, the way a reader pastes them. The operator
commands must exit 0, or 1 with their "nothing to do" message where the documented example names
a key or method the scratch service does not have (never 2, a usage error). `serve` and `worker`
run until healthy, then stop cleanly on SIGTERM. Two substitutions only: a free loopback port for
`--port 8000` (and `WOSAC_PORT` for a bare `serve`), and the demo's scenario shards where a line names none. `docker` lines are the
Docker check's (`.ci/docker`).
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from support.paths import REPO
from support.processes import alive
from support.readme_blocks import FENCED_BLOCK
from support.runs import WOSAC_SERVER
from support.server_harness import demo_data, free_port, wait_healthy, wait_logged

DOCUMENTS = (REPO / "README.md", REPO / "server" / "README.md", *sorted((REPO / "docs").glob("*.md")))
_COMMAND = re.compile(r"^(?:[A-Z_]+=\S+\s+)*wosac-server\s+[a-z]")
# What an operator command answers when the documented example's key or name is not in this service.
NOTHING_TO_DO = ("no active key named", "nobody owns", "no key named")


def documented_commands() -> list[tuple[str, str]]:
    """(where, command) of every wosac-server command line of the documents, in order."""
    found = []
    for document in DOCUMENTS:
        text = document.read_text()
        lines = []  # (line number, text) of every code line and inline code span
        for block in FENCED_BLOCK.finditer(text):
            first = text[: block.start()].count("\n") + 2
            lines += [
                (first + i, re.sub(r"\s+#\s.*$", "", code).strip())
                for i, code in enumerate(block.group(2).splitlines())
            ]
        prose = FENCED_BLOCK.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), text)  # blocks blanked, offsets kept
        lines += [(text[: m.start()].count("\n") + 1, m.group(1).strip()) for m in re.finditer(r"`([^`\n]+)`", prose)]
        found += [(f"{document.relative_to(REPO)}:{n}", c) for n, c in sorted(lines) if _COMMAND.match(c)]
    return found


def test_the_documents_show_the_operator_commands():
    commands = " ".join(command for _, command in documented_commands())
    for piece in (
        "keys create",
        "keys list",
        "keys revoke",
        "methods list",
        "methods assign",
        "methods release",
        "serve",
        "worker",
        "--data-dir ./wosac-data",
    ):
        assert piece in commands, piece


def _run_long_lived(command: str, cwd: Path, env: dict, log: Path) -> None:
    """A serve or worker line: started, healthy (serve) or running (worker), then stopped by SIGTERM."""
    port = free_port()
    command = command.replace("--port 8000", f"--port {port}")
    with open(log, "wb") as out:
        process = subprocess.Popen(
            ["bash", "-c", f"exec env {command}"],
            cwd=cwd,
            env={**env, "WOSAC_PORT": str(port)},
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        if " serve" in command:
            wait_healthy(f"http://127.0.0.1:{port}", process, timeout=60)
        else:
            # A worker has nothing to answer: its log says when it has its SIGTERM handler and polls
            # (its imports take over 3 s on a busy host, and a SIGTERM before that ends it by the signal).
            ready = wait_logged(log, ": ready, looking for queued jobs", timeout=60, process=process)
            assert ": ready, looking for queued jobs" in ready, f"exit {process.poll()}\n{ready[-3000:]}"
            time.sleep(1)  # and it goes on polling
            assert process.poll() is None, f"exited with {process.returncode}\n{log.read_text()[-3000:]}"
        process.send_signal(signal.SIGTERM)
        assert process.wait(60) == 0, f"{command}: exit {process.returncode}\n{log.read_text()[-3000:]}"
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert not alive(process.pid)


def _run_document(commands: list[tuple[str, str]], scratch: Path, scenarios: list[Path], log_dir: Path) -> None:
    """One document's lines, in order, in a scratch folder of its own (one reader's session)."""
    validation = scratch / "validation"
    validation.mkdir(parents=True)
    for shard in scenarios:  # the documents' `validation/*tfrecord*`
        (validation / f"{shard.name}.tfrecord").symlink_to(shard)
    home = scratch / ".home"
    home.mkdir()
    inherited = {k: v for k, v in os.environ.items() if not k.startswith(("WOSAC_", "RAY_"))}
    env = {
        **inherited,
        "HOME": str(home),
        "WOSAC_DATA_DIR": "./wosac-data",  # server/README's export
        "WOSAC_SCENARIOS": str(validation / "*tfrecord*"),
        "WOSAC_WORKERS": "1",
        "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]),
    }
    for index, (where, command) in enumerate(commands):
        words = shlex.split(command)
        if words[words.index("wosac-server") + 1] in ("serve", "worker"):
            _run_long_lived(command, scratch, env, log_dir / f"{scratch.name}-{index}.log")
            continue
        done = subprocess.run(
            ["bash", "-c", command], cwd=scratch, env=env, capture_output=True, text=True, timeout=120
        )
        message = f"{where}: {command}\nexit {done.returncode}\n{done.stdout}{done.stderr}"
        assert done.returncode != 2 and "usage:" not in done.stderr, message
        assert done.returncode == 0 or (done.returncode == 1 and any(t in done.stderr for t in NOTHING_TO_DO)), message
    listed = subprocess.run(
        ["bash", "-c", "wosac-server keys list"], cwd=scratch, env=env, capture_output=True, text=True, timeout=60
    )
    assert "my-team" in listed.stdout, listed.stdout + listed.stderr


@pytest.mark.ci  # the documents' blocks, as tests/readme_test.py's: the CI tier's
def test_every_documented_wosac_server_line_runs(tmp_path):
    scenarios = demo_data(tmp_path / "demo").scenarios
    commands = documented_commands()
    assert len(commands) >= 8
    for document in DOCUMENTS:
        name = str(document.relative_to(REPO))
        mine = [(where, command) for where, command in commands if where.startswith(name + ":")]
        if mine:  # a document without any wosac-server line has nothing to run
            _run_document(mine, tmp_path / name.replace("/", "-"), scenarios, tmp_path)


@pytest.mark.parametrize("before", [True, False])
def test_data_dir_goes_before_or_after_the_action(tmp_path, before):
    data_dir = tmp_path / "wosac-data"
    head = ["--data-dir", str(data_dir)]
    for argv in (["keys", "create", "--name", "team-a"], ["keys", "list"], ["methods", "list"]):
        full = [argv[0], *head, *argv[1:]] if before else [*argv, *head]
        done = subprocess.run(
            [*WOSAC_SERVER, *full],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, "HOME": str(tmp_path)},
        )
        assert done.returncode == 0, done.stderr
    assert (data_dir / "wosac.sqlite3").exists()
