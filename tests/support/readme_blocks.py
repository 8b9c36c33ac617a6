"""Run the code blocks of the documentation, in order, in a scratch folder: what `tests/readme_test.py` checks.

The documents are README.md, then every `docs/*.md` by name (`documents()`).
Every ```bash and ```python block runs, except the two set-up commands (the
blocks of the README's "Set up" section, which CI itself runs); ```text, ```json
and unlabelled blocks show output or data. The blocks share the folder, one
reader's session: the README's first block runs the demo into `demo/` and its
score block writes `result.json`, which the later blocks of the README and of
`docs/` use, as those pages say; within a page, a block may use what an earlier
block of the page wrote. `examples/` of the repository is linked into the folder. Blocks that use Ray need a network
namespace with loopback only (Ray binds to the machine's address): run this
module inside `unshare -n` (the test does when it is root), or they are
skipped and named.

The test runs the README's blocks once, then each page of `docs/` in a copy of that folder (the
pages run side by side: none uses what another page wrote).

Usage: python tests/support/readme_blocks.py SCRATCH_DIR [--skip-ray] [--document README.md ...]
(every document, in order, unless --document names some). Exit 0 when every block ran with exit 0;
else 1, naming the block's line.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RUNNABLE = ("bash", "python")
FENCED_BLOCK = re.compile(r"^```(\w*)[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)


def readme_blocks(text: str) -> list[tuple[int, str, str]]:
    """(line, language, code) of every fenced block to run, set-up section excluded."""
    setup = re.search(r"^## Set up\n(.*?)(?=^## )", text, re.S | re.M)
    out = []
    for match in FENCED_BLOCK.finditer(text):
        if match.group(1) not in RUNNABLE:
            continue
        if setup and setup.start() <= match.start() < setup.end():
            continue
        out.append((text[: match.start()].count("\n") + 1, match.group(1), match.group(2)))
    return out


def documents() -> list[Path]:
    """The documents whose blocks run, in the order they run: the README first (it runs the demo)."""
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def document_blocks() -> list[tuple[str, int, str, str]]:
    """(document, line, language, code) of every block to run, documents in `documents()` order."""
    return [
        (str(path.relative_to(REPO)), line, language, code)
        for path in documents()
        for line, language, code in readme_blocks(path.read_text())
    ]


def uses_ray(code: str) -> bool:
    return "--engine ray" in code or 'engine="ray"' in code or "ray start" in code


def run_blocks(scratch: Path, skip_ray: bool, only: list[str] | None = None) -> int:
    """Run the blocks of every document, or of the documents named in `only` (paths as in
    `document_blocks()`), in order in `scratch`; 1 if any failed."""
    scratch.mkdir(parents=True, exist_ok=True)
    if not (scratch / "examples").exists():
        (scratch / "examples").symlink_to(REPO / "examples")
    home = scratch / ".home"
    home.mkdir(exist_ok=True)
    env = {
        **os.environ,
        "HOME": str(home),
        "MPLBACKEND": "Agg",
        "RAY_DISABLE_USAGE_STATS": "1",
        "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]),
        "PYTHONUNBUFFERED": "1",
        # The service's disk floor (10% of its disk by default) must not make a block's upload wait on how
        # full this machine's disk is (a 507 until space returns); server_disk_test.py tests the floor.
        "WOSAC_MIN_FREE_FRACTION": "0",
    }
    env.pop("RAY_ADDRESS", None)
    blocks = [block for block in document_blocks() if only is None or block[0] in only]
    if not blocks:
        print(f"no blocks to run in {only}", flush=True)
        return 1
    failed = 0
    for document, line, language, code in blocks:
        if skip_ray and uses_ray(code):
            print(f"{document}:{line}: skipped (uses Ray; run inside a loopback-only namespace)", flush=True)
            continue
        command = ["bash", "-euo", "pipefail", "-c", code] if language == "bash" else [sys.executable, "-c", code]
        start = time.monotonic()
        done = subprocess.run(command, cwd=scratch, env=env, capture_output=True, text=True, timeout=900)
        status = "ok" if done.returncode == 0 else f"FAILED (exit {done.returncode})"
        print(f"{document}:{line}: {language} block {status} in {time.monotonic() - start:.1f} s", flush=True)
        if done.returncode != 0:
            failed += 1
            print(
                f"--- code\n{code}--- stdout (tail)\n{done.stdout[-3000:]}\n--- stderr (tail)\n{done.stderr[-3000:]}",
                flush=True,
            )
    print(f"{len(blocks)} block(s) of {len({block[0] for block in blocks})} document(s), {failed} failed", flush=True)
    return 1 if failed else 0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description="Run the documentation's code blocks in order in SCRATCH_DIR.")
    parser.add_argument("scratch", type=Path, metavar="SCRATCH_DIR")
    parser.add_argument("--skip-ray", action="store_true", help="skip (and name) the blocks that start Ray")
    parser.add_argument("--document", action="append", help="only this document (repeatable); default all")
    args = parser.parse_args(argv)
    return run_blocks(args.scratch, args.skip_ray, args.document)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
