"""Every code block of README.md and docs/*.md runs (`support/readme_blocks.py`), the two set-up commands aside.

As root with `unshare`, the blocks run in a network namespace with only
loopback, so the Ray examples run too and no traffic leaves 127.0.0.1;
otherwise the Ray blocks are skipped and named.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from support.paths import REPO
from support.readme_blocks import document_blocks, documents, readme_blocks

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


@pytest.mark.slow
@pytest.mark.ray  # its Ray blocks start a cluster (in the namespace): in turn with tests/ray
def test_every_readme_block_runs(tmp_path):
    namespace = os.geteuid() == 0 and shutil.which("unshare") and shutil.which("ip")
    inner = [sys.executable, str(RUNNER), str(tmp_path / "readme")]
    if namespace:
        quoted = " ".join(f"'{a}'" for a in inner)
        command = ["unshare", "-n", "bash", "-c", f"ip link set lo up && exec {quoted}"]
    else:
        command = inner + ["--skip-ray"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=1500)
    assert done.returncode == 0, done.stdout[-8000:] + done.stderr[-2000:]
    print(done.stdout.splitlines()[-1])
