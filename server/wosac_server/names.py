"""Leaderboard names: what is shown, and the form that decides who owns a name.

Two names are the same name when their *normal forms* are equal: Unicode NFKC (compatibility
forms such as full-width letters become plain ones, a no-break space becomes a space), format
characters (Unicode category Cf: zero-width space and joiners, bidi marks, soft hyphen) removed,
case-folded, whitespace runs collapsed to one space and trimmed. `Team Rocket`, `team  rocket `
and `Ｔｅａｍ Rocket` are one name; ownership (`method_names.name_key`) and the reservation of key
names (`api_keys.name_key`) compare normal forms, never the text as typed.

What is stored and shown (`display_name`) is the name as typed with its whitespace trimmed and
runs of it collapsed: a page collapses whitespace anyway, so two names that differ only there
would show as the same text.
"""

from __future__ import annotations

import re
import unicodedata

_SPACES = re.compile(r"\s+")


def display_name(name: str) -> str:
    """The name as stored and shown: whitespace trimmed, runs of it one space."""
    return _SPACES.sub(" ", name).strip()


def name_key(name: str) -> str:
    """The normal form two names are compared by (see the module's text)."""
    text = unicodedata.normalize("NFKC", name)
    text = "".join(ch for ch in text if unicodedata.category(ch) != "Cf")
    # Case folding can undo NFKC (e.g. U+1E9E folds to "ss", fine; some fold to non-NFKC text): again.
    text = unicodedata.normalize("NFKC", text.casefold())
    return _SPACES.sub(" ", text).strip()
