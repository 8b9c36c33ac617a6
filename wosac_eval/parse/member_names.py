"""Names in a submission: which files or archive members are shards, which are skipped, which are refused.

In archives (and folders), hidden entries (name starting with "."),
`__MACOSX/` and documentation (README*, LICENSE*, NOTICE*, *.md, *.txt, *.rst)
are skipped; any other member is an error, so a mis-named shard is never
silently dropped. Member names with `..` components or absolute names are
refused (`safe_member_name`): nothing read from an archive can name a place
outside it.
"""

from __future__ import annotations

import re
from pathlib import PurePosixPath

from wosac_eval.parse.errors import UnsafeArchiveMemberError

SHARD_NAME_MARKER = ".binproto"
_DOC_PREFIXES = ("README", "LICENSE", "LICENCE", "NOTICE", "CHANGELOG")
_DOC_SUFFIXES = (".md", ".txt", ".rst")


def is_shard_name(name: str) -> bool:
    """True for a file or member name that holds a submission shard."""
    return SHARD_NAME_MARKER in PurePosixPath(name).name


def is_ignored_name(name: str) -> bool:
    """True for hidden entries, macOS resource forks and documentation."""
    parts = PurePosixPath(name).parts
    base = parts[-1] if parts else ""
    if any(part.startswith(".") or part == "__MACOSX" for part in parts):
        return True
    return base.upper().startswith(_DOC_PREFIXES) or base.lower().endswith(_DOC_SUFFIXES)


def not_a_shard_message(container: object, name: str) -> str:
    """Why a file of a folder or a member of an archive is refused: it is neither a shard nor documentation."""
    return (
        f"{container}: {name!r} is neither a submission shard (a name containing {SHARD_NAME_MARKER!r}) "
        "nor documentation (README*, *.md, *.txt); rename or remove it"
    )


def safe_member_name(archive: object, name: str) -> str:
    """The member name normalized to 'a/b/c', refusing names that could escape.

    Refused: empty names, NUL bytes, absolute paths (/x, \\x, C:x) and any
    '..' component (with / or \\ as separator).
    """
    if not name or "\x00" in name:
        raise UnsafeArchiveMemberError(f"{archive}: member with an empty or NUL-containing name")
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name):
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} has an absolute path")
    parts = [part for part in re.split(r"[/\\]", name) if part not in ("", ".")]
    if ".." in parts:
        raise UnsafeArchiveMemberError(f"{archive}: member {name!r} has a '..' component (would escape the archive)")
    return "/".join(parts)
