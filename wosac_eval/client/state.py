"""Where an upload is remembered between runs: one small JSON file per (server, key, file, parameters).

The file's name is a SHA-256 of the server URL, a hash of the API key, the submission's absolute
path, size and modification time, and the upload's parameters (method, challenge, config, publish,
partial): the same command run again finds it, and a changed file, another key or other parameters
do not. It holds the upload's id and, once completed, the submission's id; never the key.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from wosac_eval.runtime.cache_dirs import user_cache_dir

KEEP_S = 30 * 86400  # forget uploads untouched for 30 days (the server drops unfinished ones after 7 by default)


def default_state_dir() -> Path:
    return user_cache_dir("uploads")


def key_digest(key: str) -> str:
    """A one-way hash of the API key: part of the state's identity, never the key itself."""
    return hashlib.sha256(b"wosac-eval upload state\0" + key.encode()).hexdigest()


class UploadState:
    """The state file of one upload; `data` is what it holds (upload_id, submission_id, what was sent)."""

    def __init__(self, folder: Path, identity: dict) -> None:
        self.folder = folder
        digest = hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:40]
        self.path = folder / f"{digest}.json"
        self.lock_path = folder / f"{digest}.lock"
        self.data: dict = {}

    def load(self) -> dict:
        try:
            value = json.loads(self.path.read_text())
        except (OSError, ValueError):
            value = {}
        self.data = value if isinstance(value, dict) else {}
        return self.data

    def save(self, **fields: Any) -> None:
        """Merge `fields` and write the file atomically (temporary file, fsync, rename), private to the user."""
        self.data.update(fields, updated_at=time.time())
        self.folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        temp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump(self.data, f, indent=1, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, self.path)

    def forget(self) -> None:
        self.data = {}
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    @contextlib.contextmanager
    def locked(self) -> Iterator[bool]:
        """Hold this upload's lock file for the block: a second run on the same upload is refused at once
        (yields False to it) instead of racing the first for the server's offset. Released by the
        kernel when the process dies, however it dies."""
        try:
            import fcntl
        except ImportError:  # not POSIX: no lock, the server's offsets still keep the bytes right
            yield True
            return
        self.folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                yield False
                return
            yield True
        finally:
            os.close(fd)


def prune(folder: Path, keep_s: float = KEEP_S) -> None:
    """Remove state and lock files untouched for `keep_s` (their uploads have long expired)."""
    now = time.time()
    try:
        entries = list(folder.iterdir())
    except OSError:
        return
    for entry in entries:
        try:
            if entry.suffix not in (".json", ".lock", ".tmp") or now - entry.stat().st_mtime <= keep_s:
                continue
            if entry.suffix == ".lock" and not _free(entry):
                continue  # a run holds it (for 30 days?): leave it
            entry.unlink()
        except OSError:
            pass


def _free(lock: Path) -> bool:
    try:
        import fcntl
    except ImportError:
        return True
    fd = os.open(lock, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)
