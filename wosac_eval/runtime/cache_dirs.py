"""Where the project keeps what it may rebuild: under the user's cache folder (XDG's rule)."""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir(*parts: str) -> Path:
    """`$XDG_CACHE_HOME/wosac-eval/<parts>` (`~/.cache` when XDG_CACHE_HOME is unset or empty)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root, "wosac-eval", *parts)


OFF = frozenset({"off", "0", "no", "false"})


def configured_cache(env: str, *parts: str) -> Path | None:
    """The cache a setting `env` names: None when it says off ("off", "0", "no", "false"), its path when it
    gives one, else `user_cache_dir(*parts)`."""
    setting = os.environ.get(env, "").strip()
    if setting.lower() in OFF:
        return None
    return Path(setting) if setting else user_cache_dir(*parts)


def bounded(folder: Path, max_bytes: int) -> bool:
    """Empties `folder` (a cache: what it held is rebuilt on demand) when its files hold more than
    `max_bytes`; True if it did.

    JAX's compilation cache is bounded so (`backends.program_cache.keep_compiled_programs`, the tests),
    not by JAX's own `jax_compilation_cache_max_size`: with that set, one entry whose access-time file is
    missing (a process killed between its two writes) makes every later write fail, quietly
    (jax-ml/jax#39880, fixed after JAX 0.10.2), and every program is compiled again, run after run."""
    try:
        files = [p for p in folder.iterdir() if p.is_file()]
        if sum(p.stat().st_size for p in files) <= max_bytes:
            return False
        for path in files:
            path.unlink(missing_ok=True)
    except OSError:  # absent, or unreadable: JAX says so when it uses it
        return False
    return True
