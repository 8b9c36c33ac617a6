"""Where the project keeps what it may rebuild: under the user's cache folder (XDG's rule)."""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir(*parts: str) -> Path:
    """`$XDG_CACHE_HOME/wosac-eval/<parts>` (`~/.cache` when XDG_CACHE_HOME is unset or empty)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root, "wosac-eval", *parts)
