"""Every code block of README.md and docs/*.md runs (`support/readme_blocks.py`), the two set-up commands aside.

The README's blocks run once per test run (the first test to need them runs them, under a lock of the
run, the others wait and use its folder); each page of docs/ then runs in a copy of that folder, as its
own test, so that the pages spread over the workers. As root with `unshare`, the blocks run in a network
namespace with only loopback, so the Ray examples run too and no traffic leaves 127.0.0.1; otherwise
the Ray blocks are skipped and named.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys

import pytest

from support.paths import REPO
from support.processes import RAY_TEST_ENV
from support.readme_blocks import document_blocks, documents, readme_blocks, uses_ray

RUNNER = REPO / "tests" / "support" / "readme_blocks.py"


def test_readme_has_the_two_setup_commands_and_runnable_blocks():
    text = (REPO / "README.md").read_text()
    setup = text.split("## Set up", 1)[1].split("\n## ", 1)[0]
    assert setup.count("```bash") == 2, "the Set up section holds exactly the two set-up commands"
    assert "wosac-eval demo" in setup and "pytest" in setup
    assert len(readme_blocks(text)) >= 5
    assert "wosac-eval demo --workdir demo" in readme_blocks(text)[0][2], "the first block makes the others' files"


def test_the_documents_run_in_order_the_readme_first():
    names = [str(path.relative_to(REPO)) for path in documents()]
    assert names[0] == "README.md" and names[1:] == sorted(names[1:]) and len(names) >= 9
    assert all(name.startswith("docs/") for name in names[1:])
    blocks = document_blocks()
    assert {document for document, *_ in blocks} >= {"README.md", "docs/user-guide.md", "docs/jax.md"}
    assert len(blocks) >= 25


README = "README.md"
PAGES = sorted({document for document, *_ in document_blocks() if document != README})
RAY_PAGES = {document for document, _, _, code in document_blocks() if uses_ray(code)}


def run_documents(scratch, names: list[str]) -> subprocess.CompletedProcess:
    """The runner over `names` in `scratch`: in a loopback-only namespace when root can make one, else
    with the Ray blocks skipped."""
    namespace = os.geteuid() == 0 and shutil.which("unshare") and shutil.which("ip")
    inner = [sys.executable, str(RUNNER), str(scratch)] + [a for name in names for a in ("--document", name)]
    if namespace:
        quoted = " ".join(f"'{a}'" for a in inner)
        command = ["unshare", "-n", "bash", "-c", f"ip link set lo up && exec {quoted}"]
    else:
        command = inner + ["--skip-ray"]
    return subprocess.run(command, capture_output=True, text=True, timeout=1500, env={**os.environ, **RAY_TEST_ENV})


@pytest.fixture(scope="session")
def reader_folder(run_root):
    """The folder after the README's blocks: run once in the run (a lock beside the workers' folders),
    with how it went kept beside it for the other workers."""
    folder, status = run_root / "readme-reader", run_root / "readme-reader.json"
    with open(run_root / "readme-reader.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not status.exists():
            done = run_documents(folder, [README])
            output = done.stdout[-8000:] + done.stderr[-2000:]
            status.write_text(json.dumps({"returncode": done.returncode, "output": output}))
    return folder, json.loads(status.read_text())


@pytest.mark.ci  # the CI tier (pytest --ci): the documents' blocks run as a reader runs them
def test_every_readme_block_runs(reader_folder):
    _, status = reader_folder
    assert status["returncode"] == 0, status["output"]
    print(status["output"].splitlines()[-1])


@pytest.mark.ci
@pytest.mark.parametrize(
    "page", [pytest.param(page, marks=[pytest.mark.ray] if page in RAY_PAGES else []) for page in PAGES]
)
def test_every_block_of_the_page_runs(page, reader_folder, tmp_path):
    """A page's blocks in a copy of the README's folder (its `demo/` and `result.json`), in order."""
    folder, status = reader_folder
    if status["returncode"] != 0:
        pytest.fail(f"the README's blocks failed, which {page} builds on:\n{status['output']}")
    scratch = tmp_path / "reader"
    shutil.copytree(folder, scratch, symlinks=True)
    done = run_documents(scratch, [page])
    assert done.returncode == 0, done.stdout[-8000:] + done.stderr[-2000:]
    print(done.stdout.splitlines()[-1])
